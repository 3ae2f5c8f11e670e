"""What the network's head outputs mean: the per-frame correction, in torch (training) and as a LUT (inference).

One place decides it for training, inference and export, so they cannot drift apart:

* head ``gamma`` (the paper's): ``a`` -> ``out = in ** (1/a)``; the reported gamma is ``1/a``.
* head ``gain-gamma``: raw ``(z0, z1)`` -> ``gamma = exp(LOG_GAMMA_SPAN * tanh(z0))``,
  ``gain = exp(LOG_GAIN_SPAN * tanh(z1))``, ``out = min(1, gain * in ** gamma)``. Zero outputs are the identity.
  Why two numbers: a recorder's lighting changes are a gain (exposure, light power) and a tone-curve change
  (contrast): ``image = g * clean ** k``. Its inverse ``clean = g**(-1/k) * image ** (1/k)`` is in this family,
  while one gamma can undo only one of the two.
* head ``curve``: raw ``z`` of ``CURVE_SEGMENTS`` numbers -> a monotone piecewise-linear tone curve through
  ``(0, 0)`` with slope ``softplus(z_k + SLOPE_OFFSET)`` on segment ``k`` of ``CURVE_KNOTS``, ``out = min(1, f(in))``.
  Zero outputs are the identity. Why: a recorder's response is not a power law (a highlight shoulder, a lagging
  exposure acting before it), and one gamma, or a gain and a gamma, leave part of a lighting change that a
  global curve removes (the per-frame oracle curve tracks where the oracle gamma fails, issue 12).

Values are in [0, 1]; 8-bit frames are corrected through a 256-entry table (``curves.gain_gamma_lut``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

#: ``|log gamma|`` and ``|log gain|`` the gain-gamma head can reach (tanh-bounded, so training stays stable).
LOG_GAMMA_SPAN = 2.0
LOG_GAIN_SPAN = 1.2


def correct(frames: Tensor, a: Tensor, eps: float = 1e-6) -> Tensor:
    """The gamma head's differentiable correction ``I ** (1/a)``; ``a`` broadcasts over ``(..., 3, H, W)``.

    ``a`` is floored at ``eps`` and the base at ``eps`` so that gradients stay finite.
    """
    gamma = 1.0 / a.clamp_min(eps)
    return frames.clamp_min(eps) ** per_frame(gamma, frames)


def apply_head(frames: Tensor, out: Tensor, head: str) -> Tensor:
    """Frames corrected by a head's raw outputs (``(...)`` for ``gamma``, ``(..., K)`` for the others), with
    ``frames`` ``(..., 3, H, W)``; differentiable."""
    if head == "gamma":
        return correct(frames, out)
    if head == "curve":
        return apply_curve(frames, curve_slopes_from_raw(out))
    gain, gamma = gain_gamma_from_raw(out)
    return apply_gain_gamma(frames, gain, gamma)


def gain_gamma_from_raw(z: Tensor) -> tuple[Tensor, Tensor]:
    """``(..., 2)`` raw head outputs -> ``(gain, gamma)``, each ``(...)``; differentiable."""
    gamma = torch.exp(LOG_GAMMA_SPAN * torch.tanh(z[..., 0]))
    gain = torch.exp(LOG_GAIN_SPAN * torch.tanh(z[..., 1]))
    return gain, gamma


def gain_gamma_values(z0: float, z1: float) -> tuple[float, float]:
    """The same mapping for one frame's two floats (inference): ``(gain, gamma)`` in float64."""
    return math.exp(LOG_GAIN_SPAN * math.tanh(z1)), math.exp(LOG_GAMMA_SPAN * math.tanh(z0))


def per_frame(value: Tensor, frames: Tensor) -> Tensor:
    """``value`` ``(...)``, one number per frame, with trailing axes added so that it broadcasts over ``frames``
    ``(..., 3, H, W)`` (or over any array with more axes than it, such as a 1-D table of levels)."""
    while value.ndim < frames.ndim:
        value = value.unsqueeze(-1)
    return value


def apply_gain_gamma(frames: Tensor, gain: Tensor, gamma: Tensor, eps: float = 1e-6) -> Tensor:
    """Differentiable ``min(1, gain * I ** gamma)``; ``gain``/``gamma`` broadcast over ``(..., 3, H, W)``."""
    return (per_frame(gain, frames) * frames.clamp_min(eps) ** per_frame(gamma, frames)).clamp_max(1.0)


#: Segments of the curve head's tone curve, and their end points on [0, 1]: spaced on a square-root scale so
#: the dark values a colonoscope's lumen fills get as many segments as the bright ones.
CURVE_SEGMENTS = 8
CURVE_KNOTS = tuple((k / CURVE_SEGMENTS) ** 2 for k in range(CURVE_SEGMENTS + 1))
#: ``softplus(0 + SLOPE_OFFSET) == 1``: a zero output layer gives the identity curve.
SLOPE_OFFSET = math.log(math.e - 1.0)
#: Steepest slope a segment may take (x ** 0.25 near 0.015 is about 23); beyond it the slope is clamped.
CURVE_SLOPE_MAX = 64.0


def curve_slopes_from_raw(z: Tensor) -> Tensor:
    """``(..., CURVE_SEGMENTS)`` raw head outputs -> the curve's slope on each segment; differentiable."""
    return torch.nn.functional.softplus(z + SLOPE_OFFSET).clamp_max(CURVE_SLOPE_MAX)


def apply_curve(frames: Tensor, slopes: Tensor) -> Tensor:
    """Differentiable ``min(1, f(I))`` for the curve with ``slopes`` ``(..., K)`` broadcast over ``(..., 3, H, W)``."""
    out = torch.zeros_like(frames)
    for k in range(CURVE_SEGMENTS):
        lo, width = CURVE_KNOTS[k], CURVE_KNOTS[k + 1] - CURVE_KNOTS[k]
        out = out + per_frame(slopes[..., k], frames) * (frames - lo).clamp(0.0, width)
    return out.clamp_max(1.0)


def curve_values(z: Sequence[float]) -> tuple[np.ndarray, bool]:
    """The same curve for one frame's raw outputs (inference): its values at ``CURVE_KNOTS`` in float64 (first
    0, non-decreasing, not yet capped at 1) and whether a slope was clamped. Non-finite outputs raise ValueError."""
    raw = np.asarray(z, dtype=np.float64)
    if raw.shape != (CURVE_SEGMENTS,) or not np.all(np.isfinite(raw)):
        raise ValueError(f"the curve head gives {CURVE_SEGMENTS} finite numbers, got {list(z)!r}")
    slopes = np.logaddexp(0.0, raw + SLOPE_OFFSET)  # softplus, without overflow
    clamped = bool(np.any(slopes > CURVE_SLOPE_MAX))
    slopes = np.minimum(slopes, CURVE_SLOPE_MAX)
    values = np.concatenate([[0.0], np.cumsum(slopes * np.diff(CURVE_KNOTS))])
    return values, clamped


#: Raw gain-gamma outputs the map below is fitted over: ``|z0| <= 0.1`` (gamma 0.82-1.22) and ``|z1| <= 0.3``
#: (gain 0.70-1.43), about twice the spread the shipped model's outputs have over its training clips.
GAIN_GAMMA_FIT_SPAN = (0.1, 0.3)


def gain_gamma_to_curve_map() -> np.ndarray:
    """``(CURVE_SEGMENTS, 2)`` matrix ``A``: ``A @ z`` is the curve head's raw output whose tone curve is closest to
    the gain-gamma head's for raw output ``z`` (least squares of the curve's raw slopes over a grid of ``z``).

    Why: a curve head started from a gain-gamma network's output layer mapped by ``A`` starts with that network's
    corrections (about 0.8 grey levels off, mean over typical outputs) instead of the identity, so a fine-tune
    begins where the gain-gamma model is instead of relearning it (session 16). Linear and without an intercept
    (zero is the identity of both heads), so it also holds for ``delta`` networks, whose outputs add up."""
    span0, span1 = GAIN_GAMMA_FIT_SPAN
    z0, z1 = np.meshgrid(np.linspace(-span0, span0, 21), np.linspace(-span1, span1, 21))
    z = np.stack([z0.ravel(), z1.ravel()], axis=1)
    gain, gamma = (t.numpy() for t in gain_gamma_from_raw(torch.from_numpy(z)))
    knots = np.asarray(CURVE_KNOTS)
    values = gain[:, None] * knots[None, :] ** gamma[:, None]  # the gain-gamma curve at the knots, uncapped
    slopes = np.clip(np.diff(values, axis=1) / np.diff(knots)[None, :], 1e-3, CURVE_SLOPE_MAX)
    raw = np.log(np.expm1(slopes)) - SLOPE_OFFSET  # softplus's inverse
    solution, *_ = np.linalg.lstsq(z, raw, rcond=None)
    mapping: np.ndarray = solution.T
    return mapping
