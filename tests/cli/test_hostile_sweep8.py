"""Hostile-input sweep 8: real video files of unusual but legal kinds, and damaged ones, made with the ffmpeg
binary, through ``colonlight enhance`` (tests/service/test_service_hostile_sweep8.py uploads the same kinds).

Legal clips of rare pixel formats and codecs (alpha, 16-bit grey, 10-bit 4:2:2, 10-bit HEVC, AV1, VP9 with
alpha, MJPEG, ProRes, one-pixel and 4000x16 frames) give the frames ``ffmpeg -vf fps=18`` gives. The defects
found: a file with two video streams gave the smaller one (libavformat's "best" stream, by bit rate) where
``ffmpeg`` takes the larger; a short note or data file beginning with ``I`` or a tab was taken for CD+G karaoke
graphics, a one-frame "clip" that failed the batch; an MP4 cut inside its index said "contains no video
stream", "no decoder for its video codec" or "the file ends before its first frame" instead of "truncated".
"""

from __future__ import annotations

import functools
import json
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from ..commands import colonlight_env
from ..media import X264, ffmpeg_exe, ffmpeg_fps_indices, ffmpeg_frames, make_clip, needs_ffmpeg, read_index

pytestmark = [needs_ffmpeg, pytest.mark.timeout(120)]


@functools.cache
def encoders() -> frozenset[str]:
    """The encoders of the ffmpeg binary the clips are made with."""
    exe = ffmpeg_exe()
    assert exe is not None
    out = subprocess.run([exe, "-hide_banner", "-encoders"], capture_output=True, text=True, check=False).stdout
    return frozenset(line.split()[1] for line in out.splitlines() if line.startswith(" V") and len(line.split()) > 1)


def enhance(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["enhance", *args, "--method", "none", "-q"])
    assert "Traceback" not in result.output, result.output
    return result.exit_code, result.output


def manifest(out: Path) -> dict[str, dict]:
    return {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}


def frames_of(out: Path, clip: str) -> list[np.ndarray]:
    return [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in sorted((out / clip / "frames").iterdir())]


# ---------------------------------------------------------------------------------------- legal, rare formats

LOSSLESS = ("-c:v", "libx264", "-preset", "ultrafast", "-qp", "0", "-pix_fmt", "yuv420p")
FAST_VP9 = ("-deadline", "realtime", "-cpu-used", "8", "-b:v", "1M")
HEVC = ("-c:v", "libx265", "-preset", "ultrafast", "-x265-params", "log-level=error")
#: file name -> (the encoder it needs, its codec arguments, frame size)
EXOTIC: dict[str, tuple[str, tuple[str, ...], tuple[int, int]]] = {
    "yuv422p10.mkv": ("libx264", ("-c:v", "libx264", "-pix_fmt", "yuv422p10le"), (128, 96)),
    "gray16.mkv": ("ffv1", ("-c:v", "ffv1", "-pix_fmt", "gray16le"), (128, 96)),
    "argb.mov": ("qtrle", ("-c:v", "qtrle", "-pix_fmt", "argb"), (128, 96)),
    "rgba_png.mov": ("png", ("-c:v", "png", "-pix_fmt", "rgba"), (128, 96)),
    "vp9_alpha.webm": ("libvpx-vp9", ("-c:v", "libvpx-vp9", "-pix_fmt", "yuva420p", *FAST_VP9), (128, 96)),
    "hevc10.mp4": ("libx265", (*HEVC, "-pix_fmt", "yuv420p10le"), (128, 96)),
    "av1.webm": ("libsvtav1", ("-c:v", "libsvtav1", "-preset", "12"), (128, 96)),
    "mjpeg.avi": ("mjpeg", ("-c:v", "mjpeg", "-q:v", "3"), (128, 96)),
    "prores.mov": ("prores_ks", ("-c:v", "prores_ks"), (128, 96)),
    "px1x1.mp4": ("libx264", ("-c:v", "libx264", "-pix_fmt", "yuv444p"), (1, 1)),
    "wide4000x16.mp4": ("libx264", X264, (4000, 16)),
}


@pytest.mark.parametrize("name", list(EXOTIC))
def test_rare_pixel_formats_codecs_and_sizes_give_ffmpegs_frames(tmp_path: Path, name: str) -> None:
    """No defect here (each already matched): kept so that the formats earlier sweeps never made stay covered."""
    encoder, codec_args, size = EXOTIC[name]
    if encoder not in encoders():
        pytest.skip(f"the ffmpeg binary has no {encoder} encoder")
    path = make_clip(tmp_path / name, 30, 25, size=size, codec_args=codec_args)
    out = tmp_path / "out"
    code, output = enhance(str(path), "-o", str(out), "--video")
    assert code == 0, output
    clip = path.stem
    ours, theirs = frames_of(out, clip), list(ffmpeg_frames(path, vf="fps=18"))
    assert len(ours) == len(theirs) == json.loads((out / clip / "gammas.json").read_text())["frame_count"]
    for a, b in zip(ours, theirs, strict=True):
        assert a.shape == b.shape
        diff = np.abs(a.astype(int) - b.astype(int))  # 10 bits to 8: rounding may differ by a level or so
        assert diff.max() <= 4 and diff.mean() < 0.1, (diff.max(), diff.mean())


# -------------------------------------------------------------------------------------- two video streams


def make_two_stream_clip(d: Path, container: str) -> tuple[Path, Path]:
    """``d/two.<container>``: a 128x96 recording beside a 64x48 preview of a higher bit rate (lossless); in the
    mkv the preview comes first, after a thumbnail track (one 64x64 PNG frame). The file and the recording."""
    big = make_clip(d / "big.mp4", 50, 25)
    small = make_clip(d / "small.mp4", 60, 30, size=(64, 48), first_index=1000, codec_args=LOSSLESS)
    thumbnail = d / "thumbnail.png"
    cv2.imwrite(str(thumbnail), np.full((64, 64, 3), 200, np.uint8))
    clip = d / "videos" / f"two.{container}"
    clip.parent.mkdir(exist_ok=True)
    if container == "mkv":
        inputs = ["-i", str(thumbnail), "-i", str(small), "-i", str(big)]
        maps = ["-map", "0", "-map", "1", "-map", "2"]
    else:
        inputs, maps = ["-i", str(big), "-i", str(small)], ["-map", "0", "-map", "1"]
    exe = ffmpeg_exe()
    assert exe is not None
    subprocess.run(
        [exe, "-hide_banner", "-loglevel", "error", *inputs, *maps, "-c", "copy", "-y", str(clip)], check=True
    )
    return clip, big


@pytest.mark.parametrize("container", ["mkv", "mp4"])
def test_the_clip_is_the_video_stream_ffmpeg_maps(tmp_path: Path, container: str) -> None:
    """libavformat's "best" stream is the preview (first in the mkv, the higher bit rate in the mp4), and it was
    enhanced; ``ffmpeg -i`` and now colonlight take the larger picture."""
    clip, big = make_two_stream_clip(tmp_path, container)
    out = tmp_path / "out"
    code, output = enhance(str(clip), "-o", str(out))
    assert code == 0, output
    frames = frames_of(out, "two")
    assert {f.shape for f in frames} == {(96, 128, 3)}
    assert [read_index(f) for f in frames] == ffmpeg_fps_indices(big, 18)


def test_stream_reads_a_file_from_the_same_video_stream(tmp_path: Path) -> None:
    """``colonlight stream FILE`` took the first video stream (the thumbnail track in this mkv)."""
    clip, big = make_two_stream_clip(tmp_path, "mkv")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "colonlight_cli.main", "stream", str(clip), "-o", str(out), "--method", "none"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=colonlight_env(), timeout=90, check=False)
    assert proc.returncode == 0, proc.stderr
    frames = [cv2.imread(str(f)) for f in sorted((out / "frames").iterdir())]
    assert {f.shape for f in frames} == {(96, 128, 3)}
    assert [read_index(f[..., ::-1]) for f in frames] == ffmpeg_fps_indices(big, 18)


# ----------------------------------------------------------------------------------- tiny non-video files


def test_short_notes_and_data_files_are_not_taken_for_clips(tmp_path: Path) -> None:
    """FFmpeg's CD+G probe takes a file of 24-47 bytes whose first byte ends in the bits 001001 (``I``, a tab):
    such a note was a "clip" of one frame, which failed the batch (exit 1) among data files that are no videos."""
    videos = tmp_path / "videos"
    make_clip(videos / "clip.mp4", 20, 25)
    (videos / "NOTES").write_text("In this folder: two clips of 2024.\n")
    (videos / "readme").write_text("\tsee the clips beside this file\n")
    rng = np.random.default_rng(8)
    data = videos / "data"
    data.mkdir()
    for i in range(300):
        blob = bytearray(rng.integers(0, 256, 16 + i % 300, dtype=np.uint8).tobytes())
        if i % 10 == 0:
            blob[0] = 0x09  # CD+G's command byte
            blob[24 : 24 * (len(blob) // 24) : 24] = b"\x09" * (len(blob) // 24 - 1)
        (data / f"sample{i}.bin").write_bytes(bytes(blob))
    out = tmp_path / "out"
    code, output = enhance(str(videos), "-o", str(out))
    assert code == 0, output
    assert list(manifest(out)) == ["clip"], output
    code, output = enhance(str(videos / "NOTES"), "-o", str(tmp_path / "out2"))  # named: refused in one line
    assert code == 1 and f"{videos / 'NOTES'}: not a video" in output, output


# ----------------------------------------------------------------------------------- an MP4 cut in its index


def cut_in_index(src: Path, dst: Path, fraction: float) -> int:
    """``dst``: ``src`` (an MP4) cut ``fraction`` of the way into its 'moov' box; the length kept."""
    data, pos = src.read_bytes(), 0
    while data[pos + 4 : pos + 8] != b"moov":
        pos += struct.unpack(">I", data[pos : pos + 4])[0]
    at = pos + int(struct.unpack(">I", data[pos : pos + 4])[0] * fraction)
    dst.write_bytes(data[:at])
    return at


@pytest.mark.parametrize("faststart", [False, True], ids=["index-last", "faststart"])
def test_an_mp4_cut_inside_its_index_fails_saying_so(tmp_path: Path, faststart: bool) -> None:
    """Cut anywhere in its 'moov' box, an MP4 failed as "contains no video stream", "no decoder for its video
    codec" or "no video frames: the file ends before its first frame", by where the cut fell."""
    args = ["-movflags", "+faststart"] if faststart else []
    src = make_clip(tmp_path / "src.mp4", 60, 25, size=(32, 32), output_args=args)
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "whole.mp4").write_bytes(src.read_bytes())
    cuts = {f"cut{k}": cut_in_index(src, videos / f"cut{k}.mp4", k / 10) for k in range(1, 10)}
    out = tmp_path / "out"
    code, output = enhance(str(videos), "-o", str(out))
    assert code == 1, output
    entries = manifest(out)
    assert entries["whole"]["status"] == "done"
    failed = [line for line in output.splitlines() if line.startswith("failed")]
    assert len(failed) == len(cuts), output
    for name, at in cuts.items():
        assert entries[name]["status"] == "failed" and not (out / name).exists(), entries[name]
        line = next(line for line in failed if f"{videos / name}.mp4:" in line)
        assert f"truncated MP4/MOV: the file ends at byte {at}, inside its index" in line, line


def _ivf_frame_offsets(data: bytes) -> list[int]:
    """Where each frame header (4-byte size, 8-byte pts) of an IVF file starts, after its 32-byte file header."""
    offsets, at = [], 32
    while at + 12 <= len(data):
        offsets.append(at)
        at += 12 + struct.unpack_from("<I", data, at)[0]
    return offsets


@pytest.mark.parametrize("container", ["ivf", "y4m"])
def test_reading_that_stops_mid_file_keeps_the_frames_read_as_ffmpeg_does(tmp_path: Path, container: str) -> None:
    """A damaged IVF frame size (a 4 GB frame) or y4m FRAME marker stops FFmpeg's demuxer part way. ``ffmpeg``
    says "Error during demuxing", ends the input there and writes the frames it has (exit status 0); colonlight
    failed the clip ("reading failed after 23 frames (Cannot allocate memory)"). Now it is done with those frames
    (the decoder's last ones included), marked truncated, with the cause in one warning line."""
    if container == "ivf" and "libvpx" not in encoders():
        pytest.skip("the ffmpeg binary has no libvpx encoder")
    codec = ["-c:v", "libvpx", "-b:v", "500k"] if container == "ivf" else ["-pix_fmt", "yuv420p"]
    good = make_clip(tmp_path / f"good.{container}", n_frames=36, fps=18, codec_args=codec)
    data = bytearray(good.read_bytes())
    if container == "ivf":
        struct.pack_into("<I", data, _ivf_frame_offsets(bytes(data))[25], 0xFFFFFFF0)
    else:
        at = [i for i in range(len(data)) if data[i : i + 6] == b"FRAME\n"][20]
        data[at : at + 5] = b"XXXXX"
    bad = tmp_path / "in" / f"bad.{container}"
    bad.parent.mkdir()
    bad.write_bytes(bytes(data))
    want = ffmpeg_fps_indices(bad, 18)
    assert 0 < len(want) < 36  # ffmpeg stops part way, keeping what it read
    code, out = enhance(str(bad.parent), "-o", str(tmp_path / "out"))
    assert code == 0 and "truncated: reading stopped after" in out and "Traceback" not in out, out
    assert [read_index(f) for f in frames_of(tmp_path / "out", "bad")] == want
    entry = manifest(tmp_path / "out")["bad"]
    assert entry["status"] == "done" and entry.get("truncated") is True, entry
