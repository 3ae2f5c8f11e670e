"""Per-pixel tone curves as 256-entry lookup tables.

A global curve maps each 8-bit value to one 8-bit value, so applying it through a table is exact and costs one
memory lookup per sample (``cv2.LUT``), whatever the frame size. This is how a gamma predicted on a small copy of a
frame is applied to the full-resolution frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from .errors import OptionError
from .methods.base import number_option

_LEVELS = np.arange(256, dtype=np.float64) / 255.0
#: The table that leaves every value as it is (read-only: shared).
IDENTITY_LUT = np.arange(256, dtype=np.uint8)
IDENTITY_LUT.flags.writeable = False


def _positive(name: str, value: float) -> float:
    """``value`` as a finite positive float, else :class:`OptionError` naming it (an int past a float's range or
    a value of no number type failed in numpy's ``isfinite`` with a TypeError that named nothing): the methods'
    own rule for a number option (:func:`~colonlight.methods.base.number_option`), with the range."""
    number = number_option(name, value, "finite and > 0")
    if number <= 0:
        raise OptionError(f"{name} must be finite and > 0, got {value!r}")
    return number


def gamma_lut(gamma: float) -> np.ndarray:
    """The table of ``round(255 * (v / 255) ** gamma)`` for v in 0..255, as uint8.

    ``gamma`` must be finite and positive (``gamma < 1`` brightens). Computed in float64 and rounded with
    ``numpy.rint`` (round half to even, like Python's ``round``), so it is bit-identical to that formula.
    """
    gamma = _positive("gamma", gamma)
    return np.rint(255.0 * _LEVELS**gamma).astype(np.uint8)


def gain_gamma_lut(gain: float, gamma: float) -> np.ndarray:
    """The table of ``round(255 * min(1, gain * (v / 255) ** gamma))`` for v in 0..255, as uint8.

    ``gain == 1`` gives exactly :func:`gamma_lut`. Both must be finite and positive.
    """
    gain = _positive("gain", gain)
    if gain == 1.0:
        return gamma_lut(gamma)
    gamma = _positive("gamma", gamma)
    return np.rint(255.0 * np.minimum(1.0, gain * _LEVELS**gamma)).astype(np.uint8)


def curve_lut(knots: Sequence[float] | np.ndarray, values: Sequence[float] | np.ndarray) -> np.ndarray:
    """The table of ``round(255 * min(1, f(v / 255)))`` for the piecewise-linear curve ``f`` through
    ``(knots[i], values[i])``, as uint8. ``values`` must be finite and non-decreasing, ``knots`` increasing."""
    x = np.asarray(knots, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 1 or len(x) < 2 or np.any(np.diff(x) <= 0):
        raise OptionError("a curve needs as many increasing knots as values (at least 2)")
    if not np.all(np.isfinite(y)) or np.any(np.diff(y) < 0):
        raise OptionError("a curve's values must be finite and non-decreasing")
    return np.rint(255.0 * np.clip(np.interp(_LEVELS, x, y), 0.0, 1.0)).astype(np.uint8)


def apply_lut(frame: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Apply a 256-entry uint8 table to every sample of a uint8 image (any channel count)."""
    if lut.shape != (256,) or lut.dtype != np.uint8:
        raise ValueError(f"lut must be (256,) uint8, got {lut.shape} {lut.dtype}")
    if frame.dtype != np.uint8:
        raise ValueError(f"frame must be uint8, got {frame.dtype}")
    return cv2.LUT(frame, lut)


def apply_gamma(frame: np.ndarray, gamma: float) -> np.ndarray:
    """``round(255 * (frame / 255) ** gamma)`` for a uint8 frame, through a lookup table."""
    return apply_lut(frame, gamma_lut(gamma))
