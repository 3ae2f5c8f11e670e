"""Which files of a folder a batch takes as clips: one list of video suffixes (``colonlight.decoding``) for decoding,
discovery and the service's uploads; a raw H.264 stream (``.h264``) in a folder is a clip, as it is when named
directly, and a broken one is reported like a broken ``.mp4``, not silently left out."""

from __future__ import annotations

import json
from pathlib import Path

from colonlight_cli.main import app
from colonlight_service.uploads import safe_suffix
from typer.testing import CliRunner

from colonlight import VIDEO_SUFFIXES, decoding, discovery, video
from colonlight.discovery import discover

from ...media import make_clip, needs_ffmpeg, text_file

runner = CliRunner()


def _frames(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((folder / "frames").iterdir())}


def test_one_list_of_video_suffixes() -> None:
    assert discovery.VIDEO_SUFFIXES is decoding.VIDEO_SUFFIXES is video.VIDEO_SUFFIXES is VIDEO_SUFFIXES
    assert ".h264" in VIDEO_SUFFIXES and {".mp4", ".mov", ".mkv", ".ts", ".mxf", ".vob"} <= VIDEO_SUFFIXES
    assert safe_suffix("endoscopy.H264") == ".h264"  # an upload keeps the demuxer's hint
    assert safe_suffix("notes.txt") == ""


@needs_ffmpeg
def test_a_raw_h264_file_in_a_folder_is_a_clip_and_a_broken_one_fails(tmp_path: Path) -> None:
    videos = tmp_path / "videos"
    make_clip(videos / "raw.h264", n_frames=12, fps=25, size=(64, 48), output_args=["-f", "h264"])
    make_clip(videos / "clip.mp4", n_frames=12, fps=25, size=(64, 48))
    text_file(videos / "broken.h264")
    text_file(videos / "notes.txt")
    jobs = {job.name: job.source for job in discover([videos], tmp_path / "out").jobs}
    assert jobs == {"broken": videos / "broken.h264", "clip": videos / "clip.mp4", "raw": videos / "raw.h264"}

    out = tmp_path / "out"
    result = runner.invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q"])
    assert result.exit_code == 1, result.output  # one clip failed, the rest done
    assert "Traceback" not in result.output
    clips = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}
    assert {k: c["status"] for k, c in clips.items()} == {"broken": "failed", "clip": "done", "raw": "done"}
    error = clips["broken"]["error"]
    assert "\n" not in error and "broken.h264" in error and "not a video" in error, error
    assert not (out / "broken" / "gammas.json").exists()

    direct = tmp_path / "direct"
    result = runner.invoke(app, ["enhance", str(videos / "raw.h264"), "-o", str(direct), "--method", "none", "-q"])
    assert result.exit_code == 0, result.output
    assert len(_frames(out / "raw")) == 9  # 12 frames at 25 fps, taken at the default 18 fps
    assert _frames(out / "raw") == _frames(direct / "raw")  # the same clip, found or named
