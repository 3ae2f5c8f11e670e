"""A scope's content area as a mask image: what a host that cannot run the detection (a C++ SLAM front end) is
given instead, and how colonlight finds one for a clip.

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
import stat
from pathlib import Path

import cv2
import numpy as np

from .atomic import NOT_REGULAR_FILE, atomic_path
from .content_area import ContentArea
from .errors import InputError, OptionError
from .frames import check_image_size, read_image

SCENE, OVERLAY, BORDER = 255, 128, 0
#: The names a mask is written under: PGM (what the C++ host reads) or PNG.
MASK_SUFFIXES = (".pgm", ".png")


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


def content_mask_format(path: Path) -> str:
    """``"pgm"`` or ``"png"``, the format a mask named ``path`` is written in; OptionError for any other name (a
    shell checks it before the clip is read)."""
    suffix = Path(path).suffix.lower()
    if suffix not in MASK_SUFFIXES:
        wanted = " or ".join(MASK_SUFFIXES)
        raise OptionError(f"{path}: a content mask is written as {wanted}, not {suffix or 'a name without one'}")
    return suffix[1:]


def write_content_mask(path: Path, area: ContentArea) -> None:
    """Write ``area`` to ``path`` as a mask image, atomically (a host never reads half a mask): binary PGM, or PNG
    for a ``.png`` name. OptionError for any other name, before anything is written; ``OSError`` if it cannot be
    written."""
    image = area_image(area)
    data = cv2.imencode(".png", image)[1].tobytes() if content_mask_format(path) == "png" else pgm_bytes(image)
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(data)


def mask_digest(path: Path) -> str:
    """The SHA-256 of the mask file's bytes: what an output records of the mask it was made with."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def read_content_mask(path: Path) -> ContentArea:
    """The area in the mask image at ``path``. InputError naming the file if it cannot be read, is not one grey
    channel, or shows no scene."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise InputError(f"{path}: cannot read the content mask ({exc.strerror or exc})") from exc
    if not stat.S_ISREG(mode):
        raise InputError(f"{path}: {NOT_REGULAR_FILE}")
    check_image_size(path)
    rgb = read_image(path)
    if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
        raise InputError(f"{path}: a content mask is grey (0 border, 255 scene), not a colour image")
    try:
        return image_area(np.ascontiguousarray(rgb[..., 0]))
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None


__all__ = [
    "BORDER",
    "MASK_SUFFIXES",
    "OVERLAY",
    "SCENE",
    "area_image",
    "content_mask_format",
    "image_area",
    "mask_digest",
    "pgm_bytes",
    "read_content_mask",
    "write_content_mask",
]
