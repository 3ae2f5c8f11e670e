"""colonlight.frames: folders of frame images as clips, and reading/writing single frames."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from colonlight.errors import InputError, OptionError
from colonlight.frames import (
    IMAGE_SUFFIXES,
    encode_image,
    is_image_folder,
    iter_image_folder,
    list_image_frames,
    natural_key,
    read_image,
    write_image_atomic,
)

from ...media import index_frame, make_clip, make_image_folder, needs_ffmpeg, read_index, text_file


def _write(path: Path, img: np.ndarray) -> Path:
    ok, buf = cv2.imencode(path.suffix, img)
    assert ok
    buf.tofile(str(path))
    return path


# ------------------------------------------------------------------------------------------------ ordering


def test_natural_key_orders_numbers_as_numbers() -> None:
    names = ["frame10.png", "frame2.png", "Frame3.png", "frame1.png", "frame02.png", "frame100.png", "a.png"]
    assert sorted(names, key=natural_key) == [
        "a.png",
        "frame1.png",
        "frame02.png",
        "frame2.png",
        "Frame3.png",
        "frame10.png",
        "frame100.png",
    ]
    assert natural_key("x²1") < natural_key("x²2")  # non-ASCII digits stay text, no crash


def test_list_image_frames_natural_order_ignoring_hidden_and_side_files(tmp_path: Path) -> None:
    make_image_folder(tmp_path, n=12, name="img_{i}")
    (tmp_path / ".img_99.png").write_bytes(b"hidden")  # hidden, e.g. our own temporaries
    (tmp_path / "meta.json").write_text("{}")
    (tmp_path / "sub").mkdir()
    _write(tmp_path / "sub" / "img_50.png", index_frame(50, 64, 48))
    _write(tmp_path / "IMG_12.JPG", index_frame(12, 64, 48))  # suffixes are case-insensitive
    got = [p.name for p in list_image_frames(tmp_path)]
    assert got == [f"img_{i}.png" for i in range(12)] + ["IMG_12.JPG"]


def test_list_image_frames_errors(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="no frame images"):
        list_image_frames(tmp_path)
    with pytest.raises(InputError, match="not found"):
        list_image_frames(tmp_path / "missing")


# -------------------------------------------------------------------------------------------- folder or not


@needs_ffmpeg
def test_is_image_folder(tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    make_image_folder(frames, n=3)
    text_file(frames / "notes.txt")
    (frames / "info.json").write_text("{}")
    assert is_image_folder(frames)  # side files are fine
    make_clip(frames / "recording.dat", 5, 25, output_args=["-f", "matroska"])  # a video, whatever its name:
    # then the folder is not a frame clip
    assert not is_image_folder(frames)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert not is_image_folder(empty)
    assert not is_image_folder(tmp_path / "missing")
    assert not is_image_folder(frames / "notes.txt")
    assert {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"} == IMAGE_SUFFIXES


# --------------------------------------------------------------------------------------------------- iterate


def test_iter_image_folder_yields_every_frame_with_times(tmp_path: Path) -> None:
    make_image_folder(tmp_path, n=15, name="frame{i}")
    frames = list(iter_image_folder(tmp_path, fps=18))
    assert [read_index(f.image) for f in frames] == list(range(15))
    assert [(f.index, f.source_index) for f in frames] == [(i, i) for i in range(15)]
    assert [f.time_s for f in frames] == pytest.approx([i / 18 for i in range(15)])
    assert all(f.source_time_s == f.time_s for f in frames)
    assert [f.time_s for f in iter_image_folder(tmp_path, fps=None)][1] == pytest.approx(1 / 18)
    assert frames[0].image.shape == (48, 64, 3) and frames[0].image.dtype == np.uint8


def test_iter_image_folder_mixed_sizes_names_the_file(tmp_path: Path) -> None:
    make_image_folder(tmp_path, n=4)
    _write(tmp_path / "frame4.png", index_frame(4, 80, 48))
    it = iter_image_folder(tmp_path)
    assert [next(it).index for _ in range(4)] == [0, 1, 2, 3]
    with pytest.raises(InputError) as err:
        next(it)
    assert str(tmp_path / "frame4.png") in str(err.value) and "80x48" in str(err.value)


def test_iter_image_folder_unreadable_or_vanished_image_names_the_file(tmp_path: Path) -> None:
    paths = make_image_folder(tmp_path, n=6)
    paths[2].write_bytes(b"\x89PNG\r\n\x1a\n but then garbage")
    with pytest.raises(InputError) as err:
        list(iter_image_folder(tmp_path))
    assert str(paths[2]) in str(err.value) and "\n" not in str(err.value)
    paths[2].unlink()
    it = iter_image_folder(tmp_path)
    next(it)
    paths[4].unlink()  # vanishes mid-run
    with pytest.raises(InputError, match="not found") as err:
        list(it)
    assert str(paths[4]) in str(err.value)


def test_iter_image_folder_min_frames(tmp_path: Path) -> None:
    make_image_folder(tmp_path, n=1)
    with pytest.raises(InputError, match="too short"):
        next(iter_image_folder(tmp_path, min_frames=2))
    assert len(list(iter_image_folder(tmp_path))) == 1


def test_non_ascii_paths_with_spaces(tmp_path: Path) -> None:
    folder = tmp_path / "Bilder ä 画像"
    make_image_folder(folder, n=3, name="Bild {i} ü", fmt="jpg")
    assert is_image_folder(folder)
    assert [read_index(f.image) for f in iter_image_folder(folder)] == [0, 1, 2]
    out = folder / "enhanced ö" / "000001.png"
    write_image_atomic(out, index_frame(7, 64, 48))
    assert read_index(read_image(out)) == 7


# --------------------------------------------------------------------------------------------- single images


def test_read_image_normalises_channels_and_depth(tmp_path: Path) -> None:
    rgb = index_frame(5, 64, 48)
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    grey = _write(tmp_path / "grey.png", bgr[..., 1])
    bgra = _write(tmp_path / "alpha.png", np.dstack([bgr, np.full(bgr.shape[:2], 7, np.uint8)]))
    deep = _write(tmp_path / "deep.png", bgr.astype(np.uint16) * 257)
    tiff = _write(tmp_path / "frame.tiff", bgr)
    bmp = _write(tmp_path / "frame.bmp", bgr)
    for p in (grey, bgra, deep, tiff, bmp):
        img = read_image(p)
        assert img.shape == (48, 64, 3) and img.dtype == np.uint8, p
        assert read_index(img) == 5, p
    np.testing.assert_array_equal(read_image(bgra), rgb)
    np.testing.assert_array_equal(read_image(deep), rgb)
    np.testing.assert_array_equal(read_image(grey)[..., 0], read_image(grey)[..., 2])


def _with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """Insert a minimal EXIF block carrying only an orientation tag, as a phone camera writes one."""
    ifd = struct.pack("<H", 1) + struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack("<I", 0)
    app1 = b"Exif\x00\x00" + b"II*\x00" + struct.pack("<I", 8) + ifd
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:]


def test_read_image_applies_exif_orientation(tmp_path: Path) -> None:
    img = np.zeros((40, 80, 3), np.uint8)
    img[:10, :20] = 255  # a white block top-left
    p = tmp_path / "phone.jpg"
    p.write_bytes(_with_exif_orientation(encode_image(img, "jpg"), 6))  # 6: turn 90 degrees clockwise to view
    up = read_image(p)
    assert up.shape == (80, 40, 3)
    assert up[:20, -10:].mean() > 200 and up[:10, :10].mean() < 50  # block now top-right


def test_read_image_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "zero.png").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_image(tmp_path / "zero.png")
    (tmp_path / "text.jpg").write_text("not an image")
    with pytest.raises(InputError, match="not a readable image") as err:
        read_image(tmp_path / "text.jpg")
    assert str(tmp_path / "text.jpg") in str(err.value)


def test_encode_and_atomic_write(tmp_path: Path) -> None:
    rgb = index_frame(9, 64, 48)
    png = encode_image(rgb)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    decoded = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB), rgb)
    jpg = encode_image(rgb, "jpg", quality=90)
    assert jpg[:2] == b"\xff\xd8" and len(encode_image(rgb, "jpeg", quality=30)) < len(jpg)
    assert len(encode_image(rgb, png_compression=9)) <= len(encode_image(rgb, png_compression=0))
    for bad_fmt, bad_img in (("gif", rgb), ("png", rgb[..., 0]), ("png", rgb.astype(np.float32))):
        with pytest.raises(ValueError):
            encode_image(bad_img, bad_fmt)
    for bad in (float("nan"), float("inf"), -1, 101, "90", True, None):  # int(nan) failed in Python's words
        with pytest.raises(OptionError, match="quality"):
            encode_image(rgb, "jpg", quality=bad)  # type: ignore[arg-type]
    with pytest.raises(OptionError, match="png_compression"):
        encode_image(rgb, png_compression=10)
    out = tmp_path / "out" / "000000.jpg"
    write_image_atomic(out, rgb, fmt="jpg", quality=95)
    assert read_index(read_image(out)) == 9
    assert [p.name for p in out.parent.iterdir()] == ["000000.jpg"]  # no temporaries left
