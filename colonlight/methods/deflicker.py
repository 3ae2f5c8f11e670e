"""``deflicker``: FFmpeg's ``deflicker`` filter (libavfilter/vf_deflicker.c), on RGB frames.

One global gain per frame pulls its mean luma towards a mean of the luma of the next ``size`` frames
(look-ahead window, current frame included). FFmpeg works on the Y plane after its automatic RGB -> YUV
conversion (BT.601, limited range); :func:`ffmpeg_luma` reproduces that conversion bit for bit, so the
measured luminances equal FFmpeg's. The gain multiplies Y only: ``Y' = clip(trunc(Y * f))``. We then add one
offset to R, G and B of each pixel (:func:`set_luma`), which changes Y and keeps Cb and Cr, chosen so that
FFmpeg's conversion of our output gives exactly ``Y'`` (except where R, G or B saturate: Y' above 235 has no
RGB). There is no chroma subsampling and no lossy RGB -> YUV -> RGB round trip (``f = 1`` returns the frame
unchanged).

By default the filter's defects are fixed (true median, float64 with scaling so no overflow, an epsilon guard,
short clips padded by replication); ``ffmpeg_compatible=True`` reproduces them (see
``/work/shared/baselines.md``).
"""

from __future__ import annotations

import math
import numbers
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any, Generic, TypeVar

import numpy as np

from ..errors import OptionError
from .base import FrameResult, Method, MethodStream, check_frame

MODES = ("am", "gm", "hm", "qm", "cm", "pm", "median")
MIN_SIZE, MAX_SIZE = 2, 129  # FFmpeg's option range
_EPS = 1e-6  # luminance floor (code values) for the logs and reciprocals of gm/hm in the fixed version

# FFmpeg's RGB -> Y (libswscale, BT.601 limited range, coefficients derived from its YUV -> RGB table).
_RY, _GY, _BY = 8414, 16519, 3208
_Y_OFFSET = (32 << 14) + (1 << 8)
_INT_MIN = -(2**31)

T = TypeVar("T")


def _luma_numerator(frame: np.ndarray) -> np.ndarray:
    f = frame.astype(np.int32)
    return _RY * f[..., 0] + _GY * f[..., 1] + _BY * f[..., 2] + _Y_OFFSET


def ffmpeg_luma(frame: np.ndarray) -> np.ndarray:
    """Y plane of FFmpeg's automatic ``rgb24 -> yuv`` conversion, bit-exact (checked on all 2^24 colours).

    ``Y14 = (8414 R + 16519 G + 3208 B + (32 << 14) + (1 << 8)) >> 9``, then ``Y = (Y14 + 32) >> 6``.

    Args:
        frame: ``(H, W, 3)`` uint8 RGB.

    Returns:
        ``(H, W)`` uint8, range 16..235.
    """
    return (((_luma_numerator(frame) >> 9) + 32) >> 6).astype(np.uint8)


def set_luma(frame: np.ndarray, luma: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Add one offset ``o`` to R, G and B of each pixel so that :func:`ffmpeg_luma` becomes ``target``.

    Adding the same ``o`` to R, G and B leaves Cb and Cr unchanged (up to rounding), i.e. it changes Y only.
    Each unit of ``o`` moves FFmpeg's Y by 219/255 < 1 code, so some integer ``o`` hits ``target`` exactly: we
    take the one nearest ``(target - Y) * 255 / 219``. Only where R, G or B would leave 0..255 does clipping
    miss it.

    Args:
        frame: ``(H, W, 3)`` uint8 RGB; ``luma``: its :func:`ffmpeg_luma`; ``target``: ``(H, W)`` wanted Y
            (int).

    Returns:
        ``(H, W, 3)`` uint8 RGB.
    """
    num = _luma_numerator(frame)
    t = target.astype(np.int32) << 15  # Y == t  <=>  32768 t - 16384 <= num + 28141 o <= 32768 t + 16383
    step = _RY + _GY + _BY
    lo = -((num - t + 16384) // step)  # ceil((t - 16384 - num) / step)
    hi = (t + 16383 - num) // step
    ideal = np.rint((target.astype(np.float32) - luma) * np.float32(255.0 / 219.0)).astype(np.int32)
    o = np.clip(ideal, lo, hi).astype(np.int16)
    shifted: np.ndarray = np.clip(frame.astype(np.int16) + o[..., None], 0, 255).astype(np.uint8)
    return shifted


def plane_luminance(plane: np.ndarray, ffmpeg_compatible: bool = False) -> float:
    """Mean of every sample of a luma plane, in code values (FFmpeg: ``1.0f * sum / (w * h)`` in float32)."""
    total = int(np.bincount(plane.ravel(), minlength=256) @ np.arange(256, dtype=np.int64))
    if ffmpeg_compatible:
        return float(np.float32(total) / np.float32(plane.size))
    return total / plane.size


@cache
def ffmpeg_median_slot(size: int) -> int:
    """The window slot FFmpeg's broken median returns (its qsort compares element addresses, not values).

    We run FFmpeg's ``AV_QSORT`` on slot indices with that comparator and read the slot left at ``size // 2``:
    1, 1, 1, 3, 3, 2, 2, 7 for sizes 2..9 (3, i.e. frame k + 3, for the default size 5).
    """
    a = list(range(size))

    def swap(i: int, j: int) -> None:
        a[i], a[j] = a[j], a[i]

    stack = [(0, size - 1)]
    while stack:  # a literal transcription of libavutil/qsort.h with cmp(p, q) = p - q
        start, end = stack.pop()
        while start < end:
            if start >= end - 1:
                if start > end:
                    swap(start, end)
                break
            checksort = False
            right, left, mid = end - 2, start + 1, start + ((end - start) >> 1)
            if start > end:
                swap(start, mid if end > mid else end)
            elif start > mid:
                swap(start, mid)
            else:
                checksort = True
            if mid > end:
                swap(mid, end)
                checksort = False
            if start == end - 2:
                break
            swap(end - 1, mid)
            while left <= right:
                while left <= right and left < end - 1:
                    left += 1
                while left <= right and right > end - 1:
                    right -= 1
                if left <= right:
                    swap(left, right)
                    left += 1
                    right -= 1
            swap(end - 1, left)
            if checksort and (mid == left - 1 or mid == left):
                mid = start
                while mid < end and mid <= mid + 1:
                    mid += 1
                if mid == end:
                    break
            if end - left < left - start:
                stack.append((start, right))
                start = left + 1
            else:
                stack.append((left + 1, end))
                end = right
    return a[size >> 1]


_CBRT_FACTOR = (
    1.0 / 1.5874010519681994748,
    1.0 / 1.2599210498948731648,
    1.0,
    1.2599210498948731648,
    1.5874010519681994748,
)


def _glibc_cbrtf(x: np.float32) -> np.float32:
    """glibc's ``cbrtf`` (not correctly rounded; FFmpeg's build uses it), step for step.

    Its cubic-root estimate is evaluated in x87 long double, refined once in double and rounded to float.
    """
    if x == 0 or not np.isfinite(x):
        return np.float32(x + x)
    xm, xe = np.frexp(np.float32(abs(x)))
    xm, xe = np.float32(xm), int(xe)
    ld = np.longdouble
    u = np.float32(
        ld("0.492659620528969547") + (ld("0.697570460207922770") - ld("0.191502161678719066") * ld(xm)) * ld(xm)
    )
    t2 = np.float32(np.float32(u * u) * u)
    ym = np.float32(
        float(u)
        * (float(t2) + 2.0 * float(xm))
        / (2.0 * float(t2) + float(xm))
        * _CBRT_FACTOR[2 + int(math.fmod(xe, 3))]
    )
    return np.float32(np.ldexp(ym if x > 0 else -ym, int(xe / 3)))


def _mean_f32(window: Sequence[float], mode: str) -> np.float32:
    """FFmpeg's window mean, operation for operation in float32 (overflow to inf, 1/0 = inf included)."""
    f32 = np.float32
    s = len(window)
    lum = [f32(v) for v in window]
    with np.errstate(all="ignore"):
        if mode == "am":
            f = f32(0)
            for v in lum:
                f = f32(f + v)
            return f32(f / f32(s))
        if mode == "gm":
            f = f32(1)
            for v in lum:
                f = f32(f * v)
            return f32(np.power(np.float64(f), np.float64(f32(1) / f32(s))))  # C pow() on doubles
        if mode == "hm":
            f = f32(0)
            for v in lum:
                f = f32(f + f32(1) / v)
            return f32(f32(s) / f)
        if mode in ("qm", "cm"):
            f = f32(0)
            for v in lum:
                f = f32(f + (v * v if mode == "qm" else v * v * v))
            f = f32(f / f32(s))
            return f32(np.sqrt(f)) if mode == "qm" else _glibc_cbrtf(f)
        if mode == "pm":
            f = f32(0)
            for v in lum:
                f = f32(f + np.power(v, f32(s)))
            f = f32(f / f32(s))
            return f32(np.power(f, f32(1) / f32(s)))
        return lum[ffmpeg_median_slot(s)]


def _mean_f64(window: Sequence[float], mode: str) -> float:
    """The intended window mean in float64, scaled by the window maximum so that no power can overflow."""
    lum = np.asarray(window, dtype=np.float64)
    s = lum.size
    if mode == "am":
        return float(lum.mean())
    if mode == "gm":
        return float(np.exp(np.log(np.maximum(lum, _EPS)).mean()))
    if mode == "hm":
        return float(s / np.sum(1.0 / np.maximum(lum, _EPS)))
    if mode == "median":
        return float(np.sort(lum)[s // 2])
    p = {"qm": 2.0, "cm": 3.0, "pm": float(s)}[mode]
    top = lum.max()
    if top <= 0:
        return 0.0
    return float(top * np.mean((lum / top) ** p) ** (1.0 / p))


def deflicker_factor(window: Sequence[float], mode: str = "am", ffmpeg_compatible: bool = False) -> float:
    """The gain ``f = M(window) / window[0]`` for the frame at ``window[0]``.

    Args:
        window: luminances ``L_k .. L_{k+s-1}`` (current frame first).
        mode: one of :data:`MODES`.
        ffmpeg_compatible: float32 arithmetic and FFmpeg's broken median; ``L_k = 0`` gives inf/nan as FFmpeg.
            Otherwise float64, a true median (sorted value at ``s // 2``), and ``f = 1`` when ``L_k = 0``.

    Returns:
        The factor (may be inf or nan only in compatible mode).
    """
    if mode not in MODES:
        raise OptionError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    if ffmpeg_compatible:
        with np.errstate(all="ignore"):
            return float(_mean_f32(window, mode) / np.float32(window[0]))
    if window[0] <= 0:
        return 1.0
    return _mean_f64(window, mode) / float(window[0])


def luma_gain_lut(factor: float, ffmpeg_compatible: bool = False) -> np.ndarray:
    """``clip(trunc(Y * f), 0, 255)`` for Y = 0..255 as an int16 table.

    The fixed version adds 1e-9 before truncating, so that an exact gain of 1 that float rounding turned into
    ``1 - 1e-16`` (e.g. the harmonic mean of a constant window) does not darken every sample by one code.

    Compatible mode multiplies in float32 and converts to int as x86 does: inf, nan and values beyond int32
    become INT_MIN and so clip to 0 (why FFmpeg's overflowing gm/pm frames come out black).
    """
    levels = np.arange(256)
    if ffmpeg_compatible:
        with np.errstate(all="ignore"):
            prod = levels.astype(np.float32) * np.float32(factor)
        ok = np.isfinite(prod) & (prod > -(2.0**31)) & (prod < 2.0**31)
        out = np.where(ok, np.trunc(np.where(ok, prod, 0)), _INT_MIN)
    else:
        # The 1e-9 keeps a product that float rounding put just below an integer (f = 1 - 1e-16 for a constant
        # window) from being truncated a whole code value down.
        out = np.trunc(levels * factor + 1e-9) if math.isfinite(factor) else np.where(levels > 0, 255, 0)
    return np.clip(out, 0, 255).astype(np.int16)


class LookAheadWindow(Generic[T]):
    """FFmpeg's deflicker window bookkeeping on luminances, with an arbitrary payload per frame.

    ``push`` returns ``(payload, window)`` for the oldest frame as soon as its window ``L_k .. L_{k+s-1}`` is
    complete (latency ``size - 1`` frames; FFmpeg holds one frame more, which does not change any value).
    ``flush`` returns the rest, the windows padded by repeating the last luminance. In compatible mode a clip
    shorter than ``size`` gets FFmpeg's windows instead, whose empty slots hold 0.
    """

    def __init__(self, size: int, ffmpeg_compatible: bool = False) -> None:
        self.size = size
        self.compatible = ffmpeg_compatible
        self._items: deque[tuple[T, float]] = deque()
        self._count = 0

    def push(self, payload: T, luminance: float) -> list[tuple[T, list[float]]]:
        self._items.append((payload, luminance))
        self._count += 1
        if len(self._items) < self.size:
            return []
        window = [lum for _, lum in self._items]
        payload0, _ = self._items.popleft()
        return [(payload0, window)]

    def flush(self) -> list[tuple[T, list[float]]]:
        items = list(self._items)
        self._items.clear()
        if not items:
            return []
        lums = [lum for _, lum in items]
        if self.compatible and self._count < self.size:
            windows = _ffmpeg_short_windows(lums, self.size)
        else:
            padded = lums + [lums[-1]] * self.size
            windows = [padded[k : k + self.size] for k in range(len(items))]
        self._count = 0
        return [(payload, w) for (payload, _), w in zip(items, windows, strict=True)]


def _ffmpeg_short_windows(lums: list[float], size: int) -> list[list[float]]:
    """Windows FFmpeg uses when the clip has fewer than ``size`` frames: replay of its end-of-stream path."""
    slots = [0.0] * size
    slots[: len(lums)] = lums
    available = len(lums)
    windows = []
    for _ in lums:
        windows.append(list(slots))
        slots[: size - 1] = slots[1:size]  # memmove of size - 1 slots; the last slot keeps its value
        slots[available - 1] = lums[-1]  # the clone of the last queued frame
        available -= 1
    return windows


@dataclass(frozen=True)
class _Pending:
    frame: np.ndarray
    luma: np.ndarray


def _result(pending: _Pending, window: list[float], mode: str, compatible: bool) -> FrameResult:
    lum = window[0]
    f = deflicker_factor(window, mode, compatible)
    lut = luma_gain_lut(f, compatible)
    if np.array_equal(lut, np.arange(256)):
        out = pending.frame
    else:
        out = set_luma(pending.frame, pending.luma, lut[pending.luma])
    finite = math.isfinite(f)
    info: dict[str, Any] = {
        "luminance": lum,
        "new_luminance": lum * f if finite else None,
        "relative_change": f - 1.0 if finite else None,
    }
    if not finite:
        info["overflow"] = True
    return FrameResult(frame=out, gamma=None, info=info)


class _DeflickerStream(MethodStream):
    def __init__(self, size: int, mode: str, compatible: bool) -> None:
        self._mode = mode
        self._compatible = compatible
        self._window: LookAheadWindow[_Pending] = LookAheadWindow(size, compatible)

    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        luma = ffmpeg_luma(frame)
        # A copy: the frame is held for up to ``size - 1`` pushes and callers may reuse their buffers.
        ready = self._window.push(_Pending(frame.copy(), luma), plane_luminance(luma, self._compatible))
        return [_result(p, w, self._mode, self._compatible) for p, w in ready]

    def flush(self) -> list[FrameResult]:
        return [_result(p, w, self._mode, self._compatible) for p, w in self._window.flush()]


def deflicker_planes(
    planes: Iterable[np.ndarray], size: int = 5, mode: str = "am", ffmpeg_compatible: bool = False
) -> list[tuple[np.ndarray, float]]:
    """The filter on 8-bit luma planes, as FFmpeg applies it to a yuv clip (chroma is copied, so not needed).

    Args:
        planes: ``(H, W)`` uint8 Y planes in clip order.

    Returns:
        ``(Y_out, factor)`` per input plane, in order.
    """
    window: LookAheadWindow[np.ndarray] = LookAheadWindow(size, ffmpeg_compatible)
    ready = []
    for plane in planes:
        ready += window.push(plane, plane_luminance(plane, ffmpeg_compatible))
    ready += window.flush()
    out = []
    for plane, w in ready:
        f = deflicker_factor(w, mode, ffmpeg_compatible)
        out.append((luma_gain_lut(f, ffmpeg_compatible).astype(np.uint8)[plane], f))
    return out


class DeflickerMethod(Method):
    """FFmpeg's ``deflicker`` (global luma gain towards a look-ahead mean), on RGB frames.

    Results lag the input by ``size - 1`` frames; :meth:`MethodStream.flush` returns the rest (one output per
    input, in order). The gain is not a gamma, so ``FrameResult.gamma`` is ``None``; ``info`` carries FFmpeg's
    metadata ``luminance``, ``new_luminance`` and ``relative_change``.

    Args:
        size: window length, 2..129 (FFmpeg's default 5).
        mode: ``am`` (default), ``gm``, ``hm``, ``qm``, ``cm``, ``pm`` or ``median``.
        ffmpeg_compatible: reproduce FFmpeg's defects (broken median slot, float32 overflow to black, zero
            slots for clips shorter than ``size``) instead of fixing them.
    """

    name = "deflicker"

    def __init__(self, size: int = 5, mode: str = "am", ffmpeg_compatible: bool = False) -> None:
        finite = isinstance(size, numbers.Real) and not isinstance(size, bool) and math.isfinite(size)
        if not finite or int(size) != size or not MIN_SIZE <= int(size) <= MAX_SIZE:  # int(nan) would raise
            raise OptionError(f"size must be an integer in {MIN_SIZE}..{MAX_SIZE}, got {size!r}")
        if mode not in MODES:
            raise OptionError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.size = int(size)
        self.mode = mode
        self.ffmpeg_compatible = bool(ffmpeg_compatible)

    def stream(self) -> MethodStream:
        return _DeflickerStream(self.size, self.mode, self.ffmpeg_compatible)

    def parameters(self) -> dict[str, Any]:
        return {"size": self.size, "mode": self.mode, "ffmpeg_compatible": self.ffmpeg_compatible}
