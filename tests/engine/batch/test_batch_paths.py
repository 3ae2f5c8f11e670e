"""A batch never aborts for one bad path (issue 13), on real trees of real files.

Symlink loops, dangling links, names that are not UTF-8, FIFOs, folders that cannot be listed (made unreadable
for root too: the run drops the capabilities that let root read anything), files that vanish between discovery
and processing, the output folder inside an input folder. Each bad path is one line naming it, a ``failed``
manifest entry where it is a clip, and the rest of the batch is done.
"""

from __future__ import annotations

import ctypes
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from colonlight_cli.display import printable
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.atomic import json_bytes
from colonlight.batch import MethodSpec, run_batch
from colonlight.discovery import discover
from colonlight.pipeline import ClipOptions

from ...commands import colonlight_command
from ...media import make_clip, make_image_folder

runner = CliRunner()
NON_UTF8 = os.fsdecode(b"caf\xe9")  # Latin-1 bytes: not valid UTF-8
GAMMA = ("--method", "gamma", "-q")  # a real method that needs no model: these tests are about paths


def manifest_of(out: Path) -> dict[str, dict]:
    return {c["clip"]: c for c in json.loads((out / "manifest.json").read_text(encoding="utf-8"))["clips"]}


@pytest.fixture()
def hostile(tmp_path: Path) -> Path:
    """videos/: two good clips, a -> b -> a link loop, a dangling link, a clip and a folder whose names are not
    UTF-8, a FIFO named like a video, a folder link back to videos/ itself."""
    root = tmp_path / "videos"
    make_clip(root / "good.mp4", n_frames=20, fps=25)
    make_image_folder(root / "seq", n=6)
    os.symlink("b.mp4", root / "a.mp4")
    os.symlink("a.mp4", root / "b.mp4")
    os.symlink("nowhere.mp4", root / "dangling.mp4")
    make_clip(root / f"{NON_UTF8}.mp4", n_frames=20, fps=25)
    make_clip(root / f"site-{NON_UTF8}" / "p1.mp4", n_frames=20, fps=25)
    os.mkfifo(root / "pipe.mp4")
    os.symlink(".", root / "again")
    return root


def test_hostile_tree_every_bad_path_is_one_line_and_the_rest_is_done(hostile: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = runner.invoke(app, ["enhance", str(hostile), "-o", str(out), *GAMMA])
    text = result.output
    assert result.exit_code == 1, text
    assert "Traceback" not in text and isinstance(result.exception, (SystemExit, type(None)))
    manifest = manifest_of(out)
    failed = {k: c["error"] for k, c in manifest.items() if c["status"] == "failed"}
    assert set(failed) == {"a", "b", "dangling", "pipe"}
    assert "symbolic link loop" in failed["a"] and "a.mp4" in failed["a"]
    assert "dangling" in failed["dangling"] and "dangling.mp4" in failed["dangling"]
    assert "not a regular file" in failed["pipe"]
    done = {k for k, c in manifest.items() if c["status"] == "done"}
    assert done == {"good", "seq", NON_UTF8, f"site-{NON_UTF8}/p1"}
    lines = text.splitlines()
    for name in ("a.mp4", "b.mp4", "dangling.mp4", "pipe.mp4"):
        assert sum(name in ln and ln.startswith("failed") for ln in lines) == 1, (name, text)
    assert sum("again" in ln and ln.startswith("skipped") for ln in lines) == 1, text  # the folder loop
    # Non-UTF-8 names: the output folder has the same bytes; the console shows them escaped
    assert b"caf\xe9" in os.listdir(os.fsencode(out))
    assert (out / f"site-{NON_UTF8}" / "p1" / "gammas.json").is_file()
    assert "done    caf\\xe9:" in text


def test_non_utf8_names_round_trip_through_json(hostile: Path, tmp_path: Path) -> None:
    """manifest.json and gammas.json are valid UTF-8 JSON and carry the name's bytes losslessly."""
    out = tmp_path / "out"
    runner.invoke(app, ["enhance", str(hostile / f"{NON_UTF8}.mp4"), "-o", str(out), *GAMMA])
    raw = (out / "manifest.json").read_bytes()
    raw.decode("utf-8")  # strict: the file itself is valid UTF-8
    doc = json.loads(raw)
    assert "surrogateescape" in doc["path_encoding"]
    (entry,) = doc["clips"]
    assert os.fsencode(entry["clip"]) == b"caf\xe9"
    assert os.fsencode(entry["source"]) == os.fsencode(hostile) + b"/caf\xe9.mp4"
    gammas = json.loads((out / NON_UTF8 / "gammas.json").read_bytes().decode("utf-8"))
    assert os.fsencode(gammas["source"]).endswith(b"/caf\xe9.mp4")
    # and any lone surrogate survives: json_bytes is the one encoder of every JSON file we write
    for name in (NON_UTF8, "\udc80\udcff", "ü \udcfe [x]"):
        assert json.loads(json_bytes({"n": name}).decode("utf-8"))["n"] == name


def test_console_shows_any_name_on_one_line() -> None:
    assert printable(NON_UTF8) == "caf\\xe9"
    assert printable("new\nline.mp4") == "new\\nline.mp4"
    assert "\n" not in printable("a\u2028b\rc") and "\u202e" not in printable("evil\u202ecod.mp4")
    assert printable("[red]x[/red].mp4") != "[red]x[/red].mp4"  # markup escaped: shown, not interpreted


def test_non_utf8_names_on_an_ascii_terminal(hostile: Path, tmp_path: Path) -> None:
    """A real process whose stderr is strict ASCII: every name is still printed, no UnicodeEncodeError."""
    make_clip(hostile / "clip ü.mov", n_frames=10, fps=25)
    env = {**os.environ, "PYTHONIOENCODING": "ascii:strict", "LC_ALL": "C", "COLUMNS": "200"}
    proc = subprocess.run(
        colonlight_command("enhance", hostile, "-o", tmp_path / "out", *GAMMA),
        capture_output=True,
        env=env,
        timeout=300,
    )
    err = proc.stderr.decode("ascii")  # strict: the whole output is ASCII
    assert proc.returncode == 1, err
    assert "Traceback" not in err and "UnicodeEncodeError" not in err
    assert "caf\\xe9" in err and "clip \\xfc" in err


def _drop_read_anything() -> None:
    """In the child before exec: drop CAP_DAC_OVERRIDE and CAP_DAC_READ_SEARCH from the bounding set, so that the
    program it runs, even as root, is refused a folder without read permission like any user."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # linux/capability.h: CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP) failed")


@pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="drops Linux capabilities to make a folder unreadable for root"
)
def test_unreadable_folder_is_one_line_and_the_rest_is_done(tmp_path: Path) -> None:
    root = tmp_path / "videos"
    make_clip(root / "ok" / "c1.mp4", n_frames=20, fps=25)
    make_clip(root / "locked" / "c2.mp4", n_frames=20, fps=25)
    out = tmp_path / "out"
    (root / "locked").chmod(0)
    try:
        probe = subprocess.run(["ls", str(root / "locked")], preexec_fn=_drop_read_anything, capture_output=True)
        if probe.returncode == 0:
            pytest.skip("cannot make a folder unreadable here (capabilities cannot be dropped)")
        proc = subprocess.run(
            colonlight_command("enhance", root, "-o", out, *GAMMA),
            preexec_fn=_drop_read_anything,
            capture_output=True,
            text=True,
            timeout=300,
        )
    finally:
        (root / "locked").chmod(0o755)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "locked" in ln]
    assert lines == [f"failed  {root / 'locked'}: cannot search this folder: permission denied"], proc.stderr
    doc = json.loads((out / "manifest.json").read_text())
    assert [c["clip"] for c in doc["clips"]] == ["ok/c1"] and doc["clips"][0]["status"] == "done"
    assert doc["problems"] == [
        {
            "path": str(root / "locked"),
            "status": "failed",
            "error": f"{root / 'locked'}: cannot search this folder: permission denied",
        }
    ]


def test_files_vanishing_between_discovery_and_processing(tmp_path: Path) -> None:
    """A video and a frame folder deleted (and a video replaced by a folder) after discovery: each fails with one
    line naming it; the clip after them is done."""
    root = tmp_path / "videos"
    for name in ("a", "b", "c", "e"):
        make_clip(root / f"{name}.mp4", n_frames=20, fps=25)
    make_image_folder(root / "d", n=6)
    found = discover([root], tmp_path / "out")
    assert [j.name for j in found.jobs] == ["d", "a", "b", "c", "e"]  # frame folders first
    jobs = sorted(found.jobs, key=lambda j: j.name)  # a runs first: d vanishes before its turn

    def vandal(event: str, clip: str, data: dict[str, object]) -> None:
        if event == "start" and clip == "a":
            (root / "b.mp4").unlink()
            (root / "c.mp4").unlink()
            (root / "c.mp4").mkdir()
            for p in (root / "d").iterdir():
                p.unlink()
            (root / "d").rmdir()

    outcomes = run_batch(jobs, MethodSpec.of("gamma"), ClipOptions(), tmp_path / "out", progress=vandal)
    status = {o.name: (o.status, o.error or "") for o in outcomes}
    assert status["a"][0] == "done" and status["e"][0] == "done"
    for name, shown in (("d", "d"), ("b", "b.mp4"), ("c", "c.mp4")):
        assert status[name][0] == "failed", status
        assert shown in status[name][1] and "\n" not in status[name][1]
    assert any(w in status["b"][1] for w in ("not found", "no such file")), status["b"]
    assert any(w in status["c"][1] for w in ("directory", "folder")), status["c"]
    assert manifest_of(tmp_path / "out")["b"]["status"] == "failed"


def test_the_output_folder_inside_an_input_is_never_read_as_input(tmp_path: Path) -> None:
    root = tmp_path / "videos"
    make_clip(root / "c1.mp4", n_frames=20, fps=25)
    out = root / "enhanced"
    for _ in range(2):  # the second run finds the first run's frame folders inside videos/
        result = runner.invoke(app, ["enhance", str(root), "-o", str(out), *GAMMA])
        assert result.exit_code == 0, result.output
        assert set(manifest_of(out)) == {"c1"}, result.output
    # nor is another colonlight output folder inside the input (it holds the lock file): one line says so
    result = runner.invoke(app, ["enhance", str(root), "-o", str(tmp_path / "elsewhere"), *GAMMA])
    assert result.exit_code == 0, result.output
    assert set(manifest_of(tmp_path / "elsewhere")) == {"c1"}
    assert f"skipped {out}: skipped: a colonlight output folder" in result.output
    # and the output folder given through a link is the same folder
    os.symlink(out, tmp_path / "link-to-out")
    result = runner.invoke(app, ["enhance", str(root), "-o", str(tmp_path / "link-to-out"), *GAMMA])
    assert result.exit_code == 0 and set(manifest_of(out)) == {"c1"}, result.output


def test_an_input_folder_without_clips_beside_others_is_one_skipped_line(tmp_path: Path) -> None:
    """``enhance a/ b/`` with nothing in ``b/`` (a mistyped mount, a copy not yet done) went unremarked; one
    line now says so, the manifest keeps it, and the clips of ``a/`` are enhanced (exit 0)."""
    make_clip(tmp_path / "a" / "c1.mp4", n_frames=20, fps=25)
    (tmp_path / "b" / "sub").mkdir(parents=True)
    (tmp_path / "b" / "notes.txt").write_text("not a clip")
    out = tmp_path / "out"
    result = runner.invoke(app, ["enhance", str(tmp_path / "a"), str(tmp_path / "b"), "-o", str(out), *GAMMA])
    assert result.exit_code == 0, result.output
    assert f"skipped {tmp_path / 'b'}: skipped: no clips in this folder" in result.output
    doc = json.loads((out / "manifest.json").read_text())
    assert set(manifest_of(out)) == {"c1"}
    assert doc["problems"] == [
        {
            "path": str(tmp_path / "b"),
            "error": f"{tmp_path / 'b'}: skipped: no clips in this folder",
            "status": "skipped",
        }
    ]
    # alone, the folder is the usual error, said once
    result = runner.invoke(app, ["enhance", str(tmp_path / "b"), "-o", str(tmp_path / "out2"), *GAMMA])
    assert result.exit_code == 1 and result.output.count("no clips") == 1, result.output


def test_deep_and_looping_trees_end(tmp_path: Path) -> None:
    """A folder 1200 levels deep (deeper than Python's recursion limit) and a loop of folder links."""
    root = tmp_path / "videos"
    root.mkdir()
    levels = [root]
    try:
        for _ in range(1200):  # not os.makedirs: it recurses
            levels.append(levels[-1] / "d")
            levels[-1].mkdir()
        make_clip(levels[-1] / "c.mp4", n_frames=20, fps=25)
        (root / "x").mkdir()
        os.symlink("../y", root / "x" / "to-y")
        (root / "y").mkdir()
        os.symlink("../x", root / "y" / "to-x")
        found = discover([root], tmp_path / "out")
        assert [len(Path(j.name).parts) for j in found.jobs] == [1201]
        assert all(not p.failed for p in found.problems) and len(found.problems) == 2
    finally:
        # pytest's clean-up of old temporary folders recurses (shutil.rmtree on Python 3.11) and would overflow
        # on this tree in a later run, so the tree is taken down here, deepest folder first.
        (levels[-1] / "c.mp4").unlink(missing_ok=True)
        for level in reversed(levels[1:]):
            level.rmdir()


def test_dot_and_dotdot_inputs_never_write_outside_their_clip_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``colonlight enhance .`` inside a frame folder: the clip is named after the folder, not "." (which would
    write its frames into OUT itself) nor ".." (above OUT)."""
    seq = tmp_path / "seq"
    make_image_folder(seq, n=4)
    monkeypatch.chdir(seq)
    (seq / "sub").mkdir()
    for given in (Path("."), Path("../seq/../seq"), Path("sub/..")):
        (job,) = discover([given], tmp_path / "out").jobs
        assert job.name == "seq" and job.out_dir == tmp_path / "out" / "seq", job
