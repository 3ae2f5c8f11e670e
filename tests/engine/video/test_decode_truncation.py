"""A truncated container of any kind is a clear failure or a ``done`` clip flagged ``truncated``, never silent.

Files are cut at several offsets, as an interrupted copy or recording leaves them. Container metadata (the
RIFF size of an AVI, the Segment size of Matroska/WebM or its elements' sizes in a live recording, whole MPEG-TS
packets, MPEG-PS pack and PES lengths, the sample index or the box sizes of an MP4) is used to warn; the frames
are always those that decode, never a count the container claims. (A cut exactly between two MPEG-PS packs, or
two Matroska elements of a live recording, leaves no trace in the sizes: the offsets below are not such cuts.)
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import av
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.errors import InputError
from colonlight.video import DecodeReport, iter_video_frames

from ...media import ffmpeg_exe, make_clip, needs_ffmpeg, truncated_copy

MPEG4 = ("-c:v", "mpeg4", "-q:v", "2")
VP8 = ("-c:v", "libvpx", "-b:v", "1M")
MPEG2 = ("-c:v", "mpeg2video", "-q:v", "2")
FRAGMENTED = ("-movflags", "frag_keyframe+empty_moov", "-g", "10")

CONTAINERS: dict[str, Callable[[Path], Path]] = {
    "mp4": lambda d: make_clip(d / "c.mp4", 50, 25),
    "mp4_faststart": lambda d: make_clip(d / "fs.mp4", 50, 25, output_args=["-movflags", "+faststart"]),
    "mkv": lambda d: make_clip(d / "c.mkv", 50, 25),
    "mkv_audio": lambda d: make_clip(d / "ca.mkv", 50, 25, audio=True),
    "ts": lambda d: make_clip(d / "c.ts", 50, 25),
    "avi": lambda d: make_clip(d / "c.avi", 50, 25, codec_args=MPEG4),
    "avi_audio": lambda d: make_clip(d / "ca.avi", 50, 25, codec_args=MPEG4, audio=True),
    "webm": lambda d: make_clip(d / "c.webm", 50, 25, codec_args=VP8),
    # a fragmented mp4 (recorders and live encoders write them): no index to check, its boxes' sizes warn
    "mp4_fragmented": lambda d: make_clip(d / "frag.mp4", 50, 25, audio=True, output_args=FRAGMENTED),
    # a live Matroska recording: the Segment's size is unknown, its elements' sizes warn
    "mkv_live": lambda d: make_clip(d / "live.mkv", 50, 25, output_args=("-live", "1")),
    # MPEG program streams: a DVD-style .vob with audio and a plain .mpg; the PES packet lengths warn
    "mpg": lambda d: make_clip(d / "c.mpg", 50, 25, codec_args=MPEG2),
    "vob": lambda d: make_clip(d / "c.vob", 50, 25, codec_args=MPEG2, audio=True, output_args=("-c:a", "mp2")),
}
CUTS = (0.3, 0.6, 0.9)


@pytest.fixture(scope="module")
def sources(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    if ffmpeg_exe() is None:
        pytest.skip("imageio-ffmpeg's ffmpeg binary is not available")
    root = tmp_path_factory.mktemp("containers")
    return {name: make(root) for name, make in CONTAINERS.items()}


def _decode(path: Path) -> tuple[int, DecodeReport]:
    report = DecodeReport()
    return sum(1 for _ in iter_video_frames(path, None, report=report)), report


@needs_ffmpeg
@pytest.mark.parametrize("name", list(CONTAINERS))
def test_complete_files_are_not_flagged(sources: dict[str, Path], name: str) -> None:
    count, report = _decode(sources[name])
    assert count == 50 and report.truncated is None and report.warnings == []


@needs_ffmpeg
@pytest.mark.parametrize("keep", CUTS)
@pytest.mark.parametrize("name", list(CONTAINERS))
def test_truncated_files_fail_clearly_or_are_flagged(
    sources: dict[str, Path], tmp_path: Path, name: str, keep: float
) -> None:
    src = sources[name]
    cut = truncated_copy(src, tmp_path / f"cut{src.suffix}", keep)
    try:
        count, report = _decode(cut)
    except InputError as err:
        message = str(err)
        assert message.startswith(str(cut)) and "\n" not in message
        assert "truncated" in message or "corrupt" in message, message
        return
    assert count <= 50  # (a cut in the audio or the index at the end may leave every frame)
    assert report.truncated, f"{name} cut to {keep:.0%}: {count} frames and no truncation found"
    assert any(w.startswith("truncated:") and f"{count} frames" in w for w in report.warnings)


@needs_ffmpeg
@pytest.mark.parametrize("name", ["mkv", "mpg"])  # each was done silently: 10 of 50 frames, 17 of 50
def test_cli_marks_a_truncated_clip_done_and_truncated_with_a_warning(
    sources: dict[str, Path], tmp_path: Path, name: str
) -> None:
    videos = tmp_path / "videos"
    videos.mkdir()
    suffix = sources[name].suffix
    truncated_copy(sources[name], videos / f"cut{suffix}", 0.3)
    (videos / f"whole{suffix}").write_bytes(sources[name].read_bytes())
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q"])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning")]
    assert warnings and all(str(videos / f"cut{suffix}") in w for w in warnings)  # (a cut mpg also: damaged)
    assert sum(": truncated: " in w for w in warnings) == 1, warnings
    gammas = json.loads((out / "cut" / "gammas.json").read_text())
    assert gammas["truncated"] is True and gammas["warnings"][0].startswith("truncated:")
    assert list(gammas)[-1] == "frames"  # added fields come before the frame list
    whole = json.loads((out / "whole" / "gammas.json").read_text())
    assert "truncated" not in whole and "warnings" not in whole
    manifest = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}
    assert manifest["cut"]["status"] == "done" and manifest["cut"]["truncated"] is True
    assert manifest["cut"]["frames"] == gammas["frame_count"] > 0
    assert "truncated" not in manifest["whole"] and "warnings" not in manifest["whole"]
    rerun = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q"])
    assert rerun.exit_code == 0, rerun.output
    entry = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}["cut"]
    assert entry["skipped"] is True and entry["truncated"] is True  # a skipped clip keeps its flag


@needs_ffmpeg
def test_a_clip_too_short_because_it_was_cut_says_it_is_truncated(tmp_path: Path) -> None:
    """A clip cut inside its second or third frame fails as too short, and says the file is cut: the failure came
    before the container's sizes were compared (after the last frame), and "too short" alone sends the user to a
    recording that was long enough rather than to the cut copy."""
    src = make_clip(tmp_path / "c.mkv", 3, 25, size=(64, 48))
    with av.open(str(src)) as container:
        starts = [packet.pos for packet in container.demux(video=0) if packet.size]  # in decoding order
    videos = tmp_path / "videos"
    videos.mkdir()
    data = src.read_bytes()
    for name, kept in (("one", 1), ("two", 2)):  # two frames 1/25 s apart give one at the default 18 fps
        (videos / f"{name}.mkv").write_bytes(data[: starts[kept] + 1])
    with pytest.raises(InputError, match="too short") as caught:
        next(iter_video_frames(videos / "one.mkv", None, min_frames=2))
    cut = f"the file is truncated: the file ends at byte {starts[1] + 1} but its container says it ends at byte"
    assert cut in str(caught.value) and "\n" not in str(caught.value)
    result = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(tmp_path / "out"), "--method", "none", "-q"])
    assert result.exit_code == 1, result.output
    for name, says in (("one", "too short: 1 frame(s) decoded"), ("two", "its 2 frames span too short a time")):
        (line,) = [line for line in result.output.splitlines() if f"{name}.mkv: " in line]
        assert says in line and "; the file is truncated: the file ends at byte" in line, line
