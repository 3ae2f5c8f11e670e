"""A scope's content area as a mask image: what a host that cannot run the detection (a C++ SLAM front end) is
given instead (:func:`colonlight.content.find_content_area` finds one on a clip), and ``--content MASK``.

The image has the frame's size, one 8-bit channel: ``SCENE`` (255) where the scene shows, ``BORDER`` (0) outside
the field of view, and any level between (``OVERLAY``, 128, when colonlight writes it) for fixed on-screen text
inside the field of view. Written as binary PGM (``P5``), which a host parses in a few lines without an image
library; read from any single-channel image OpenCV decodes (a PNG mask drawn by hand, ``colonlight synth``'s
``content.png``). A host given the mask does what :class:`~colonlight.content.ContentStream` does with that area:
the method sees the field of view's bounding box with every non-scene pixel in it filled with the scene's mean
colour, and only scene pixels are written back (README, C++ SLAM host).
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from .atomic import atomic_path, parent_problem, read_regular_file
from .content_area import ContentArea
from .errors import InputError, OptionError
from .frames import IMAGE_SUFFIXES, check_image_size, decode_image

SCENE, OVERLAY, BORDER = 255, 128, 0
#: The names a mask is written under: PGM (what the C++ host reads) or PNG.
MASK_SUFFIXES = (".pgm", ".png")
#: A binary PGM's header (Netpbm): fields apart by whitespace or ``#`` comments, one whitespace byte before the
#: raster. Bytes enough to hold one with comments; a longer one is taken as damaged.
_GAP = rb"(?:\s|#[^\r\n]*[\r\n])+"
_PGM_HEADER = re.compile(rb"P5" + _GAP + rb"(\d+)" + _GAP + rb"(\d+)" + _GAP + rb"(\d+)\s")
_HEADER_BYTES = 65536
#: JPEG's (and MPO's) first bytes: a lossy image, whose levels beside an edge are neither 0 nor 255.
_JPEG_MAGIC = b"\xff\xd8\xff"
#: A WebP file: ``RIFF``, its size, ``WEBP``, then chunks (FourCC, little-endian size, data padded to an even
#: length). ``VP8 `` holds a lossy image, ``VP8L`` a lossless one; an animation frame (``ANMF``) holds its image's
#: chunks after a 16-byte frame header.
_WEBP_FIRST_CHUNK = 12
_WEBP_LOSSY, _WEBP_FRAME, _WEBP_FRAME_HEADER = b"VP8 ", b"ANMF", 16


class ContentMask(str):
    """A ``--content MASK`` read once for a whole run (:func:`load_content_mask`): the text is the mask's absolute
    path (or, for one read from bytes, :func:`content_mask_from_bytes`'s name), :attr:`sha256` the SHA-256 of the
    bytes read and :attr:`area` the area those same bytes show.

    Every clip is shown :attr:`area` and the settings record :attr:`sha256`, so a mask edited while a batch runs
    changes neither: hashed once and read again for each clip, the record could name bytes no clip was shown. A
    ``str`` so that it goes wherever the path went (the options' ``content``, the manifest's settings, a
    ``content: str`` parameter) and compares equal to it; immutable, and pickled whole (a pool's or a cluster's
    worker process gets the area with the options, and never reads the file)."""

    __slots__ = ("area", "sha256")
    area: ContentArea
    sha256: str

    def __new__(cls, path: str, sha256: str, area: ContentArea) -> ContentMask:
        mask = super().__new__(cls, path)
        object.__setattr__(mask, "sha256", sha256)
        object.__setattr__(mask, "area", area)
        return mask

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"a content mask is read once: its {name} cannot be changed")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"a content mask is read once: its {name} cannot be changed")

    def __reduce__(self) -> tuple[type[ContentMask], tuple[str, str, ContentArea]]:
        return ContentMask, (str(self), self.sha256, self.area)


def area_image(area: ContentArea) -> np.ndarray:
    """``(H, W)`` uint8: ``SCENE``, ``OVERLAY`` or ``BORDER`` for each pixel of ``area``."""
    image = np.full(area.fov.shape, BORDER, np.uint8)
    image[area.fov] = SCENE
    image[area.fov & area.overlay] = OVERLAY
    return image


def image_area(image: np.ndarray) -> ContentArea:
    """The area a mask image says: the field of view where it is not ``BORDER``, text where it is neither
    ``BORDER`` nor ``SCENE``. ``ValueError`` if it shows no scene pixel."""
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"a mask is one 8-bit channel, got shape {image.shape} of {image.dtype}")
    if not (image == SCENE).any():
        raise ValueError(f"no scene pixel ({SCENE}) in the mask")
    fov = image != BORDER
    return ContentArea(fov, fov & (image != SCENE))


def pgm_bytes(image: np.ndarray) -> bytes:
    """``image`` ((H, W) uint8) as a binary PGM file."""
    height, width = image.shape
    return f"P5\n{width} {height}\n255\n".encode("ascii") + np.ascontiguousarray(image).tobytes()


def check_mask_output(path: Path, clip: Path | None = None) -> str:
    """``"pgm"`` or ``"png"``, the format a mask named ``path`` is written in; OptionError for any other name, and
    for a name that would change ``clip`` (the clip the mask is found on): the clip file itself (a video may be
    named ``.png``), or an image name in a frame-folder clip (read as one of its frames); and for a path no file
    can be made at (a parent that is a file). A shell checks it before the clip is read."""
    suffix = Path(path).suffix.lower()
    if suffix not in MASK_SUFFIXES:
        wanted = " or ".join(MASK_SUFFIXES)
        raise OptionError(f"{path}: a content mask is written as {wanted}, not {suffix or 'a name without one'}")
    clash = _clip_clash(Path(clip), Path(path)) if clip is not None else None
    if clash:
        raise OptionError(f"{path}: {clash}")
    blocked = parent_problem(Path(path))
    if blocked:  # before the clip is read: it was the write's bare "File exists", after the detection
        raise OptionError(f"{path}: {blocked}")
    return suffix[1:]


def _clip_clash(clip: Path, output: Path) -> str | None:
    """Why writing ``output`` would change ``clip``, links resolved (None if it would not)."""
    try:
        if output.exists() and output.samefile(clip):
            return "is the clip itself: the mask would overwrite it"
        folder = output.absolute().parent.resolve()  # the folder the name lands in, whatever a link there points to
        if clip.is_dir() and output.suffix.lower() in IMAGE_SUFFIXES and folder == clip.resolve():
            return f"is in the clip's frame folder {clip}: the mask would be read as one of its frames"
    except (OSError, RuntimeError):  # unresolvable (a link loop: RuntimeError): the clip or the output says so
        pass
    return None


def write_content_mask(path: Path, area: ContentArea) -> None:
    """Write ``area`` to ``path`` as a mask image, atomically (a host never reads half a mask): binary PGM, or PNG
    for a ``.png`` name. OptionError for any other name, before anything is written; ``OSError`` if it cannot be
    written."""
    image = area_image(area)
    data = cv2.imencode(".png", image)[1].tobytes() if check_mask_output(path) == "png" else pgm_bytes(image)
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(data)


def _check_mask_file(path: Path, data: bytes) -> None:
    """InputError naming ``path`` for a mask that would be read with wrong levels or in the wrong place: a JPEG or
    a lossy WebP (scene pixels that are not quite 255 would count as text, border ones not quite 0 as field of
    view; a lossless WebP decodes exactly), or a binary PGM (``P5``) that OpenCV and the C++ host read shifted or
    scaled unlike colonlight's levels: a damaged header (a comment where the raster's one whitespace byte belongs,
    CR LF line ends), a maxval other than 255 (or 65535), or bytes past the raster its header declares (compared
    by size, nothing allocated)."""
    head = data[:_HEADER_BYTES]
    if head.startswith(_JPEG_MAGIC):
        raise InputError(f"{path}: a JPEG content mask is lossy (levels near 0 and 255 change): save it as PNG or PGM")
    if _lossy_webp(data):
        raise InputError(
            f"{path}: a lossy WebP content mask (levels near 0 and 255 change): save it as PNG, PGM or lossless WebP"
        )
    if not head.startswith(b"P5"):
        return
    header = _PGM_HEADER.match(head)
    width, height, maxval = (int(v) for v in header.groups()) if header else (0, 0, 0)
    if header is None or min(width, height, maxval) < 1:
        raise InputError(f"{path}: not a readable image: its binary PGM header is damaged")
    if maxval not in (255, 65535):
        raise InputError(f"{path}: a binary PGM mask has maxval 255 (the scene's level) or 65535, not {maxval}")
    raster, found = width * height * (1 if maxval == 255 else 2), len(data) - header.end()
    if found != raster:
        raise InputError(
            f"{path}: not a readable image: a {width}x{height} binary PGM has {raster} bytes after its header, "
            f"this one {found} (cut short, extra bytes or a damaged header)"
        )


def _lossy_webp(data: bytes) -> bool:
    """True for a WebP holding a lossy image: a ``VP8 `` chunk, alone (the simple format) or among an extended
    file's (``VP8X``) chunks, an animation's frames included. (An ``ALPH`` chunk, whose alpha may be lossy too,
    only goes with a ``VP8 `` one; the alpha is dropped when the mask is read.)"""
    is_webp = data.startswith(b"RIFF") and data[8:_WEBP_FIRST_CHUNK] == b"WEBP"
    return is_webp and _WEBP_LOSSY in _riff_chunks(data, _WEBP_FIRST_CHUNK, len(data))


def _riff_chunks(data: bytes, start: int, end: int) -> Iterator[bytes]:
    """The FourCCs of the chunks in ``data[start:end]``, then those of each WebP animation frame's image; a
    chunk's size is not trusted past ``end`` (a file cut short ends the walk)."""
    while start + 8 <= end:
        fourcc, size = data[start : start + 4], int.from_bytes(data[start + 4 : start + 8], "little")
        yield fourcc
        if fourcc == _WEBP_FRAME:
            yield from _riff_chunks(data, start + 8 + _WEBP_FRAME_HEADER, min(end, start + 8 + size))
        start += 8 + size + size % 2


def load_content_mask(path: Path) -> ContentMask:
    """The mask image at ``path``, read once: its absolute path (a cluster's worker processes run in their own
    working folders; '../masks/scope.pgm' is recorded without its '..'), the SHA-256 of the bytes read and the
    area they show. InputError naming the file if it cannot be read, is not one grey channel, or shows no scene
    (and for the files :func:`_check_mask_file` refuses)."""
    path = Path(path)
    try:
        data = read_regular_file(path)  # read once; a FIFO is refused, never waited on
    except IsADirectoryError:
        raise InputError(f"{path}: a folder, not a content mask image") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the content mask ({exc.strerror or exc})") from exc
    return _read_mask(data, path, os.path.abspath(path))


def content_mask_from_bytes(data: bytes, name: str, max_pixels: int | None = None) -> ContentMask:
    """A mask image's file bytes that are in no file of the caller's (the service's WebSocket stream gets them in
    its start message), checked and read exactly as :func:`load_content_mask` reads a file, so that a mask is
    taken or refused alike whichever way it came; no temporary file to write and remove. ``name`` (a label, not a
    path) starts each error and is the mask's text (what the stream's frame-size error names). ``max_pixels``:
    the pixel cap (None: the configured one); FrameTooLargeError past it, with the size."""
    return _read_mask(data, Path(name), name, max_pixels)


def _read_mask(data: bytes, label: Path, text: str, max_pixels: int | None = None) -> ContentMask:
    """The :class:`ContentMask` of a mask file's bytes ``data`` (its text ``text``), its errors naming ``label``."""
    _check_mask_file(label, data)
    check_image_size(label, max_pixels, data=data)  # the header's size against the pixel cap, before decoding
    rgb = decode_image(np.frombuffer(data, np.uint8), label)
    if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
        raise InputError(f"{label}: a content mask is grey (0 border, 255 scene), not a colour image")
    try:
        area = image_area(np.ascontiguousarray(rgb[..., 0]))
    except ValueError as exc:
        raise InputError(f"{label}: {exc}") from None
    return ContentMask(text, hashlib.sha256(data).hexdigest(), area)


def read_content_mask(path: Path) -> ContentArea:
    """The area in the mask image at ``path`` (:func:`load_content_mask`'s, with its errors)."""
    return load_content_mask(path).area


__all__ = [
    "BORDER",
    "ContentMask",
    "MASK_SUFFIXES",
    "OVERLAY",
    "SCENE",
    "area_image",
    "check_mask_output",
    "content_mask_from_bytes",
    "image_area",
    "load_content_mask",
    "pgm_bytes",
    "read_content_mask",
    "write_content_mask",
]
