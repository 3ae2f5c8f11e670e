"""A sixth hostile-input sweep of the engine, on real files: frame images and camera files a hostile user hands to
``colonlight enhance``, and a stream's timeout.

* A float TIFF frame holding NaN or infinities (a float image's "no data") was cast to 8 bits as it was: numpy
  printed "RuntimeWarning: invalid value encountered in cast" (with a line of source) once per frame, and NaN
  pixels took whatever the platform's float-to-int conversion gives. They are now 0 (NaN, -inf) and 255 (+inf).
* A one-channel float TIFF (ImageJ's "32-bit", Pillow's mode F) failed as "not a readable image (corrupt or
  unsupported format)", and OpenCV printed "[ERROR:...] global loadsave.cpp ... imdecode_ ..." on stderr beside
  the one line: its colour read fails a channel check that its as-is read does not. It is now read as grey;
  a frame that cannot be read at all is one line, with nothing of OpenCV's on stderr.
* A camera file whose numbers are written in other digits (Arabic-Indic ``١٢٨``, a superscript ``²``, ``1_00``)
  passed the check (Python's ``str.isdigit``, ``int`` and ``float`` take them) and was copied beside every clip,
  for the SLAM tool to fail on; a superscript failed with Python's "invalid literal for int() with base 10".
  Both are now "expected numbers"/"expected 'width height'" naming the file.
* A ``.y4m`` whose header gives a size of 0x0, a negative one or one past FFmpeg's limit failed as
  "FILE: Device or resource busy" (the errno FFmpeg's demuxer answers with), which reads as trouble with the disk.
  It now says FFmpeg refuses the file's header.
* ``StreamOptions(timeout_s=inf)`` (``colonlight stream --timeout inf`` or ``1e308``) was taken, and the end of
  the run crashed with an OverflowError traceback (the reader thread's ``join(timeout + 1)``) after the frames
  were out, leaving no stream.json (tests/cli/test_hostile_sweep6.py runs the command).
"""

from __future__ import annotations

import math
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from colonlight.decoding import probe_video
from colonlight.errors import FrameTooLargeError, InputError, OptionError
from colonlight.frames import iter_image_folder, read_image
from colonlight.live import StreamOptions
from colonlight.slam_layout import parse_camera

from ..media import flat_png


def test_nan_and_infinities_in_a_float_frame_are_defined_and_silent(tmp_path: Path) -> None:
    bgr = np.full((6, 8, 3), 0.5, np.float32)
    bgr[0, 0] = np.nan
    bgr[0, 1] = np.inf
    bgr[0, 2] = -np.inf
    path = tmp_path / "f.tif"
    assert cv2.imwrite(str(path), bgr)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's RuntimeWarning for the cast of NaN
        rgb = read_image(path)
    assert rgb.dtype == np.uint8 and rgb.shape == (6, 8, 3)
    assert rgb[0, 0].tolist() == [0, 0, 0]
    assert rgb[0, 1].tolist() == [255, 255, 255]
    assert rgb[0, 2].tolist() == [0, 0, 0]
    assert (rgb[1:] == 128).all()


def test_a_one_channel_float_tiff_is_read_as_grey_without_opencv_noise(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    grey = np.linspace(0.0, 1.0, 48 * 64, dtype=np.float32).reshape(48, 64)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        Image.fromarray(grey, mode="F").save(folder / f"{i}.tif")  # Pillow's mode F: one float32 channel
    frames = list(iter_image_folder(folder))
    assert len(frames) == 3
    expected = (grey * 255.0 + 0.5).astype(np.uint8)
    for frame in frames:
        assert frame.image.shape == (48, 64, 3) and frame.image.dtype == np.uint8
        for c in range(3):
            np.testing.assert_array_equal(frame.image[..., c], expected)
    # a frame that cannot be read: one error naming it, and OpenCV prints nothing of its own
    broken = tmp_path / "broken.png"
    ok, buf = cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))
    broken.write_bytes(buf.tobytes()[:40])
    with pytest.raises(InputError, match="broken.png: not a readable image"):
        read_image(broken)
    captured = capfd.readouterr()
    assert "ERROR" not in captured.err and "imdecode" not in captured.err, captured.err


def test_threads_decode_side_by_side_quietly_and_the_log_level_comes_back(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """Decodes in several threads, broken ones among them, share one silence of OpenCV's log: none prints, and
    the level the process had is back when the last ends (a lock held across each decode serialised them)."""
    good, broken = tmp_path / "good.png", tmp_path / "broken.png"
    png = cv2.imencode(".png", np.full((64, 64, 3), 7, np.uint8))[1].tobytes()
    good.write_bytes(png)
    broken.write_bytes(png[:40])
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_WARNING)
    try:

        def read(i: int) -> str:
            try:
                return str(read_image(good if i % 2 else broken).shape)
            except InputError as exc:
                return str(exc)

        with ThreadPoolExecutor(8) as pool:
            answers = list(pool.map(read, range(200)))
        assert answers.count("(64, 64, 3)") == 100
        assert all("broken.png: not a readable image" in a for a in answers[::2])
        assert cv2.utils.logging.getLogLevel() == cv2.utils.logging.LOG_LEVEL_WARNING
    finally:
        cv2.utils.logging.setLogLevel(level)
    captured = capfd.readouterr()
    assert "ERROR" not in captured.err and "imdecode" not in captured.err, captured.err


@pytest.mark.parametrize(
    "line",
    [
        "1 PINHOLE ١٢٨ 96 100 100 64 48",  # Arabic-Indic digits: int() reads 128
        "1 PINHOLE ²8 96 100 100 64 48",  # a superscript: isdigit() says yes, int() says no
        "1 PINHOLE 128 96 1_00 100 64 48",  # float() reads 100
        "١ PINHOLE 128 96 100 100 64 48",  # the camera id
        "Pinhole ٠.٥ 0.5 0.5 0.5 0\n128 96\ncrop\n128 96",  # DSO
    ],
    ids=["arabic-size", "superscript", "underscore", "arabic-id", "dso-arabic"],
)
def test_a_camera_file_with_numbers_slam_tools_cannot_read_is_refused(line: str) -> None:
    with pytest.raises(InputError) as err:
        parse_camera(line + "\n", "cam.txt")
    message = str(err.value)
    assert message.startswith("cam.txt: not a valid ") and "\n" not in message, message
    assert "invalid literal" not in message, message


def test_ascii_camera_numbers_are_still_read() -> None:
    cam = parse_camera("# c\n1 PINHOLE 128 96 1e2 +100. .5e1 -0.5\n", "cam.txt")
    assert cam.kind == "colmap" and cam.sizes == ((128, 96),)
    dso = parse_camera("Pinhole 0.5 0.5 0.5 0.5 0\n128 96\ncrop\n128 96\n", "camera.txt")
    assert dso.kind == "dso" and dso.sizes == ((128, 96),)


@pytest.mark.parametrize("timeout", [math.inf, 1e308, math.nan, 0.0, -1.0])
def test_a_stream_timeout_no_thread_wait_takes_is_an_option_error(timeout: float) -> None:
    with pytest.raises(OptionError, match="timeout must be"):
        StreamOptions(timeout_s=timeout)
    assert StreamOptions(timeout_s=1e9).timeout_s == 1e9


@pytest.mark.parametrize("duration", [0.0, -1.0, math.nan])
def test_a_stream_duration_that_is_not_above_0_is_an_option_error(duration: float) -> None:
    with pytest.raises(OptionError, match="duration must be a number of seconds above 0"):
        StreamOptions(duration_s=duration)
    assert StreamOptions(duration_s=math.inf).duration_s == math.inf  # no limit


@pytest.mark.parametrize("size", ["W0 H0", "W-5 H10", "W20000 H20000"])
def test_a_y4m_header_ffmpeg_refuses_is_not_called_a_busy_device(tmp_path: Path, size: str) -> None:
    path = tmp_path / "clip.y4m"
    path.write_bytes(f"YUV4MPEG2 {size} F18:1 Ip A1:1 C420jpeg\nFRAME\n".encode())
    with pytest.raises(InputError) as err:
        probe_video(path)
    assert str(err.value).startswith(f"{path}: not a video FFmpeg can open: it refuses the file's header ("), err.value


def test_an_image_past_pillows_bomb_limit_is_judged_by_our_cap_with_its_size(tmp_path: Path) -> None:
    """Pillow refuses to report a size past 179 Mpx (its decompression-bomb check): the error said "frames of
    unknown size exceed the pixel cap ... raise it with COLONLIGHT_MAX_PIXELS", and raising it did not help."""
    from PIL import Image

    from colonlight.frames import check_image_size

    path = tmp_path / "huge.png"
    path.write_bytes(flat_png(20000, 20000, rows=0))  # 400 Mpx declared
    limit = Image.MAX_IMAGE_PIXELS
    with pytest.raises(FrameTooLargeError, match=r"huge.png: frames of 20000x20000 \(400.0 Mpx\) exceed") as err:
        check_image_size(path, max_pixels=4096 * 4096)
    assert (err.value.width, err.value.height) == (20000, 20000)
    assert check_image_size(path, max_pixels=500_000_000) == (20000, 20000)  # a cap above it: our cap decides
    assert limit == Image.MAX_IMAGE_PIXELS  # Pillow's own limit is put back
