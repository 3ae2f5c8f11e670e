"""A timestamp gap repeats a frame until the next is due (as ``ffmpeg -vf fps=18`` repeats it), one copy at a
time, up to a cap: ``--max-gap-frames`` / ``COLONLIGHT_MAX_GAP_FRAMES`` (default 10 minutes at 18 fps). Past it
the clip fails with one line naming the file and the gap, before the first repeat, and leaves nothing behind.
MPEG-TS/PS jumps of more than 10 s never reach the cap: they are bridged as ffmpeg bridges them
(tests/engine/video/test_decode_timestamps.py, ``jump60.ts``). Before, a 12-minute gap in an mp4 made 12960 frames."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.errors import InputError
from colonlight.limits import DEFAULT_MAX_GAP_FRAMES, MAX_GAP_FRAMES_ENV, max_gap_frames_setting
from colonlight.video import iter_video_frames

from ...media import ffmpeg_fps_indices, make_vfr_clip, needs_ffmpeg


def test_default_cap_is_ten_minutes_at_18_fps(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(MAX_GAP_FRAMES_ENV, raising=False)
    assert max_gap_frames_setting() == DEFAULT_MAX_GAP_FRAMES == 10800
    monkeypatch.setenv(MAX_GAP_FRAMES_ENV, "50")
    assert max_gap_frames_setting() == 50
    monkeypatch.setenv(MAX_GAP_FRAMES_ENV, "many")
    with pytest.raises(ValueError, match=MAX_GAP_FRAMES_ENV):
        max_gap_frames_setting()


@needs_ffmpeg
def test_a_gap_under_the_cap_repeats_as_ffmpeg_does(tmp_path: Path) -> None:
    clip = make_vfr_clip(tmp_path / "gap4.mp4", [0.0, 0.05, 0.1, 4.0, 4.05])  # 4 s gap: 70 repeats at 18 fps
    ours = [f.source_index for f in iter_video_frames(clip, 18, max_gap_frames=80)]
    assert ours == ffmpeg_fps_indices(clip, 18)
    assert ours.count(2) == 70
    with pytest.raises(InputError) as err:
        list(iter_video_frames(clip, 18, max_gap_frames=60))
    message = str(err.value)
    assert message.startswith(f"{clip}: a timestamp gap after source frame 2") and "\n" not in message
    assert "69 times" in message and "--max-gap-frames" in message and MAX_GAP_FRAMES_ENV in message


@needs_ffmpeg
def test_cli_fails_a_clip_past_the_default_cap_and_goes_on(tmp_path: Path) -> None:
    videos = tmp_path / "videos"
    make_vfr_clip(videos / "gap12min.mp4", [0.0, 0.05, 0.1, 720.0, 720.05], size=(64, 48))  # 12960 repeats
    make_vfr_clip(videos / "ok.mp4", [i / 25 for i in range(10)], size=(64, 48))
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q"])
    assert result.exit_code == 1, result.output
    failed = [line for line in result.output.splitlines() if line.startswith("failed")]
    assert len(failed) == 1 and str(videos / "gap12min.mp4") in failed[0] and "10800" in failed[0], result.output
    assert not (out / "gap12min").exists()  # the frames before the gap were removed with the clip
    entries = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}
    assert entries["gap12min"]["status"] == "failed" and "timestamp gap" in entries["gap12min"]["error"]
    assert entries["ok"]["status"] == "done"


@needs_ffmpeg
def test_cli_option_and_variable_set_the_cap(tmp_path: Path) -> None:
    videos = tmp_path / "videos"
    make_vfr_clip(videos / "gap4.mp4", [0.0, 0.05, 0.1, 4.0, 4.05], size=(64, 48))
    base = ["enhance", str(videos), "--method", "none", "-q"]
    low = CliRunner().invoke(app, [*base, "-o", str(tmp_path / "a"), "--max-gap-frames", "60"])
    assert low.exit_code == 1 and "more than the cap of 60" in low.output, low.output
    env = CliRunner().invoke(app, [*base, "-o", str(tmp_path / "b")], env={MAX_GAP_FRAMES_ENV: "60"})
    assert env.exit_code == 1 and "more than the cap of 60" in env.output, env.output
    ok = CliRunner().invoke(app, [*base, "-o", str(tmp_path / "c"), "--max-gap-frames", "70"])
    assert ok.exit_code == 0, ok.output
    expected = len(ffmpeg_fps_indices(videos / "gap4.mp4", 18))
    assert json.loads((tmp_path / "c" / "gap4" / "gammas.json").read_text())["frame_count"] == expected
    bad = CliRunner().invoke(app, [*base, "-o", str(tmp_path / "d"), "--max-gap-frames", "0"])
    assert bad.exit_code == 2
