"""`colonlight synth clips/` then `colonlight enhance clips/`: one clip per synthetic clip folder."""

from __future__ import annotations

import json
from pathlib import Path

from colonlight_cli.main import app
from typer.testing import CliRunner


def test_enhance_takes_each_synthetic_clip_folder_as_one_clip(tmp_path: Path) -> None:
    """`colonlight synth clips/` then `colonlight enhance clips/`: one clip per synthetic folder, its video."""
    runner = CliRunner()
    clips = tmp_path / "clips"
    made = runner.invoke(
        app,
        ["synth", str(clips), "--clips", "2", "--frames", "10", "--width", "64", "--height", "48", "--workers", "1"],
    )
    assert made.exit_code == 0, made.output
    folders = sorted(p.name for p in clips.iterdir() if p.is_dir())
    assert len(folders) == 2 and all((clips / f / "clean").is_dir() and (clips / f / "depth").is_dir() for f in folders)
    # one of them without its video: its frames are the clip
    (clips / folders[1] / "clip.mp4").unlink()
    out = tmp_path / "out"
    result = runner.invoke(app, ["enhance", str(clips), "-o", str(out), "-q"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    by_name = {c["clip"]: c for c in manifest["clips"]}
    assert sorted(by_name) == folders, by_name
    assert by_name[folders[0]]["source"].endswith(f"{folders[0]}/clip.mp4")
    assert by_name[folders[1]]["source"].endswith(f"{folders[1]}/frames")
    assert all(c["status"] == "done" for c in by_name.values())
    # named directly, a synthetic folder is that one clip too
    single = runner.invoke(app, ["enhance", str(clips / folders[0]), "-o", str(tmp_path / "one"), "-q"])
    assert single.exit_code == 0, single.output
    assert [c["clip"] for c in json.loads((tmp_path / "one" / "manifest.json").read_text())["clips"]] == [folders[0]]
