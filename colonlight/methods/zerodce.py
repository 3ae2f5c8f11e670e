"""``zerodce`` and ``zerodce++``: per-pixel curve estimation (Guo et al. 2020; Li et al. 2021) as baselines.

Both predict per-pixel maps ``A`` and iterate ``x <- x + A * (x**2 - x)`` on the full-resolution frame. They
keep no state between frames and have no single gamma (``FrameResult.gamma`` is ``None``).

Deviation from the official inference (documented, on by default): DCE-Net runs at the input resolution, which
costs 79,200 MAC per pixel (164 GMAC for a 1080p frame, seconds on a CPU). With ``max_side`` the network sees
a copy whose longer side is at most ``max_side`` (area downscaling) and its 24 maps are upsampled bilinearly
to the full frame, where the curves are applied. ``max_side=None`` restores the official full-resolution
inference. Zero-DCE++ has its own scale factor s (official: the net at 1/12 resolution), with reflection
padding instead of the official crop to multiples of s.

Weights are read from safetensors only (default ``colonlight/weights/zerodce.safetensors`` /
``zerodce++.safetensors``, shipped: trained by ``colonlight train --method zerodce|zerodce++`` on the default
model's synthetic clips without the colour-constancy loss; their cards give the exact command).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..checkpoint import WEIGHTS_DIR
from ..device import resolve_device
from ..errors import CheckpointError, OptionError
from .base import FrameResult, Method, MethodStream, check_frame, integer_option
from .zerodce_loss import (
    LossWeights,
    colour_constancy_loss,
    exposure_loss,
    illumination_smoothness_loss,
    spatial_consistency_loss,
    zerodce_loss,
)
from .zerodce_net import (
    DceNet,
    DcePlusPlusNet,
    apply_curves,
    build_net,
    count_parameters,
    curve_step,
    load_zerodce_weights,
    plusplus_alpha,
    save_zerodce_weights,
)
from .zerodce_train import ZeroDceTrainResult, train_zerodce

DEFAULT_WEIGHTS = {
    "zerodce": WEIGHTS_DIR / "zerodce.safetensors",
    "zerodce++": WEIGHTS_DIR / "zerodce++.safetensors",
}


def _to_tensor(frame: np.ndarray, device: torch.device) -> torch.Tensor:
    """``(H, W, 3)`` uint8 -> ``(1, 3, H, W)`` float32 in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(frame)).to(device).permute(2, 0, 1)[None].float().div_(255.0)


def _to_frame(x: torch.Tensor) -> np.ndarray:
    """``(1, 3, H, W)`` in [0, 1] -> ``(H, W, 3)`` uint8 (rounded)."""
    return x[0].clamp_(0.0, 1.0).mul_(255.0).round_().to(torch.uint8).permute(1, 2, 0).contiguous().cpu().numpy()


class _ZeroDceBase(Method):
    variant: str

    def __init__(self, weights: str | Path | None, device: str, iterations: int) -> None:
        if isinstance(iterations, bool) or int(iterations) != iterations or int(iterations) < 1:
            raise OptionError(f"iterations must be a positive integer, got {iterations!r}")
        self.iterations = int(iterations)
        self.weights = None if weights is None else str(weights)
        self.device = resolve_device(device)
        path = Path(weights) if weights is not None else DEFAULT_WEIGHTS[self.variant]
        if weights is None and not path.is_file():
            raise CheckpointError(
                f"{self.variant} weights are missing: {path} is not installed; train them "
                f"(colonlight train --method {self.variant}) or pass weights=PATH"
            )
        net, self.weights_name, self.weights_sha256 = load_zerodce_weights(path, self.variant)
        self.net = net.to(self.device)

    def model_info(self) -> dict[str, Any] | None:
        return {"name": self.weights_name, "sha256": self.weights_sha256}

    def parameters(self) -> dict[str, Any]:
        return {"weights": self.weights, "device": str(self.device), "iterations": self.iterations}

    def enhance(self, frame: np.ndarray) -> np.ndarray:
        """One ``(H, W, 3)`` uint8 RGB frame -> enhanced frame of the same shape."""
        raise NotImplementedError

    def stream(self) -> MethodStream:
        return _StatelessStream(self)


class _StatelessStream(MethodStream):
    def __init__(self, method: _ZeroDceBase) -> None:
        self._method = method

    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        return [FrameResult(frame=self._method.enhance(frame), gamma=None)]


class ZeroDceMethod(_ZeroDceBase):
    """Zero-DCE: DCE-Net's 8 RGB curve maps applied to the full frame.

    Args:
        weights: a ``.safetensors`` file; ``None`` = ``colonlight/weights/zerodce.safetensors`` (a
            :class:`CheckpointError` says so if it is missing).
        device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto``.
        iterations: curve steps, 1..8 (8 official; fewer uses the first maps, as the official
            ``enhance_image_1`` does with 4).
        max_side: longest side the network sees (default 512); maps are upsampled bilinearly. ``None`` or 0:
            full resolution (official, very slow on CPU).
    """

    name = "zerodce"
    variant = "zerodce"

    def __init__(
        self,
        weights: str | Path | None = None,
        device: str = "cpu",
        iterations: int = 8,
        max_side: int | None = 512,
    ) -> None:
        if iterations not in range(1, DceNet.n_maps + 1):
            raise OptionError(f"iterations must be 1..{DceNet.n_maps} for Zero-DCE, got {iterations!r}")
        accepted = "a positive integer or None"
        side = None if max_side is None else integer_option("max_side", max_side, accepted)  # int(nan) raised
        if side is not None and side < 0:
            raise OptionError(f"max_side must be {accepted}, got {max_side!r}")
        self.max_side = side or None
        super().__init__(weights, device, iterations)

    def parameters(self) -> dict[str, Any]:
        return {**super().parameters(), "max_side": self.max_side}

    @torch.inference_mode()
    def enhance(self, frame: np.ndarray) -> np.ndarray:
        h, w = frame.shape[:2]
        x = _to_tensor(frame, self.device)
        if self.max_side is None or max(h, w) <= self.max_side:
            return _to_frame(apply_curves(x, self.net(x), self.iterations))
        k = self.max_side / max(h, w)
        small = cv2.resize(frame, (max(1, round(w * k)), max(1, round(h * k))), interpolation=cv2.INTER_AREA)
        maps = self.net(_to_tensor(small, self.device))
        for t in range(self.iterations):  # upsample one map triplet at a time: 3 full-size planes, not 24
            a = F.interpolate(maps[:, 3 * t : 3 * t + 3], size=(h, w), mode="bilinear", align_corners=False)
            x = apply_curves(x, a, 1)
        return _to_frame(x)


class ZeroDcePlusPlusMethod(_ZeroDceBase):
    """Zero-DCE++: one 3-channel curve map from the network at 1/s resolution, reused for every step.

    Args:
        weights: a ``.safetensors`` file; ``None`` = ``colonlight/weights/zerodce++.safetensors``.
        device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto``.
        scale: s, the downscaling factor of the network input (12 in the official test); frames are
            reflect-padded to multiples of s rather than cropped.
        iterations: curve steps (8 official).
    """

    name = "zerodce++"
    variant = "zerodce++"

    def __init__(
        self, weights: str | Path | None = None, device: str = "cpu", scale: int = 12, iterations: int = 8
    ) -> None:
        self.scale = integer_option("scale", scale, "a positive integer")  # int(nan) raised ValueError
        if self.scale < 1:
            raise OptionError(f"scale must be a positive integer, got {scale!r}")
        super().__init__(weights, device, iterations)

    def parameters(self) -> dict[str, Any]:
        return {**super().parameters(), "scale": self.scale}

    @torch.inference_mode()
    def enhance(self, frame: np.ndarray) -> np.ndarray:
        x = _to_tensor(frame, self.device)
        assert isinstance(self.net, DcePlusPlusNet)
        return _to_frame(apply_curves(x, plusplus_alpha(self.net, x, self.scale), self.iterations))


__all__ = [
    "DEFAULT_WEIGHTS",
    "DceNet",
    "DcePlusPlusNet",
    "LossWeights",
    "ZeroDceMethod",
    "ZeroDcePlusPlusMethod",
    "ZeroDceTrainResult",
    "apply_curves",
    "build_net",
    "colour_constancy_loss",
    "count_parameters",
    "curve_step",
    "exposure_loss",
    "illumination_smoothness_loss",
    "load_zerodce_weights",
    "plusplus_alpha",
    "save_zerodce_weights",
    "spatial_consistency_loss",
    "train_zerodce",
    "zerodce_loss",
]
