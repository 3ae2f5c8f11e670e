"""The pixel cap and the fps cap: what one clip may ask of a machine.

The pixel cap (``--max-pixels`` / ``COLONLIGHT_MAX_PIXELS``, default ``limits.DEFAULT_MAX_PIXELS``) is checked
from the stream header, or an image's header, before a frame is decoded: a clip whose pixel data cannot be
decoded at all is still refused as too large, which shows that nothing was decoded. The CLI names the clip,
marks it failed and goes on with the others. ``--fps`` has the service's bound, ``limits.MAX_FPS``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.errors import FrameTooLargeError, InputError
from colonlight.frames import iter_image_folder
from colonlight.limits import DEFAULT_MAX_PIXELS, MAX_FPS, MAX_PIXELS_ENV, max_pixels_setting
from colonlight.pipeline import ClipOptions
from colonlight.sources import check_frame_size, clip_frames
from colonlight.video import is_video, iter_video_frames, probe_frame_size

from ...media import joined, make_clip, make_image_folder, make_solid_clip, needs_ffmpeg, remux

runner = CliRunner()


def invoke(*args: object, env: dict[str, str] | None = None) -> tuple[int, str]:
    result = runner.invoke(app, [str(a) for a in args], env=env)
    return result.exit_code, result.output


def _undecodable(src: Path, dst: Path, keep: int) -> Path:
    """``src`` with every byte after the first ``keep`` replaced by noise: the header stays, the frames are gone."""
    data = bytearray(src.read_bytes())
    data[keep:] = np.random.default_rng(3).integers(0, 256, len(data) - keep, dtype=np.uint8).tobytes()
    dst.write_bytes(bytes(data))
    return dst


@pytest.fixture(scope="module")
def bomb(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two 6000x6000 H.264 frames (36 Mpx, over the default cap) in ~70 kB: a decompression bomb."""
    return make_solid_clip(tmp_path_factory.mktemp("bomb") / "bomb.mp4", (6000, 6000))


# ------------------------------------------------------------------------------------------------ the setting


def test_max_pixels_setting_reads_the_environment() -> None:
    assert max_pixels_setting({}) == DEFAULT_MAX_PIXELS > 3840 * 2160
    assert max_pixels_setting({MAX_PIXELS_ENV: " 2000000 "}) == 2_000_000
    for bad in ("0", "-5", "lots", "1e6"):
        with pytest.raises(ValueError, match=MAX_PIXELS_ENV):
            max_pixels_setting({MAX_PIXELS_ENV: bad})


def test_clip_options_take_the_cap_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(MAX_PIXELS_ENV, "12345")
    assert ClipOptions().max_pixels == 12345
    assert ClipOptions(max_pixels=99).max_pixels == 99
    with pytest.raises(ValueError):
        ClipOptions(max_pixels=0)


# -------------------------------------------------------------------------------------------------- videos


@needs_ffmpeg
def test_bomb_is_refused_from_its_header_with_little_memory(bomb: Path) -> None:
    """In a fresh process: the header check of a 36 Mpx clip stays far below one decoded frame (54 MB YUV,
    108 MB RGB); decoding as libavformat's stream probe does would take more than 100 MB."""
    code = (
        "import resource, sys\n"
        "from colonlight.errors import FrameTooLargeError\n"
        "from colonlight.sources import check_frame_size\n"
        "base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "try:\n"
        "    check_frame_size(sys.argv[1])\n"
        "except FrameTooLargeError as e:\n"
        "    print(e.width, e.height, e.max_pixels, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != MAX_PIXELS_ENV}
    out = subprocess.run(
        [sys.executable, "-c", code, str(bomb)], capture_output=True, text=True, env=env, timeout=120, check=True
    ).stdout.split()
    assert out[:3] == ["6000", "6000", str(DEFAULT_MAX_PIXELS)], out
    assert int(out[3]) * 1024 < 40e6, f"the header check grew memory by {int(out[3]) / 1024:.0f} MB"


@needs_ffmpeg
def test_frames_growing_past_the_cap_mid_stream_are_not_decoded(tmp_path: Path, bomb: Path) -> None:
    """A small recording joined to a bomb: the header is small, the decoder itself refuses the large frames."""
    clip = joined([make_clip(tmp_path / "small.ts", 20, 25), remux(bomb, tmp_path / "bomb.ts")], tmp_path / "mix.ts")
    code = (
        "import resource, sys\n"
        "from colonlight.errors import InputError\n"
        "from colonlight.video import iter_video_frames\n"
        "base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "n = 0\n"
        "try:\n"
        "    for f in iter_video_frames(sys.argv[1], 18):\n"
        "        n += 1\n"
        "except InputError as e:\n"
        "    print(n, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base, e)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != MAX_PIXELS_ENV}
    out = subprocess.run(
        [sys.executable, "-c", code, str(clip)], capture_output=True, text=True, env=env, timeout=120, check=True
    ).stdout.split(maxsplit=2)
    assert len(out) == 3 and int(out[0]) <= 15 and out[2].startswith(str(clip)), out
    assert int(out[1]) * 1024 < 80e6, f"decoding grew memory by {int(out[1]) / 1024:.0f} MB: a 36 Mpx frame was made"


@needs_ffmpeg
def test_header_check_does_not_decode(tmp_path: Path) -> None:
    clip = make_clip(tmp_path / "c.mkv", 20, 25, size=(320, 240))
    broken = _undecodable(clip, tmp_path / "broken.mkv", keep=600)  # header and codec setup kept
    assert probe_frame_size(broken, 10**6) == (320, 240)
    with pytest.raises(FrameTooLargeError) as err:
        check_frame_size(broken, 320 * 240 - 1)
    assert (err.value.width, err.value.height, err.value.max_pixels) == (320, 240, 320 * 240 - 1)
    assert str(broken) in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(FrameTooLargeError):
        next(iter_video_frames(broken, 18, max_pixels=1000))
    with pytest.raises(InputError) as err2:  # without the cap it is the frames that fail
        list(iter_video_frames(broken, 18))
    assert not isinstance(err2.value, FrameTooLargeError)


@needs_ffmpeg
def test_a_too_large_video_is_still_a_video(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    clip = make_clip(tmp_path / "big.bin", 10, 25, size=(320, 240), output_args=["-f", "matroska"])
    monkeypatch.setenv(MAX_PIXELS_ENV, "1000")
    assert is_video(clip)  # found by content and reported as a failed clip, not ignored as a non-video
    monkeypatch.delenv(MAX_PIXELS_ENV)
    assert len(list(clip_frames(clip, 18, max_pixels=320 * 240))) == 7


# --------------------------------------------------------------------------------------------------- images


def test_image_folder_is_checked_from_each_image_header(tmp_path: Path) -> None:
    folder = tmp_path / "seq"
    paths = make_image_folder(folder, n=4, size=(64, 48))
    assert check_frame_size(folder, 64 * 48) == (64, 48)
    with pytest.raises(FrameTooLargeError) as err:
        check_frame_size(folder, 64 * 48 - 1)
    assert str(paths[0]) in str(err.value)
    # a later image with a big header and no decodable pixels: refused as too large, never decoded
    ok, png = cv2.imencode(".png", np.zeros((400, 500, 3), np.uint8))
    assert ok
    data = bytearray(png.tobytes())
    data[60:] = b"\0" * (len(data) - 60)  # IHDR (size) kept, image data destroyed
    (folder / "frame2.png").write_bytes(bytes(data))
    frames = iter_image_folder(folder, max_pixels=10_000)
    assert next(frames).index == 0 and next(frames).index == 1
    with pytest.raises(FrameTooLargeError, match="500x400") as err:
        next(frames)
    assert str(folder / "frame2.png") in str(err.value)


# ------------------------------------------------------------------------------------------------------ CLI


@needs_ffmpeg
def test_cli_names_the_large_clip_fails_it_and_goes_on(tmp_path: Path, bomb: Path) -> None:
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "bomb.mp4").write_bytes(bomb.read_bytes())
    make_clip(videos / "fine.mp4", 20, 25, size=(128, 96))
    make_clip(videos / "wide.mkv", 20, 25, size=(320, 240))
    make_image_folder(videos / "seq", n=4, size=(320, 240))
    out = tmp_path / "out"
    env = {MAX_PIXELS_ENV: str(200 * 200)}  # the variable, then the flag (which wins)
    code, text = invoke("enhance", videos, "-o", out, "--method", "none", "-q", env=env)
    assert code == 1, text
    manifest = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}
    assert {k: c["status"] for k, c in manifest.items()} == {
        "bomb": "failed",
        "fine": "done",
        "seq": "failed",
        "wide": "failed",
    }
    assert "6000x6000" in manifest["bomb"]["error"] and "pixel cap of 40000" in manifest["bomb"]["error"]
    assert "320x240" in manifest["wide"]["error"] and str(videos / "wide.mkv") in manifest["wide"]["error"]
    assert str(videos / "seq") in manifest["seq"]["error"]
    for name in ("bomb.mp4", "wide.mkv"):
        assert any(line.startswith("failed") and str(videos / name) in line for line in text.splitlines())
    assert not (out / "bomb" / "frames").exists() or not any((out / "bomb" / "frames").iterdir())
    assert "Traceback" not in text

    code, text = invoke("enhance", videos, "-o", out, "--method", "none", "-q", "--max-pixels", 320 * 240, env=env)
    assert code == 1, text
    manifest = {c["clip"]: c["status"] for c in json.loads((out / "manifest.json").read_text())["clips"]}
    assert manifest == {"bomb": "failed", "fine": "done", "seq": "done", "wide": "done"}


def test_cli_refuses_bad_caps_as_usage_errors(tmp_path: Path) -> None:
    for args, env in ((["--max-pixels", "0"], None), ([], {MAX_PIXELS_ENV: "many"})):
        code, text = invoke("enhance", tmp_path, "-o", tmp_path / "o", "--method", "none", *args, env=env)
        assert code == 2 and "max-pixels" in text.lower(), text


@pytest.mark.parametrize("fps", [MAX_FPS + 0.5, 1000, -1])
def test_cli_fps_has_the_services_bound(tmp_path: Path, fps: float) -> None:
    code, text = invoke("enhance", tmp_path, "-o", tmp_path / "o", "--method", "none", "--fps", fps)
    assert code == 2, text
    assert "--fps" in text and f"{MAX_FPS:g}" in text and "Traceback" not in text
    with pytest.raises(ValueError, match="fps"):
        ClipOptions(fps=fps)
