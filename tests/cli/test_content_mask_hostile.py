"""Hostile content masks and `colonlight content` arguments: a mask colonlight (or the C++ host) would read with
wrong levels or shifted is refused in one line naming it, the host never hangs on one, a mask edited while a
batch runs changes neither what the clips are shown nor what is recorded, `content` never writes its mask over
its own clip, and the service never takes a path."""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import shutil
import subprocess
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from colonlight import ClipJob, ClipOptions, ClipOutcome, InputError, MethodSpec, read_content_mask, run_batch
from colonlight.content_mask import BORDER, SCENE, area_image, image_area, pgm_bytes

from ..commands import boxed_text

runner = CliRunner()
W, H = 16, 12


def _mask() -> np.ndarray:
    image = np.zeros((H, W), np.uint8)
    image[2:10, 3:13] = SCENE
    image[4, 5:8] = 128
    return image


def _raster() -> bytes:
    return _mask().tobytes()


#: Files colonlight's reader (OpenCV) and the host read shifted or with other levels, before they were refused.
DAMAGED = {
    "crlf": (f"P5\r\n{W} {H}\r\n255\r\n".encode() + _raster(), "bytes after its header"),
    "comment-after-maxval": (f"P5\n{W} {H}\n255#note\n".encode() + _raster(), "header is damaged"),
    "trailing-bytes": (pgm_bytes(_mask()) + b"\0" * 40, "bytes after its header"),
    "maxval-1": (f"P5\n{W} {H}\n1\n".encode() + (_mask() == SCENE).astype(np.uint8).tobytes(), "maxval"),
    "maxval-128": (f"P5\n{W} {H}\n128\n".encode() + (_mask() // 2).tobytes(), "maxval"),
    "huge-header": (b"P5\n100000 100000\n255\n" + b"\xff" * 64, "bytes after its header"),
}


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic H.264 clip behind a round border with on-screen text (`colonlight synth`)."""
    out = tmp_path_factory.mktemp("syn")
    args = ["synth", str(out), "--frames", "20", "--width", "96", "--height", "72", "--border", "round", "--text"]
    result = runner.invoke(app, [*args, "--seed", "3", "-j", "1"])
    assert result.exit_code == 0, result.output
    return out / "clip_00000"


@pytest.mark.parametrize("name", sorted(DAMAGED))
def test_a_damaged_binary_pgm_mask_is_refused_naming_it(tmp_path: Path, name: str) -> None:
    data, says = DAMAGED[name]
    path = tmp_path / "mask.pgm"
    path.write_bytes(data)
    with pytest.raises(InputError, match=says) as caught:
        read_content_mask(path)
    assert str(caught.value).startswith(f"{path}: ") and "\n" not in str(caught.value)
    path.write_bytes(pgm_bytes(_mask()))  # the same mask written right reads
    assert read_content_mask(path).fov.sum() == np.count_nonzero(_mask())


def test_a_jpeg_mask_is_refused_as_lossy(tmp_path: Path) -> None:
    """A JPEG's scene pixels near an edge are 250-254, not 255: read as text, they would be left unenhanced."""
    mask = np.zeros((72, 96), np.uint8)
    cv2.circle(mask, (48, 36), 30, 255, -1)
    for suffix in (".jpg", ".png"):  # the format is in the bytes, not the name
        path = tmp_path / f"mask{suffix}"
        path.write_bytes(cv2.imencode(".jpg", mask, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes())
        with pytest.raises(InputError, match="JPEG content mask is lossy") as caught:
            read_content_mask(path)
        assert str(path) in str(caught.value)


def test_a_lossy_webp_mask_is_refused_as_lossy(tmp_path: Path) -> None:
    """A lossy WebP ('VP8 ', alone or in an extended file beside its alpha) changes levels near edges as a JPEG
    does; it was read, and refused as "not a colour image" at best. A lossless one ('VP8L') reads exactly."""
    mask = _mask()
    alpha = np.where(mask == BORDER, 0, 255).astype(np.uint8)  # transparent border: an extended file (VP8X, ALPH)
    for name, image in (("grey", mask), ("alpha", np.dstack([mask, mask, mask, alpha]))):
        path = tmp_path / f"{name}.webp"
        assert cv2.imwrite(str(path), image, [cv2.IMWRITE_WEBP_QUALITY, 90])
        with pytest.raises(InputError, match="lossy WebP content mask") as caught:
            read_content_mask(path)
        assert str(caught.value).startswith(f"{path}: ") and "\n" not in str(caught.value)
        assert cv2.imwrite(str(path), image, [cv2.IMWRITE_WEBP_QUALITY, 101])  # lossless
        assert np.array_equal(area_image(read_content_mask(path)), mask)


def test_a_mask_edited_during_a_batch_changes_neither_area_nor_record(tmp_path: Path) -> None:
    """The mask is read once, when the options are parsed: every clip is shown the area of those bytes and records
    their hash. It was hashed for the record and read again for each clip, so a mask edited after the options
    were made was recorded by its new bytes, and a clip after an edit between clips was shown another area than
    the clip before (one run, one mask path in its manifest)."""
    mask = tmp_path / "scope.pgm"
    parsed = pgm_bytes(_mask())
    mask.write_bytes(parsed)
    opts = ClipOptions(fps=None, content=str(mask))
    narrowed = _mask()
    narrowed[:, :8] = BORDER  # another box, no text: another area record
    mask.write_bytes(pgm_bytes(narrowed))  # edited after the options were parsed, before the batch
    jobs = []
    for name in ("a", "b"):
        folder = tmp_path / "in" / name
        folder.mkdir(parents=True)
        for i in range(3):
            cv2.imwrite(str(folder / f"{i}.png"), np.full((H, W, 3), 60 + 20 * i, np.uint8))
        jobs.append(ClipJob(folder, name, tmp_path / "out" / name))

    def edit(outcome: ClipOutcome) -> None:  # and again between the clips
        mask.write_bytes(pgm_bytes(np.full((H, W), SCENE, np.uint8)))

    outcomes = run_batch(jobs, MethodSpec("none"), opts, tmp_path / "out", on_outcome=edit)
    assert [o.status for o in outcomes] == ["done", "done"], outcomes
    for name in ("a", "b"):
        record = json.loads((tmp_path / "out" / name / "gammas.json").read_text())
        assert record["settings"]["content"] == {"mask": str(mask), "sha256": hashlib.sha256(parsed).hexdigest()}
        assert record["frames"][0]["content"] == image_area(_mask()).summary()  # the area of the recorded bytes
    sent = pickle.loads(pickle.dumps(opts))  # what a worker process gets: the area read, no path to read again
    assert sent.content == str(mask) and np.array_equal(area_image(sent.content.area), _mask())


def test_a_folder_given_as_mask_is_named_a_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="a folder, not a content mask image"):
        read_content_mask(tmp_path)
    result = runner.invoke(app, ["enhance", str(tmp_path), "-o", str(tmp_path / "o"), "--content", str(tmp_path)])
    assert result.exit_code == 2 and "a folder" in boxed_text(result.output) and "Traceback" not in result.output


def test_huge_seconds_mean_the_whole_clip(clip: Path, tmp_path: Path) -> None:
    for seconds in ("1e300", "1e308"):
        result = runner.invoke(
            app, ["content", str(clip / "clip.mp4"), "-o", str(tmp_path / "m.pgm"), "--seconds", seconds]
        )
        assert result.exit_code == 0 and "(20 frames)" in result.output, result.output


def test_content_never_writes_its_mask_over_its_clip(clip: Path, tmp_path: Path) -> None:
    """A video named .png given as its own output, and a mask named like a frame in a frame-folder clip (a frame
    replaced, or a frame added to the clip): refused before anything is read, the clip unchanged."""
    video = tmp_path / "video.png"
    shutil.copyfile(clip / "clip.mp4", video)
    same = runner.invoke(app, ["content", str(video), "-o", str(video)])
    assert same.exit_code == 2 and "the clip itself" in same.output, same.output
    assert video.read_bytes() == (clip / "clip.mp4").read_bytes()
    frames = tmp_path / "frames"
    shutil.copytree(clip / "frames", frames)
    before = {p.name: p.read_bytes() for p in frames.iterdir()}
    for output in (frames / "000000.png", frames / "mask.PNG", tmp_path / "frames" / ".." / "frames" / "mask.png"):
        refused = runner.invoke(app, ["content", str(frames), "-o", str(output)])
        assert refused.exit_code == 2 and "frame folder" in refused.output, refused.output
    (frames / "loop.png").symlink_to(frames / "loop.png")  # a link loop named as a frame: refused, no traceback
    looped = runner.invoke(app, ["content", str(frames), "-o", str(frames / "loop.png")])
    assert looped.exit_code == 2 and "frame folder" in looped.output, looped.output
    (frames / "loop.png").unlink()
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before
    beside = runner.invoke(app, ["content", str(frames), "-o", str(frames / "mask.pgm")])  # not a frame's name
    assert beside.exit_code == 0, beside.output


def test_the_service_never_takes_a_mask_path(tmp_path: Path) -> None:
    pytest.importorskip("fastapi", reason="the service extra is not installed")
    from pydantic import ValidationError

    from service.request_options import JobOptions
    from service.routes.stream import StreamStart

    mask = tmp_path / "mask.pgm"
    mask.write_bytes(pgm_bytes(_mask()))
    # where parse_content reads a mask (patched there: the name it calls, not read_content_mask, which it no longer
    # goes through since masks are read once)
    with mock.patch("colonlight.content.load_content_mask", side_effect=AssertionError("read a path")):
        for value in (str(mask), "mask.pgm", "AUTO", " full "):
            with pytest.raises(ValidationError):
                JobOptions(content=value)
            with pytest.raises(ValidationError):
                StreamStart(type="start", content=value)


# ----------------------------------------------------------------------------------------------- the C++ host


@pytest.fixture(scope="module")
def host(cpp_host: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """``colonlight_host`` (built once for the session, tests/conftest.py) and an exported model for it; skipped
    without the export extra."""
    pytest.importorskip("onnxruntime", reason="the export extra (onnxruntime) is not installed")
    pytest.importorskip("onnxscript", reason="the export extra (onnxscript) is not installed")
    from colonlight.checkpoint import load_weights
    from colonlight.onnx_export import export_onnx

    onnx = tmp_path_factory.mktemp("host_model") / "model.onnx"
    export_onnx(load_weights(), onnx, size=8)
    return cpp_host, onnx


def _run_host(host: tuple[Path, Path], mask: Path) -> subprocess.CompletedProcess[bytes]:
    binary, onnx = host
    frames = np.zeros((2, H, W, 3), np.uint8).tobytes()
    run = [str(binary), str(onnx), str(W), str(H), "--content", str(mask)]
    return subprocess.run(run, input=frames, capture_output=True, timeout=60)


@pytest.mark.parametrize(
    ("name", "says"),
    [
        ("crlf", "bytes past the mask's 16x12 raster"),
        ("comment-after-maxval", "header is damaged"),
        ("trailing-bytes", "40 bytes past the mask's 16x12 raster"),
        ("maxval-128", "maxval 255"),
        ("huge-header", "the mask is 100000x100000"),
    ],
)
def test_the_host_refuses_a_damaged_pgm_in_one_line(
    host: tuple[Path, Path], tmp_path: Path, name: str, says: str
) -> None:
    mask = tmp_path / "mask.pgm"
    mask.write_bytes(DAMAGED[name][0])
    bad = _run_host(host, mask)
    message = bad.stderr.decode()
    assert bad.returncode == 1 and message.count("\n") == 1 and str(mask) in message and says in message, message
    mask.write_bytes(pgm_bytes(_mask()))
    good = _run_host(host, mask)
    assert good.returncode == 0 and len(good.stdout.splitlines()) == 2, good.stderr.decode()


def test_the_host_refuses_a_fifo_or_folder_without_waiting(host: tuple[Path, Path], tmp_path: Path) -> None:
    """Opened plainly, a FIFO with no writer blocked the host forever; a folder read as a damaged header."""
    os.mkfifo(tmp_path / "fifo.pgm")
    for mask in (tmp_path / "fifo.pgm", tmp_path):
        bad = _run_host(host, mask)  # the timeout is the hang
        message = bad.stderr.decode()
        assert bad.returncode == 1 and message.count("\n") == 1 and "not a regular file" in message, message
    (tmp_path / "loop.pgm").symlink_to(tmp_path / "loop.pgm")
    loop = _run_host(host, tmp_path / "loop.pgm").stderr.decode()
    assert "cannot read the content mask (Too many levels of symbolic links)" in loop, loop


def test_the_pixel_cap_judges_the_mask_bytes_that_are_decoded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The mask's size is read from the bytes read once, not from the file opened again: the cap judges what is
    decoded (a file replaced in between is not what it judged), and past Pillow's own limit too."""
    from colonlight.errors import FrameTooLargeError
    from colonlight.frames import check_image_size

    from ..media import flat_png

    path = tmp_path / "mask.pgm"
    path.write_bytes(pgm_bytes(_mask()))
    monkeypatch.setenv("COLONLIGHT_MAX_PIXELS", str(_mask().size - 1))
    with pytest.raises(FrameTooLargeError, match="mask.pgm"):
        read_content_mask(path)
    huge = flat_png(20000, 20000, rows=0)  # past Pillow's bomb limit: sized with it lifted, from the bytes too
    with pytest.raises(FrameTooLargeError, match=r"mask.pgm: frames of 20000x20000"):
        check_image_size(path, max_pixels=4096 * 4096, data=huge)
    assert check_image_size(path, max_pixels=10**9, data=huge) == (20000, 20000)
    assert check_image_size(path, max_pixels=10**9) == _mask().shape[::-1]  # the file itself: the small mask
