"""Frame images: a folder of images as one clip, and reading/writing single frames.

Images go through ``np.fromfile`` + ``cv2.imdecode`` and ``cv2.imencode`` + an atomic write, never
``cv2.imread``/``imwrite``: those mangle non-ASCII paths on some platforms and write in place, so a crash
could leave a half-written frame.

A frame folder is any folder holding image files (by suffix) and no video. Hidden files (``.name``, which
includes our own temporaries) and sub-folders are ignored; other side files (``.json``, ``.txt``, ...) are
allowed as long as they are not videos. Frames are taken in natural order (``frame2`` before ``frame10``).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from .atomic import NOT_REGULAR_FILE, write_bytes_atomic
from .errors import FrameTooLargeError, InputError, OptionError, os_error_cause
from .limits import DEFAULT_FPS, DEFAULT_JPEG_QUALITY, max_pixels_setting
from .methods.base import number_option
from .video import DecodedFrame, is_video

IMAGE_SUFFIXES: frozenset[str] = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"})

_DIGITS = re.compile(r"([0-9]+)")
#: The longest side a JPEG frame may have (the format's 16-bit sizes, less libjpeg's margin).
MAX_JPEG_SIDE = 65500


def natural_key(name: str) -> tuple[tuple[tuple[int, int, str], ...], str]:
    """Sort key putting ``frame2`` before ``frame10``: digit runs compare as numbers, text case-insensitively.

    Ties (``f01``/``f1``, ``A``/``a``) fall back to the plain name, so the order is total and stable.
    """
    parts = _DIGITS.split(name)
    key = tuple((1, int(p), "") if i % 2 else (0, 0, p.casefold()) for i, p in enumerate(parts) if p)
    return (key, name)


def _visible_files(folder: Path) -> list[os.DirEntry[str]]:
    """The folder's visible entries that are not sub-folders: its files, and the frame-named entries that cannot
    be read as files (a dangling link, a link loop, a FIFO), which :func:`list_image_frames` reports."""
    try:
        with os.scandir(folder) as it:
            return [e for e in it if not e.name.startswith(".") and _entry_problem(e) != "folder"]
    except FileNotFoundError as exc:
        raise InputError(f"{folder}: folder not found (moved or deleted?)") from exc
    except NotADirectoryError as exc:
        raise InputError(f"{folder}: not a folder") from exc
    except PermissionError as exc:
        raise InputError(f"{folder}: permission denied") from exc
    except OSError as exc:
        raise InputError(f"{folder}: cannot list folder ({exc.strerror or exc})") from exc


def _is_image_name(name: str) -> bool:
    return os.path.splitext(name)[1].lower() in IMAGE_SUFFIXES


def _entry_problem(entry: os.DirEntry[str]) -> str | None:
    """None for a regular file (links followed), ``"folder"`` for a folder, else why it cannot be read as a file.

    ``DirEntry.is_file`` raises for a link loop (ELOOP): unguarded, that made a whole frame folder "cannot list
    folder", so a batch dropped it without a line. A dangling link or a FIFO named ``0042.png`` was dropped from
    the clip without a word, shifting every later frame's time: each is now the clip's one-line failure, and a
    FIFO is never opened (reading one would wait forever for a writer)."""
    try:
        if entry.is_file():
            return None
        if entry.is_dir():
            return "folder"
        os.stat(entry.path)  # a dangling link or a loop raises here; anything else is no regular file
    except OSError as exc:
        return os_error_cause(exc)
    return NOT_REGULAR_FILE


def list_image_frames(folder: Path) -> list[Path]:
    """The image files of ``folder`` in natural order; InputError if it has none, cannot be read, or holds an
    entry named like a frame that cannot be read as a file (naming it: a frame lost silently shifts the clip)."""
    folder = Path(folder)
    entries = sorted((e for e in _visible_files(folder) if _is_image_name(e.name)), key=lambda e: natural_key(e.name))
    if not entries:
        raise InputError(f"{folder}: folder holds no frame images ({', '.join(sorted(IMAGE_SUFFIXES))})")
    for entry in entries:
        problem = _entry_problem(entry)
        if problem is not None:
            raise InputError(f"{folder / entry.name}: not a frame image: {problem}")
    return [folder / e.name for e in entries]


def is_image_folder(folder: Path) -> bool:
    """True if ``folder`` holds image files and no video (side files such as .json are fine). Never raises."""
    try:
        folder = Path(folder)
        if not folder.is_dir():
            return False
        entries = _visible_files(folder)
    except (InputError, OSError):
        return False
    if not any(_is_image_name(e.name) for e in entries):
        return False
    others = (e for e in entries if not _is_image_name(e.name) and _entry_problem(e) is None)  # files only
    return not any(is_video(Path(e.path)) for e in others)


_PILLOW_LIMIT_LOCK = threading.Lock()


def _image_source(path: Path, data: bytes | None) -> Path | io.BytesIO:
    """What Pillow opens: the file at ``path``, or the bytes a caller has read from it already (each open gets its
    own stream, at the start)."""
    return path if data is None else io.BytesIO(data)


def _header_size_past_pillows_limit(path: Path, data: bytes | None = None) -> tuple[int, int]:
    """The size in the header of an image past Pillow's decompression-bomb limit (> 179 Mpx), which refuses to
    report it: read again with the limit off. Only the header is read (Pillow decodes nothing here; OpenCV decodes
    the frames, after our own cap has judged this size). The limit is a module global of Pillow's, hence the lock,
    and it is put back at once."""
    from PIL import Image

    with _PILLOW_LIMIT_LOCK:
        limit = Image.MAX_IMAGE_PIXELS
        Image.MAX_IMAGE_PIXELS = None
        try:
            with Image.open(_image_source(path, data)) as img:
                return int(img.width), int(img.height)
        finally:
            Image.MAX_IMAGE_PIXELS = limit


def check_image_size(path: Path, max_pixels: int | None = None, data: bytes | None = None) -> tuple[int, int] | None:
    """``(width, height)`` from the header of the image at ``path``, read without decoding its pixels (OpenCV,
    which decodes the frames, has no header-only reader; Pillow's ``open`` is lazy). ``data``: the file's bytes,
    for a caller that has read them already, so the size judged is that of the bytes it decodes and the file is
    not opened again. None if Pillow cannot read the header (the decoder then reports the file).
    FrameTooLargeError if it gives more than ``max_pixels`` pixels (None: the configured cap), with the size; past
    Pillow's own decompression-bomb limit too (our cap decides)."""
    from PIL import Image

    cap = max_pixels_setting() if max_pixels is None else int(max_pixels)
    try:
        with warnings.catch_warnings():  # Pillow warns past 89 Mpx; our cap decides
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            try:
                with Image.open(_image_source(path, data)) as img:
                    width, height = int(img.width), int(img.height)
            except Image.DecompressionBombError:
                width, height = _header_size_past_pillows_limit(path, data)
    except Exception:  # noqa: BLE001 - unknown or broken header: the decoder reports it
        return None
    if width * height > cap:
        raise FrameTooLargeError(path, width, height, cap)
    return width, height


_OPENCV_LOG_LOCK = threading.Lock()
_opencv_silencers = [0, 0]  # [decodes in progress, the log level to restore when the last one ends]


@contextlib.contextmanager
def _opencv_quiet() -> Iterator[None]:
    """OpenCV's own logging off while an image decodes: a decoder that fails logs "[ERROR:...] imdecode_ ..." to
    stderr, beside the one line that names the file; the failure is reported by the caller. The log level is
    process-wide, so decodes share one silence: the first to start saves the level, the last to end restores it,
    and threads decode side by side (a lock held across the decode serialised every thread's images)."""
    log = cv2.utils.logging
    with _OPENCV_LOG_LOCK:
        if _opencv_silencers[0] == 0:
            _opencv_silencers[1] = log.getLogLevel()
            log.setLogLevel(log.LOG_LEVEL_SILENT)
        _opencv_silencers[0] += 1
    try:
        yield
    finally:
        with _OPENCV_LOG_LOCK:
            _opencv_silencers[0] -= 1
            if _opencv_silencers[0] == 0:
                log.setLogLevel(_opencv_silencers[1])


def _as_bgr(img: np.ndarray | None) -> np.ndarray | None:
    """An image decoded as it is (1 to 4 channels) as 3 channels: grey repeated, alpha dropped."""
    if img is None:
        return None
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 2, 3, 4):
        return None
    if img.shape[2] <= 2:  # grey, grey + alpha
        return np.ascontiguousarray(np.repeat(img[..., :1], 3, axis=2))
    return np.ascontiguousarray(img[..., :3])


def read_image(path: Path) -> np.ndarray:
    """Read an image as ``(H, W, 3)`` uint8 RGB: grey becomes 3 channels, alpha is dropped, 16-bit is scaled
    to 8-bit, and JPEG EXIF orientation is applied. InputError (naming the file) if it cannot be read."""
    path = Path(path)
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except FileNotFoundError as exc:
        raise InputError(f"{path}: file not found (moved or deleted?)") from exc
    except PermissionError as exc:
        raise InputError(f"{path}: permission denied") from exc
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    return decode_image(data, path)


def decode_image(data: np.ndarray, path: Path) -> np.ndarray:
    """The image file's bytes ``data`` (uint8) decoded as :func:`read_image` reads the file, for a caller that has
    read them already; InputError naming ``path`` if they are no readable image."""
    if data.size == 0:
        raise InputError(f"{path}: empty file (0 bytes)")
    # IMREAD_COLOR: always 3 channels (grey expanded, alpha dropped), EXIF orientation applied;
    # IMREAD_ANYDEPTH: keep 16-bit samples so that we scale them ourselves rather than OpenCV truncating them.
    with _opencv_quiet():
        img = cv2.imdecode(data, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
        if img is None:
            # OpenCV's colour read refuses a one-channel float TIFF (ImageJ's "32-bit", Pillow's mode F: a channel
            # check fails inside its decoder) that it reads as it is; take it so and make the 3 channels here.
            img = _as_bgr(cv2.imdecode(data, cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH))
    if img is None or img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"{path}: not a readable image (corrupt or unsupported format)")
    if img.dtype == np.uint16:
        img = ((img.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    elif img.dtype in (np.float32, np.float64):
        # NaN and infinities (a float TIFF's "no data") are defined here: cast as they are, NaN gave whatever the
        # platform's float-to-int conversion gives, and numpy warned on stderr once per frame.
        img = np.nan_to_num(img, nan=0.0, posinf=1.0, neginf=0.0)
        img = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"{path}: unsupported image sample type {img.dtype}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def iter_image_folder(
    folder: Path, fps: float | None = DEFAULT_FPS, *, min_frames: int = 0, max_pixels: int | None = None
) -> Iterator[DecodedFrame]:
    """Every image of ``folder`` as a frame, in natural order; ``time_s = index / fps``.

    The images are taken as frames already extracted at ``fps`` (None or 0 means the default 18). Raises
    InputError naming the file for an unreadable image, a size different from the first frame, or a file that
    vanished; and, before yielding anything, if the folder has fewer than ``min_frames`` images. Every image's
    header is checked against ``max_pixels`` (None: the configured cap) before it is decoded (FrameTooLargeError).
    """
    cap = max_pixels_setting() if max_pixels is None else int(max_pixels)
    paths = list_image_frames(Path(folder))
    if len(paths) < min_frames:
        raise InputError(f"{folder}: too short: {len(paths)} frame image(s), at least {min_frames} needed")
    rate = float(fps) if fps else DEFAULT_FPS
    if not 0 < rate < math.inf:  # NaN, negative or infinite: times.txt and gammas.json would say so for every frame
        raise OptionError(f"the rate of a folder of frames must be a number of frames per second above 0, got {fps!r}")
    size: tuple[int, ...] | None = None
    for i, p in enumerate(paths):
        check_image_size(p, cap)
        img = read_image(p)
        if img.shape[0] * img.shape[1] > cap:  # a header Pillow could not read: checked once decoded
            raise FrameTooLargeError(p, img.shape[1], img.shape[0], cap)
        if size is None:
            size = img.shape
        elif img.shape != size:
            raise InputError(
                f"{p}: frame size {img.shape[1]}x{img.shape[0]} differs from the folder's first frame "
                f"{size[1]}x{size[0]} ({paths[0].name})"
            )
        t = i / rate
        yield DecodedFrame(image=img, index=i, source_index=i, time_s=t, source_time_s=t)


def encode_image(
    rgb: np.ndarray, fmt: str = "png", quality: int = DEFAULT_JPEG_QUALITY, png_compression: int = 1
) -> bytes:
    """Encode an ``(H, W, 3)`` uint8 RGB frame as PNG or JPEG bytes.

    PNG compression 1 by default (zlib's fastest real level): frames are written at video rate; higher levels
    buy a few percent smaller files with more CPU time.
    """
    fmt = fmt.lower().lstrip(".")
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an HxWx3 uint8 RGB frame, got {rgb.shape} {rgb.dtype}")
    if rgb.size == 0:  # cvtColor's "(-215:Assertion failed) !_src.empty()" otherwise
        raise ValueError(f"expected an HxWx3 uint8 RGB frame with at least one pixel, got {rgb.shape}")
    for name, value, top in (("quality", quality, 100), ("png_compression", png_compression, 9)):
        # int() of NaN, of an infinity or of '90' failed with Python's own words; OpenCV clamps what is out of range
        if not 0 <= number_option(name, value, f"a number within 0..{top}", text=False) <= top:
            raise OptionError(f"{name} must be within 0..{top}, got {value}")
    if fmt in ("jpg", "jpeg") and max(rgb.shape[:2]) > MAX_JPEG_SIDE:
        # the format's own limit: OpenCV printed "[ERROR:...] imencode(): can't encode data ... Maximum supported
        # image dimension is 65500 pixels" on stderr, once per writer thread, beside a line that gave no cause
        raise OptionError(
            f"JPEG holds at most {MAX_JPEG_SIDE} pixels a side, the frames are {rgb.shape[1]}x{rgb.shape[0]}: "
            "write them as png"
        )
    bgr = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)
    # no _opencv_quiet here: its process-wide lock would serialise the writer threads, every frame, for failures
    # the checks above already turn into our own line before OpenCV sees them
    if fmt == "png":
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, int(png_compression)])
    elif fmt in ("jpg", "jpeg"):
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    else:
        raise ValueError(f"unsupported image format {fmt!r} (png or jpg)")
    if not ok:
        raise ValueError(f"OpenCV could not encode a {rgb.shape[1]}x{rgb.shape[0]} frame as {fmt}")
    return buf.tobytes()


def write_image_atomic(path: Path, rgb: np.ndarray, fmt: str = "png", quality: int = DEFAULT_JPEG_QUALITY) -> None:
    """Encode ``rgb`` and write it to ``path`` atomically (a reader never sees a partial image)."""
    write_bytes_atomic(Path(path), encode_image(rgb, fmt=fmt, quality=quality))
