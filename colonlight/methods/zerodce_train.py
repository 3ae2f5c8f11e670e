"""Training Zero-DCE / Zero-DCE++ with the official recipe on any RGB frames (no references needed).

The official recipe: frames resized to a square (256 for Zero-DCE), batch 8 shuffled, Adam lr 1e-4 with
weight decay 1e-4, global gradient norm clipped to 0.1; DCE-Net convolution weights from N(0, 0.02)
(Zero-DCE++ keeps PyTorch's initialisation and trains at scale 1). The colonoscopy retraining drops colour
constancy (the default here).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..atomic import remove_stale_temporaries_of
from .zerodce_loss import EXPOSURE_LEVEL, EXPOSURE_PATCH, SPATIAL_REGION, LossWeights, zerodce_loss
from .zerodce_net import VARIANTS, DceNet, apply_curves, build_net, count_parameters, save_zerodce_weights


@dataclass
class ZeroDceEpoch:
    epoch: int
    loss: float
    terms: dict[str, float]
    seconds: float


@dataclass
class ZeroDceTrainResult:
    weights: Path
    card: dict[str, Any]
    history: list[ZeroDceEpoch] = field(default_factory=list)


def to_training_tensor(frame: Any, size: int) -> torch.Tensor:
    """One frame as ``(3, size, size)`` float32 in [0, 1].

    Accepts ``(H, W, 3)`` arrays/tensors (uint8 0..255 or float 0..1) or ``(3, H, W)`` float tensors. The
    resize is antialiased bicubic (the official loader uses PIL's antialiasing filter, which is not available
    here).
    """
    t = torch.as_tensor(np.asarray(frame)) if not isinstance(frame, torch.Tensor) else frame
    if t.ndim != 3:
        raise ValueError(f"expected a 3-dimensional frame, got shape {tuple(t.shape)}")
    if t.shape[-1] == 3 and t.shape[0] != 3:
        t = t.permute(2, 0, 1)
    elif t.shape[0] != 3:
        raise ValueError(f"expected (H, W, 3) or (3, H, W), got shape {tuple(t.shape)}")
    t = t.float() / 255.0 if t.dtype == torch.uint8 else t.float()
    if t.shape[-2:] != (size, size):
        t = F.interpolate(t[None], size=(size, size), mode="bicubic", align_corners=False, antialias=True)[0]
    return t.clamp(0.0, 1.0).contiguous()


class _FrameSet:
    """Frames by index: an indexable dataset is read lazily; any other iterable is resized once, in memory."""

    def __init__(self, frames: Iterable[Any], size: int) -> None:
        self.size = size
        if hasattr(frames, "__getitem__") and hasattr(frames, "__len__"):
            self._source: Any = frames
            self._cache: list[torch.Tensor] | None = None
        else:
            self._source = None
            self._cache = [to_training_tensor(f, size) for f in frames]

    def __len__(self) -> int:
        return len(self._cache) if self._cache is not None else len(self._source)

    def batch(self, ids: np.ndarray) -> torch.Tensor:
        if self._cache is not None:
            return torch.stack([self._cache[i] for i in ids])
        return torch.stack([to_training_tensor(self._source[int(i)], self.size) for i in ids])


def _init_official(net: nn.Module) -> None:
    """DCE-Net's ``weights_init``: conv weights ~ N(0, 0.02); biases keep PyTorch's default."""
    for m in net.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.normal_(m.weight, 0.0, 0.02)


def _forward(net: nn.Module, x: torch.Tensor, iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
    alphas = net(x)  # Zero-DCE++ trains at scale 1: the net sees the full training crop
    return apply_curves(x, alphas, iterations), alphas


def train_zerodce(
    frames: Iterable[Any],
    variant: str = "zerodce",
    epochs: int = 200,
    lr: float = 1e-4,
    weight_decay: float = 1e-4,
    batch: int = 8,
    size: int = 256,
    grad_clip: float = 0.1,
    seed: int = 0,
    out_path: Path | str = "zerodce.safetensors",
    *,
    colour_constancy_weight: float = 0.0,
    iterations: int = 8,
    name: str | None = None,
    card_extra: dict[str, Any] | None = None,
    on_epoch: Callable[[ZeroDceEpoch], None] | None = None,
) -> ZeroDceTrainResult:
    """Train Zero-DCE (``variant="zerodce"``) or Zero-DCE++ (``"zerodce++"``); save safetensors and a card.

    Args:
        frames: RGB frames, ``(H, W, 3)`` uint8 or float in [0, 1] (or ``(3, H, W)`` tensors). An indexable
            dataset (``__len__`` and ``__getitem__``) is read lazily each epoch; any other iterable is resized
            and kept in memory (``size * size * 12`` bytes per frame).
        epochs, lr, weight_decay, batch, grad_clip: the optimiser settings (official: 200 / 100 epochs for
            Zero-DCE / Zero-DCE++, 1e-4, 1e-4, 8, 0.1). The last batch of an epoch may be smaller.
        size: square training size (official: 256 for Zero-DCE, 512 for Zero-DCE++).
        seed: seeds initialisation and shuffling. Runs repeat bit for bit with one CPU thread; with several,
            PyTorch's convolution gradients may differ in the last bits from run to run.
        out_path: the ``.safetensors`` to write; its card is written beside it as ``.json``.
        colour_constancy_weight: W_col; 0 (default) is the colonoscopy retraining, 5 the original Zero-DCE.
        iterations: curve steps (8).
        name, card_extra: recorded in the card.
        on_epoch: called after every epoch with its mean loss.

    Returns:
        Paths, card and per-epoch history.
    """
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if epochs < 1 or batch < 1 or size < 16:
        raise ValueError("epochs and batch must be >= 1 and size >= 16 (one exposure patch)")
    torch.manual_seed(seed)
    data = _FrameSet(frames, size)
    if len(data) == 0:
        raise ValueError("no training frames")
    net = build_net(variant)
    if isinstance(net, DceNet):
        _init_official(net)
    net.train()
    weights = LossWeights.for_variant(variant, colour_constancy=colour_constancy_weight)
    opt = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=weight_decay)
    rng = np.random.default_rng(seed)
    history: list[ZeroDceEpoch] = []
    for epoch in range(epochs):
        t0 = time.perf_counter()
        order = rng.permutation(len(data))
        terms_sum: dict[str, float] = {}
        total, n_seen = 0.0, 0
        for start in range(0, len(order), batch):
            x = data.batch(order[start : start + batch])
            enhanced, alphas = _forward(net, x, iterations)
            loss, terms = zerodce_loss(x, enhanced, alphas, weights)
            if not math.isfinite(loss.item()):
                raise FloatingPointError(f"Zero-DCE training diverged at epoch {epoch + 1} (loss {loss.item()})")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), grad_clip)
            opt.step()
            total += loss.item() * len(x)
            for k, v in terms.items():
                terms_sum[k] = terms_sum.get(k, 0.0) + v * len(x)
            n_seen += len(x)
        record = ZeroDceEpoch(
            epoch + 1, total / n_seen, {k: v / n_seen for k, v in terms_sum.items()}, time.perf_counter() - t0
        )
        history.append(record)
        if on_epoch is not None:
            on_epoch(record)
    net.eval()
    out_path = Path(out_path)
    card = {
        "name": name or out_path.stem,
        "architecture": "DCE-Net (Guo et al. 2020)" if variant == "zerodce" else "Zero-DCE++ (Li et al. 2021)",
        "params": count_parameters(net),
        "iterations": iterations,
        "training": {
            "frames": len(data),
            "epochs": epochs,
            "lr": lr,
            "weight_decay": weight_decay,
            "batch": batch,
            "size": size,
            "grad_clip": grad_clip,
            "seed": seed,
            "loss_weights": weights.as_dict(),
            "exposure_level": EXPOSURE_LEVEL,
            "exposure_patch": EXPOSURE_PATCH,
            "spatial_region": SPATIAL_REGION,
            "init": "conv weights N(0, 0.02)" if variant == "zerodce" else "pytorch default",
            "final_loss": history[-1].loss,
            "torch": torch.__version__,
        },
        **(card_extra or {}),
    }
    # a run killed while saving left the temporaries of the weights and card (NAME.json) beside them
    remove_stale_temporaries_of(out_path)
    remove_stale_temporaries_of(out_path.with_suffix(".json"))
    card = save_zerodce_weights(net, out_path, card)
    return ZeroDceTrainResult(weights=out_path, card=card, history=history)
