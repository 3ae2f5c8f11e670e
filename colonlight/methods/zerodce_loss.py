"""Zero-DCE's non-reference losses, exactly as the official ``Myloss.py`` and training script compute them.

Where the paper differs (absolute values, sums of squares) the code is followed. All take ``(B, C, H, W)``
tensors; images in [0, 1].
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F

EXPOSURE_LEVEL = 0.6  # E
EXPOSURE_PATCH = 16
SPATIAL_REGION = 4


@dataclass(frozen=True)
class LossWeights:
    """Weights of the total loss; defaults from the official Zero-DCE training script (++: W_tvA 1600).

    The colonoscopy retraining drops colour constancy (``colour_constancy=0``): colon frames are strongly red
    and a gray-world term would push them to gray.
    """

    spatial: float = 1.0
    exposure: float = 10.0
    colour_constancy: float = 5.0
    illumination_smoothness: float = 200.0

    @classmethod
    def for_variant(cls, variant: str, colour_constancy: float = 5.0) -> LossWeights:
        """Official weights of ``zerodce`` or ``zerodce++`` with the given colour-constancy weight."""
        return cls(
            colour_constancy=colour_constancy,
            illumination_smoothness=1600.0 if variant == "zerodce++" else 200.0,
        )

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _neighbour_differences(y: torch.Tensor) -> torch.Tensor:
    """Signed differences cell - neighbour (left, right, up, down) with zeros outside: ``(B, 4, h, w)``."""
    p = F.pad(y, (1, 1, 1, 1))
    c = p[..., 1:-1, 1:-1]
    return torch.cat([c - p[..., 1:-1, :-2], c - p[..., 1:-1, 2:], c - p[..., :-2, 1:-1], c - p[..., 2:, 1:-1]], 1)


def spatial_consistency_loss(enhanced: torch.Tensor, original: torch.Tensor) -> torch.Tensor:
    """L_spa: channel means, 4x4 mean pooling, per cell the sum over 4 neighbours of (D_out - D_in)^2, mean.

    Border cells are compared against 0 (zero padding), as in the official convolutions.
    """
    y_out = F.avg_pool2d(enhanced.mean(1, keepdim=True), SPATIAL_REGION)
    y_in = F.avg_pool2d(original.mean(1, keepdim=True), SPATIAL_REGION)
    d = _neighbour_differences(y_out) - _neighbour_differences(y_in)
    return (d * d).sum(1).mean()


def exposure_loss(enhanced: torch.Tensor, level: float = EXPOSURE_LEVEL, patch: int = EXPOSURE_PATCH) -> torch.Tensor:
    """L_exp: mean over 16x16 patches of the channel mean of ``(Y_k - E)^2``, E = 0.6."""
    y = F.avg_pool2d(enhanced.mean(1, keepdim=True), patch)
    return ((y - level) ** 2).mean()


def colour_constancy_loss(enhanced: torch.Tensor) -> torch.Tensor:
    """L_col: per image sqrt((J_R-J_G)^4 + (J_R-J_B)^4 + (J_G-J_B)^4) of the channel means J; batch mean.

    The sum is floored at 1e-12 before the square root (value change <= 1e-6): at exactly gray images the
    official ``pow(., 0.5)`` has an infinite derivative and turns the gradients into NaN.
    """
    j = enhanced.mean((2, 3))
    d_rg = (j[:, 0] - j[:, 1]) ** 2
    d_rb = (j[:, 0] - j[:, 2]) ** 2
    d_gb = (j[:, 1] - j[:, 2]) ** 2
    return torch.sqrt((d_rg**2 + d_rb**2 + d_gb**2).clamp_min(1e-12)).mean()


def illumination_smoothness_loss(alphas: torch.Tensor) -> torch.Tensor:
    """L_tvA on the curve maps ``(B, C, H, W)``: (2/B) * [sum dv^2 / ((H-1) W) + sum dh^2 / (H (W-1))]."""
    b, _, h, w = alphas.shape
    dv = (alphas[:, :, 1:, :] - alphas[:, :, :-1, :]).pow(2).sum()
    dh = (alphas[:, :, :, 1:] - alphas[:, :, :, :-1]).pow(2).sum()
    return 2.0 * (dv / ((h - 1) * w) + dh / (h * (w - 1))) / b


def zerodce_loss(
    original: torch.Tensor, enhanced: torch.Tensor, alphas: torch.Tensor, weights: LossWeights = LossWeights()
) -> tuple[torch.Tensor, dict[str, float]]:
    """Total ``W_spa L_spa + W_exp L_exp + W_col L_col + W_tvA L_tvA``; also the unweighted terms (floats).

    ``colour_constancy = 0`` skips L_col entirely.
    """
    terms = {
        "spatial": spatial_consistency_loss(enhanced, original),
        "exposure": exposure_loss(enhanced),
        "illumination_smoothness": illumination_smoothness_loss(alphas),
    }
    if weights.colour_constancy:
        terms["colour_constancy"] = colour_constancy_loss(enhanced)
    w = weights.as_dict()
    total = sum(w[k] * v for k, v in terms.items())
    assert isinstance(total, torch.Tensor)
    return total, {k: float(v.detach()) for k, v in terms.items()}
