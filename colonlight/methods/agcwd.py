"""``agcwd``: adaptive gamma correction with weighting distribution (Huang, Cheng & Chiu, IEEE TIP 2013).

A per-frame tone curve on V of HSV whose exponent per level, ``1 - cdf_w(l)``, comes from a flattened
histogram: levels that are common get brightened most. It is a 256-entry table, so it costs one lookup per
pixel.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import OptionError
from .base import FrameResult, Method, MethodStream, check_frame, number_option
from .histogram import scale_value, value_channel

_LEVELS = np.arange(256, dtype=np.float64)


def agcwd_lut(v: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """The AGCWD table ``T(l) = 255 * (l / 255) ** (1 - cdf_w(l))`` for the values in ``v``.

    ``pdf_w = pdf_max * ((pdf - pdf_min) / (pdf_max - pdf_min)) ** alpha`` and ``cdf_w`` is its normalised
    cumulative sum (l_max = 255). Degenerate cases: ``T(0) = 0`` always (the formula gives ``0 ** 0 = 1`` when
    all pixels are black, which would turn black white); a flat histogram (pdf_max = pdf_min) uses the pdf
    unweighted. Note that the brightest occupied level always has cdf_w = 1, so it maps to 255: a constant
    frame becomes white.

    Args:
        v: uint8 array of any shape (the V channel).
        alpha: the weighting exponent (0.5 in public implementations, 0.75 in "improved AGCWD" for dim
            images).

    Returns:
        ``(256,)`` uint8 table.
    """
    hist = np.bincount(v.ravel(), minlength=256).astype(np.float64)
    pdf = hist / hist.sum()
    pmin, pmax = pdf.min(), pdf.max()
    pdf_w = pmax * ((pdf - pmin) / (pmax - pmin)) ** alpha if pmax > pmin else pdf
    cdf_w = np.cumsum(pdf_w) / pdf_w.sum()
    gamma = np.clip(1.0 - cdf_w, 0.0, 1.0)
    lut = 255.0 * (_LEVELS / 255.0) ** gamma
    lut[0] = 0.0
    table: np.ndarray = np.clip(np.rint(lut), 0, 255).astype(np.uint8)
    return table


class _AgcwdStream(MethodStream):
    def __init__(self, alpha: float) -> None:
        self._alpha = alpha

    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        v = value_channel(frame)
        lut = agcwd_lut(v, self._alpha)
        return [FrameResult(frame=scale_value(frame, lut[v], v))]


class AgcwdMethod(Method):
    """AGCWD on V of HSV, one curve per frame (the paper's reuse of a curve across video frames is not done).

    V is changed with hue and saturation kept exactly (:func:`colonlight.methods.histogram.scale_value`),
    which equals an HSV round trip without OpenCV's 8-bit hue quantisation. No single gamma: reports ``None``.

    Args:
        alpha: weighting exponent, > 0 (default 0.5).
    """

    name = "agcwd"

    def __init__(self, alpha: float = 0.5) -> None:
        alpha = number_option("alpha", alpha, "finite and > 0")
        if alpha <= 0:
            raise OptionError(f"alpha must be finite and > 0, got {alpha!r}")
        self.alpha = alpha

    def stream(self) -> MethodStream:
        return _AgcwdStream(self.alpha)

    def parameters(self) -> dict[str, Any]:
        return {"alpha": self.alpha}
