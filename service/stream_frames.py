"""Frames of the WebSocket stream: JPEG/PNG bytes in, RGB arrays out and back, with the pixel cap checked from
the image header before anything is decoded (a small PNG can claim 8000 x 8000 and decode to 192 MB)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from colonlight import InputError, decode_image, encode_image
from colonlight.limits import DEFAULT_MAX_PIXELS, MAX_PIXELS_ENV, max_pixels_setting

ImageFormat = Literal["jpeg", "png"]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SIGNATURE = b"\xff\xd8"
# Start-of-frame markers carry the size; 0xC4 (DHT), 0xC8 (JPG) and 0xCC (DAC) share the range but are not SOFs.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_NO_LENGTH = frozenset({0x01, *range(0xD0, 0xD9)})  # TEM, RSTn, SOI, EOI: markers without a length field


class FrameError(ValueError):
    """A frame that cannot be used: the message says why, in one line, for the client."""


def max_pixels() -> int:
    """The pixel cap: ``COLONLIGHT_MAX_PIXELS`` when set (the CLI and service share it), else the default."""
    try:
        return max_pixels_setting()
    except ValueError:  # the server's settings refuse such a value at start-up; a test may set it later
        return DEFAULT_MAX_PIXELS


@dataclass(frozen=True)
class ImageHeader:
    format: ImageFormat
    width: int
    height: int


def _jpeg_size(data: bytes) -> tuple[int, int]:
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            raise FrameError("not a valid JPEG: a marker was expected")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in _JPEG_NO_LENGTH:
            pos += 2
            continue
        (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        if marker in _JPEG_SOF:
            if pos + 9 > len(data):
                break
            height, width = struct.unpack(">HH", data[pos + 5 : pos + 9])
            return width, height
        if marker == 0xDA or length < 2:  # image data before any frame header
            raise FrameError("not a valid JPEG: no frame header before the image data")
        pos += 2 + length
    raise FrameError("truncated JPEG: no frame header")


def read_header(data: bytes) -> ImageHeader:
    """Format and size of a JPEG or PNG from its first bytes, without decoding it (FrameError otherwise)."""
    if data.startswith(PNG_SIGNATURE):
        if len(data) < 24 or data[12:16] != b"IHDR":
            raise FrameError("truncated PNG: no IHDR header")
        width, height = struct.unpack(">II", data[16:24])
        return ImageHeader("png", width, height)
    if data.startswith(JPEG_SIGNATURE):
        width, height = _jpeg_size(data)
        return ImageHeader("jpeg", width, height)
    head = data[:8].hex(" ") if data else "nothing"
    raise FrameError(f"not a JPEG or PNG image ({len(data)} bytes starting with {head})")


def decode_frame(data: bytes, limit: int) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB from JPEG/PNG bytes; FrameError for anything else or over ``limit`` pixels."""
    header = read_header(data)
    if header.width == 0 or header.height == 0:
        raise FrameError(f"the {header.format.upper()} is {header.width}x{header.height}: an empty image")
    if header.width * header.height > limit:
        raise FrameError(
            f"the {header.format.upper()} is {header.width}x{header.height} = "
            f"{header.width * header.height} pixels, over the limit of {limit} ({MAX_PIXELS_ENV})"
        )
    corrupt = FrameError(
        f"the {header.format.upper()} ({header.width}x{header.height}) could not be decoded: corrupt or truncated"
    )
    try:  # the engine's decoder, as for a folder of frames: EXIF orientation applied, 16-bit PNG rounded, quiet
        rgb = decode_image(np.frombuffer(data, np.uint8), Path(header.format))
    except InputError:
        raise corrupt from None
    # a JPEG turned by its EXIF orientation (a phone's) has its header's sides swapped: it was refused as corrupt
    if rgb.shape[:2] not in ((header.height, header.width), (header.width, header.height)):
        raise corrupt
    return rgb


def encode_frame(rgb: np.ndarray, fmt: ImageFormat, quality: int) -> bytes:
    """JPEG (at ``quality``) or PNG bytes of an RGB frame, encoded as the engine encodes a clip's frames."""
    return encode_image(rgb, "jpg" if fmt == "jpeg" else "png", quality)
