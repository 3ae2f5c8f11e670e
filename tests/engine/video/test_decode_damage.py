"""Damage part way through a clip (packets overwritten mid-stream) is decoded past as the ``ffmpeg`` tool decodes
past it: the frames ``ffmpeg -vf fps=18`` outputs on the damaged file are ours, pixel for pixel outside the damaged
stretch (inside it the ffmpeg tool's own concealment varies from run to run), and ours are the same every run.
The decoder rejecting a packet used to end the clip there (an mp4 kept 30 of 72 frames and failed, an avi 19 of
71)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.errors import InputError
from colonlight.video import DecodeReport, iter_video_frames

from ...media import X264, corrupted_copy, ffmpeg_exe, ffmpeg_frames, make_clip, needs_ffmpeg, read_index

MPEG4 = ("-c:v", "mpeg4", "-q:v", "2")
VP8 = ("-c:v", "libvpx", "-b:v", "1M")
GOP = ("-g", "10")  # a keyframe every 10 frames: decoding picks up again soon after the damage

CONTAINERS: dict[str, Callable[[Path], Path]] = {
    "mp4": lambda d: make_clip(d / "c.mp4", 100, 25, codec_args=X264, output_args=GOP),
    "mkv": lambda d: make_clip(d / "c.mkv", 100, 25, codec_args=X264, output_args=GOP),
    "ts": lambda d: make_clip(d / "c.ts", 100, 25, codec_args=X264, output_args=GOP),
    "avi": lambda d: make_clip(d / "c.avi", 100, 25, codec_args=MPEG4, output_args=GOP),
    "webm": lambda d: make_clip(d / "c.webm", 100, 25, codec_args=VP8, output_args=GOP),
}


@pytest.fixture(scope="module")
def sources(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    if ffmpeg_exe() is None:
        pytest.skip("imageio-ffmpeg's ffmpeg binary is not available")
    root = tmp_path_factory.mktemp("damage")
    return {name: make(root) for name, make in CONTAINERS.items()}


#: Output frames that may differ from ffmpeg's around the damage: the damaged packets and the frames that refer to
#: them, up to the next keyframes (a GOP is 10 source frames at 25 fps: 7 at 18 fps; three GOPs of slack).
DAMAGE_SPAN = 21


@needs_ffmpeg
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("name", list(CONTAINERS))
def test_damage_mid_stream_gives_ffmpegs_frames(sources: dict[str, Path], tmp_path: Path, name: str, seed: int) -> None:
    """Before the damage and from the next clean keyframes on, every frame is ffmpeg's (pixels for H.264 and
    MPEG-4, frame choice for VP8). Inside the damaged stretch the concealed frames may differ: ffmpeg's frame
    threads (and libvpx's) conceal a damaged frame differently from run to run of the ffmpeg tool itself."""
    src = sources[name]
    bad = corrupted_copy(src, tmp_path / f"bad{src.suffix}", start=0.4, length=0.02, seed=seed)
    reference = list(ffmpeg_frames(bad, vf="fps=18"))
    report = DecodeReport()
    ours = [f.image for f in iter_video_frames(bad, 18, report=report)]  # no exception: decoded past the damage
    assert len(reference) >= 70  # ffmpeg went on to the end (100 frames at 25 fps: 72 at 18 fps)
    assert len(ours) == len(reference)
    if name == "webm":
        same = [read_index(a) == read_index(b) for a, b in zip(ours, reference, strict=True)]
    else:
        same = [np.array_equal(a, b) for a, b in zip(ours, reference, strict=True)]
    differ = [i for i, ok in enumerate(same) if not ok]
    assert not differ or (differ[0] >= 20 and differ[-1] - differ[0] < DAMAGE_SPAN), differ
    assert read_index(ours[-1]) == read_index(reference[-1]) >= 95  # the frames after the damage too
    again = [f.image for f in iter_video_frames(bad, 18, report=DecodeReport())]
    assert all(np.array_equal(a, b) for a, b in zip(ours, again, strict=True))  # ours are the same every run


@needs_ffmpeg
def test_cli_keeps_a_damaged_clip_with_a_warning(sources: dict[str, Path], tmp_path: Path) -> None:
    videos = tmp_path / "videos"
    videos.mkdir()
    bad = corrupted_copy(sources["mp4"], videos / "damaged.mp4", start=0.4, length=0.02, seed=0)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q"])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning")]
    assert len(warnings) == 1 and str(bad) in warnings[0] and "damaged" in warnings[0], result.output
    gammas = json.loads((out / "damaged" / "gammas.json").read_text())
    assert gammas["frame_count"] == len(list(ffmpeg_frames(bad, vf="fps=18")))
    assert "truncated" not in gammas and any("damaged" in w for w in gammas["warnings"])
    entry = json.loads((out / "manifest.json").read_text())["clips"][0]
    assert entry["status"] == "done" and entry["frames"] == gammas["frame_count"]


@needs_ffmpeg
def test_a_stream_the_decoder_refuses_is_said_for_what_it_is(tmp_path: Path) -> None:
    """A valid clip whose every packet the decoder refuses (libavcodec will not open Theora at 17x9) fails in one
    line with the decoder's own reason, not as "truncated or corrupt?", which sent the user looking for damage;
    the batch goes on with the next clip."""
    videos = tmp_path / "videos"
    odd = make_clip(videos / "odd.ogv", 20, 25, size=(17, 9), codec_args=("-c:v", "libtheora"))
    make_clip(videos / "fine.mkv", 20, 25)
    try:
        decoded = len(list(iter_video_frames(odd, 18)))
    except InputError as exc:
        message = str(exc)
    else:
        pytest.skip(f"this build's FFmpeg decodes 17x9 Theora ({decoded} frames): no refused stream to test")
    assert message.startswith(str(odd)) and "\n" not in message, message
    assert "the decoder refused all" in message and "theora decoder cannot be opened for this 17x9" in message
    assert "corrupt" not in message, message
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q"])
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    failed = [line for line in result.output.splitlines() if "odd.ogv" in line]
    assert len(failed) == 1 and "theora decoder cannot be opened" in failed[0], result.output
    assert (out / "fine" / "gammas.json").is_file()
