"""``he`` and ``clahe``: histogram equalisation of the lightness channel only.

Equalising R, G and B separately shifts hue, so both methods work on one lightness channel (Y of YCrCb, L of
Lab or V of HSV) and leave the colour channels alone. OpenCV does the work; this module only picks the
channel.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import cv2
import numpy as np

from ..errors import OptionError
from .base import FrameResult, Method, MethodStream, check_frame, integer_option, number_option

_CLAHE_SPACES = ("lab", "hsv")
#: The most CLAHE tiles a side (8 by default): OpenCV holds a table of 256 bytes per tile (16 MB at this bound).
MAX_TILES = 256


def equalize_luma(frame: np.ndarray) -> np.ndarray:
    """Global histogram equalisation (``cv2.equalizeHist``) of Y in YCrCb, converted back to RGB.

    Args:
        frame: ``(H, W, 3)`` uint8 RGB.

    Returns:
        ``(H, W, 3)`` uint8 RGB. The YCrCb round trip itself may move samples by 1-2 codes.
    """
    ycc = cv2.cvtColor(frame, cv2.COLOR_RGB2YCrCb)
    ycc[..., 0] = cv2.equalizeHist(np.ascontiguousarray(ycc[..., 0]))
    return cv2.cvtColor(ycc, cv2.COLOR_YCrCb2RGB)


def value_channel(frame: np.ndarray) -> np.ndarray:
    """V of HSV, ``max(R, G, B)``, as ``(H, W)`` uint8 (an elementwise chain: ``max(axis=2)`` is ~15x slower)."""
    v: np.ndarray = np.maximum(np.maximum(frame[..., 0], frame[..., 1]), frame[..., 2])
    return v


def scale_value(frame: np.ndarray, v_new: np.ndarray, v: np.ndarray | None = None) -> np.ndarray:
    """Replace V = max(R, G, B) of every pixel by ``v_new`` keeping hue and saturation (HSV), exactly.

    With H and S fixed, RGB is proportional to V, so this multiplies each pixel by ``v_new / V``. It equals
    "convert to 8-bit HSV, change V, convert back" without the 2-degree hue quantisation of OpenCV's 8-bit
    HSV; the output's max channel is exactly ``v_new``. A black pixel (V = 0) becomes grey ``v_new``, as HSV
    (S = 0) does.

    Args:
        frame: ``(H, W, 3)`` uint8 RGB.
        v_new: ``(H, W)`` uint8, the new V.
        v: the frame's :func:`value_channel`, if already computed.

    Returns:
        ``(H, W, 3)`` uint8 RGB.
    """
    if v is None:
        v = value_channel(frame)
    ratio = v_new.astype(np.float32) / np.maximum(v, 1).astype(np.float32)
    out: np.ndarray = np.rint(frame.astype(np.float32) * ratio[..., None])
    out = np.clip(out, 0, 255).astype(np.uint8)
    black = v == 0
    if black.any():
        out[black] = v_new[black, None]
    return out


class _HeStream(MethodStream):
    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        return [FrameResult(frame=equalize_luma(frame))]


class HistogramEqualizationMethod(Method):
    """Global histogram equalisation of Y (YCrCb, BT.601 full range as OpenCV defines it), per frame.

    No options; it has no per-frame gamma (reports ``None``).
    """

    name = "he"

    def stream(self) -> MethodStream:
        return _HeStream()


class _ClaheStream(MethodStream):
    def __init__(self, clip_limit: float, tile_grid: tuple[int, int], space: str) -> None:
        # One CLAHE object per stream: OpenCV's object keeps buffers and is not meant to be shared across
        # threads.
        self._clahe = cv2.createCLAHE(clipLimit=clip_limit, tileGridSize=tile_grid)
        self._space = space

    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        if self._space == "lab":
            lab = cv2.cvtColor(frame, cv2.COLOR_RGB2Lab)
            lab[..., 0] = self._clahe.apply(np.ascontiguousarray(lab[..., 0]))
            out = cv2.cvtColor(lab, cv2.COLOR_Lab2RGB)
        else:
            v = value_channel(frame)
            out = scale_value(frame, self._clahe.apply(v), v)
        return [FrameResult(frame=out)]


class ClaheMethod(Method):
    """Contrast-limited adaptive histogram equalisation (``cv2.createCLAHE``) of one lightness channel.

    Args:
        clip_limit: OpenCV's clipLimit (OpenCV's own default is 40; 2.0 is the usual endoscopy setting).
        tile_grid: ``(columns, rows)`` of tiles, OpenCV's tileGridSize; frames not divisible by it are fine
            (OpenCV reflect-pads for the histograms only).
        space: ``"lab"`` (L of 8-bit Lab, converted with OpenCV) or ``"hsv"`` (V = max(R, G, B), applied by
            :func:`scale_value`, which keeps hue and saturation exactly).
    """

    name = "clahe"

    def __init__(self, clip_limit: float = 2.0, tile_grid: tuple[int, int] = (8, 8), space: str = "lab") -> None:
        clip_limit = number_option("clip_limit", clip_limit, "finite and >= 0")
        if clip_limit < 0:
            raise OptionError(f"clip_limit must be finite and >= 0, got {clip_limit!r}")
        # at most MAX_TILES a side: OpenCV keeps a 256-entry table per tile, so (10000, 10000) asked it for 25 GB
        # and failed deep inside it (cv2.error "Insufficient memory"); an int raised "not iterable"
        accepted = f"two integers 1..{MAX_TILES}"
        tiles = list(tile_grid) if isinstance(tile_grid, Iterable) and not isinstance(tile_grid, (str, bytes)) else []
        try:
            grid = tuple(integer_option("tile_grid", t, accepted) for t in tiles) if len(tiles) == 2 else ()
        except OptionError:
            grid = ()  # refused below, naming the whole grid
        if len(grid) != 2 or not all(1 <= t <= MAX_TILES for t in grid):
            raise OptionError(f"tile_grid must be {accepted}, got {tile_grid!r}")
        if space not in _CLAHE_SPACES:
            raise OptionError(f"space must be one of {', '.join(_CLAHE_SPACES)}, got {space!r}")
        self.clip_limit = clip_limit
        self.tile_grid: tuple[int, int] = (grid[0], grid[1])
        self.space = space

    def stream(self) -> MethodStream:
        return _ClaheStream(self.clip_limit, self.tile_grid, self.space)

    def parameters(self) -> dict[str, Any]:
        return {"clip_limit": self.clip_limit, "tile_grid": list(self.tile_grid), "space": self.space}
