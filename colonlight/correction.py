"""What the network's head outputs mean: the per-frame correction, in torch (training) and as a LUT (inference).

One place decides it for training, inference and export, so they cannot drift apart:

* head ``gamma`` (the paper's): ``a`` -> ``out = in ** (1/a)``; the reported gamma is ``1/a``.
* head ``gain-gamma``: raw ``(z0, z1)`` -> ``gamma = exp(LOG_GAMMA_SPAN * tanh(z0))``,
  ``gain = exp(LOG_GAIN_SPAN * tanh(z1))``, ``out = min(1, gain * in ** gamma)``. Zero outputs are the identity.
  Why two numbers: a recorder's lighting changes are a gain (exposure, light power) and a tone-curve change
  (contrast): ``image = g * clean ** k``. Its inverse ``clean = g**(-1/k) * image ** (1/k)`` is in this family,
  while one gamma can undo only one of the two.

Values are in [0, 1]; 8-bit frames are corrected through a 256-entry table (``curves.gain_gamma_lut``).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

#: ``|log gamma|`` and ``|log gain|`` the gain-gamma head can reach (tanh-bounded, so training stays stable).
LOG_GAMMA_SPAN = 2.0
LOG_GAIN_SPAN = 1.2


def gain_gamma_from_raw(z: Tensor) -> tuple[Tensor, Tensor]:
    """``(..., 2)`` raw head outputs -> ``(gain, gamma)``, each ``(...)``; differentiable."""
    gamma = torch.exp(LOG_GAMMA_SPAN * torch.tanh(z[..., 0]))
    gain = torch.exp(LOG_GAIN_SPAN * torch.tanh(z[..., 1]))
    return gain, gamma


def gain_gamma_values(z0: float, z1: float) -> tuple[float, float]:
    """The same mapping for one frame's two floats (inference): ``(gain, gamma)`` in float64."""
    return math.exp(LOG_GAIN_SPAN * math.tanh(z1)), math.exp(LOG_GAMMA_SPAN * math.tanh(z0))


def apply_gain_gamma(frames: Tensor, gain: Tensor, gamma: Tensor, eps: float = 1e-6) -> Tensor:
    """Differentiable ``min(1, gain * I ** gamma)``; ``gain``/``gamma`` broadcast over ``(..., 3, H, W)``."""
    while gamma.ndim < frames.ndim:
        gamma = gamma.unsqueeze(-1)
        gain = gain.unsqueeze(-1)
    return (gain * frames.clamp_min(eps) ** gamma).clamp_max(1.0)
