"""The one small interface every enhancement method implements.

A :class:`Method` holds what is shared across clips (a loaded network, parameters) and is built once per worker.
For each clip it hands out a fresh :class:`MethodStream`, which holds the per-clip state (a recurrent state, a
temporal window) and turns frames, pushed in order, into :class:`FrameResult` s. A stream may hold frames back
(FFmpeg's deflicker looks ahead), so ``push`` returns zero or more results and ``flush`` returns the rest; results
always come out in input order, one per input frame.
"""

from __future__ import annotations

import math
import numbers
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..errors import FrameShapeError, OptionError


@dataclass(frozen=True)
class FrameResult:
    """One enhanced frame.

    Attributes:
        frame: ``(H, W, 3)`` uint8 RGB, same size as the input frame.
        gamma: the exponent applied to the frame (``out = in ** gamma``) when the method has one per frame,
            else ``None``.
        info: per-frame facts worth recording (e.g. ``{"seed": True}``, ``{"clamped": True, "a": 0.0}``).
    """

    frame: np.ndarray
    gamma: float | None = None
    info: dict[str, Any] = field(default_factory=dict)


class MethodStream(ABC):
    """Per-clip state of a method. Frames go in order; results come out in order."""

    @abstractmethod
    def push(self, frame: np.ndarray) -> list[FrameResult]:
        """Feed one ``(H, W, 3)`` uint8 RGB frame; return the results now ready (possibly none)."""

    def flush(self) -> list[FrameResult]:
        """End of clip: return results still held back."""
        return []


class Method(ABC):
    """An enhancement method; build once, then call :meth:`stream` for every clip."""

    name: ClassVar[str]

    @abstractmethod
    def stream(self) -> MethodStream:
        """A fresh per-clip stream (state reset)."""

    def parameters(self) -> dict[str, Any]:
        """Parameters that, with :meth:`model_info`, reproduce this method's output (recorded in gammas.json)."""
        return {}

    def model_info(self) -> dict[str, Any] | None:
        """``{"name": ..., "sha256": ...}`` of the weights used, or ``None`` for methods without weights."""
        return None


def check_frame(frame: np.ndarray) -> None:
    """Raise ``FrameShapeError`` (a ``ValueError``) unless ``frame`` is a non-empty ``(H, W, 3)`` uint8 array."""
    if not isinstance(frame, np.ndarray) or frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        shape = getattr(frame, "shape", None)
        dtype = getattr(frame, "dtype", type(frame).__name__)
        raise FrameShapeError(f"expected an (H, W, 3) uint8 RGB frame, got shape {shape} dtype {dtype}")
    if frame.size == 0:  # would fail deep inside OpenCV or torch, each in its own way
        raise FrameShapeError(f"empty frame of shape {frame.shape}: a frame needs at least one pixel")


def number_option(name: str, value: object, accepted: str, *, text: bool = True) -> float:
    """A method constructor's numeric option as a finite float (from an int, a float, a numpy number or, with
    ``text``, its text), for the caller's own range check; else :class:`OptionError` ``"{name} must be {accepted},
    got {value!r}"``.

    ``float()`` of the Python API's values raised TypeError (None), OverflowError (an int past a float's range)
    or took ``True`` as 1; a string compared with a float raised TypeError: none of them named the option."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, str) if text else numbers.Real):
        raise OptionError(f"{name} must be {accepted}, got {value!r}")
    try:
        number = float(value)
    except (ValueError, OverflowError):
        raise OptionError(f"{name} must be {accepted}, got {value!r}") from None
    if not math.isfinite(number):
        raise OptionError(f"{name} must be {accepted}, got {value!r}")
    return number


def integer_option(name: str, value: object, accepted: str) -> int:
    """A method constructor's whole-number option (an int, a numpy integer or a float of integral value), for the
    caller's own range check; else :class:`OptionError` as :func:`number_option` (``int()`` of NaN or an
    infinity raised ValueError or OverflowError; ``1.5`` was truncated silently)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise OptionError(f"{name} must be {accepted}, got {value!r}")
    if isinstance(value, numbers.Integral):
        return int(value)
    number = float(value)
    if not number.is_integer():  # also NaN and the infinities
        raise OptionError(f"{name} must be {accepted}, got {value!r}")
    return int(number)
