"""Hostile inputs beyond issue 13's list, through ``colonlight enhance`` (tests/service/test_service_hostile_shapes.py
sends the same files to a real server): frames
of 1x1, 3x5 and one pixel row (also turned by rotation metadata), an archive renamed ``.mp4``, and an MP4 whose
index lies (a sample of 10^9 bytes, a timing table claiming 10^9 frames). Each is either a ``done`` clip with the
frames ``ffmpeg -vf fps=18`` gives and an even-sized ``enhanced.mp4`` (x264 pads), or ``failed`` in one line
naming the file, with no traceback and nothing left of it."""

from __future__ import annotations

import json
import struct
import tarfile
import zipfile
from pathlib import Path

import av
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from ..media import ffmpeg_fps_indices, make_clip, needs_ffmpeg, with_rotation

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]

PNG = ("-c:v", "png")
#: name -> size of enhanced.mp4 (even: yuv420p needs it; a 90-degree turn swaps the sides first)
DONE = {"tiny_1x1": (2, 2), "odd_3x5": (4, 6), "row_64x1": (64, 2), "row_63x1_turned": (2, 64), "stts_1e9": (64, 48)}
#: name -> what its one failure line says
FAILED = {"zip": "not a video", "tar": "not a video", "stsz_1e9": "video"}


def patched_mp4(src: Path, dst: Path, box: bytes, offset: int, value: int) -> Path:
    """``src`` with the 32-bit field ``offset`` bytes into its first ``box`` set to ``value`` (a lying index)."""
    data = bytearray(src.read_bytes())
    at = data.find(box)
    assert at > 0, box
    data[at + offset : at + offset + 4] = struct.pack(">I", value)
    dst.write_bytes(bytes(data))
    return dst


def make_shapes(d: Path) -> Path:
    """The hostile files in ``d / "videos"`` (named as in :data:`DONE` and :data:`FAILED`); that folder."""
    v = d / "videos"
    v.mkdir()
    make_clip(v / "tiny_1x1.mkv", 20, 25, size=(1, 1), codec_args=PNG)
    make_clip(v / "odd_3x5.mkv", 20, 25, size=(3, 5), codec_args=PNG)
    make_clip(v / "row_64x1.mkv", 20, 25, size=(64, 1), codec_args=PNG)
    with_rotation(make_clip(d / "row_63x1.mkv", 20, 25, size=(63, 1), codec_args=PNG), v / "row_63x1_turned.mkv", 90)
    ok = make_clip(d / "ok.mp4", 20, 25, size=(64, 48))
    with zipfile.ZipFile(v / "zip.mp4", "w") as z:
        z.write(ok, "ok.mp4")
    with tarfile.open(v / "tar.mp4", "w") as t:
        t.add(ok, "ok.mp4")
    patched_mp4(ok, v / "stsz_1e9.mp4", b"stsz", 16, 10**9)  # the first sample "is" 1 GB long
    patched_mp4(ok, v / "stts_1e9.mp4", b"stts", 12, 10**9)  # 10^9 samples of one duration, 20 in the file
    return v


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_shapes(tmp_path_factory.mktemp("hostile-shapes"))


def test_cli_enhances_or_fails_each_in_one_line(clips: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["enhance", str(clips), "-o", str(out), "--video", "--method", "none"])
    assert result.exit_code == 1, result.output  # some clips failed, the batch went on
    assert "Traceback" not in result.output
    entries = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}
    assert set(entries) == set(DONE) | set(FAILED)
    for name, size in DONE.items():
        assert entries[name]["status"] == "done", entries[name]
        source = next(clips.glob(name + ".*"))
        expected = len(ffmpeg_fps_indices(source, 18)) if name == "stts_1e9" else 14  # 20 frames at 25 fps
        assert json.loads((out / name / "gammas.json").read_text())["frame_count"] == expected, name
        with av.open(str(out / name / "enhanced.mp4"), mode="r") as c:
            s = c.streams.video[0]
            assert (s.codec_context.width, s.codec_context.height) == size, name
            assert sum(1 for _ in c.decode(video=0)) == expected, name
    lines = [line for line in result.output.splitlines() if line.startswith("failed")]
    for name, cause in FAILED.items():
        assert entries[name]["status"] == "failed" and cause in entries[name]["error"], entries[name]
        assert not (out / name).exists(), name
        assert [line for line in lines if f"{name}.mp4" in line and cause in line], result.output
