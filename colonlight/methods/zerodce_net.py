"""Zero-DCE (Guo et al., CVPR 2020) and Zero-DCE++ (Li et al., TPAMI 2021): networks, curves, weights files.

Module and parameter names follow the official code (``e_conv1`` .. ``e_conv7``; ``depth_conv`` /
``point_conv`` in Zero-DCE++), so a converted official state dict loads unchanged. The curve step is the
official code's ``x + a * (x**2 - x)``, i.e. ``x - a * x * (1 - x)``: the paper writes ``+ a * x * (1 - x)``;
the sign of the learned ``a`` is flipped, nothing else (where paper and code differ we follow the code).

Weights are stored only as safetensors (never unpickled) with a JSON card beside them (``NAME.json``).
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from safetensors import SafetensorError
from safetensors.torch import load as load_safetensors_bytes
from torch import nn

from ..atomic import write_json_atomic
from ..checkpoint import read_card, save_tensors, sha256_file
from ..errors import CheckpointError, OptionError

VARIANTS = ("zerodce", "zerodce++")
WEIGHTS_FORMAT = "colonlight-zerodce"
N_FEATURES = 32


def _skip_forward(net: DceNet | DcePlusPlusNet, x: torch.Tensor) -> torch.Tensor:
    """The seven-layer DCE-Net topology shared by both variants: ReLU after layers 1-6, skips by concatenation
    (c5 <- [c3, c4], c6 <- [c2, c5], c7 <- [c1, c6]), tanh on the curve maps."""
    x1 = F.relu(net.e_conv1(x))
    x2 = F.relu(net.e_conv2(x1))
    x3 = F.relu(net.e_conv3(x2))
    x4 = F.relu(net.e_conv4(x3))
    x5 = F.relu(net.e_conv5(torch.cat([x3, x4], 1)))
    x6 = F.relu(net.e_conv6(torch.cat([x2, x5], 1)))
    return torch.tanh(net.e_conv7(torch.cat([x1, x6], 1)))


class DceNet(nn.Module):
    """DCE-Net: seven 3x3 convolutions with concatenation skips; 24 tanh maps = 8 RGB curve maps (79,416).

    Shapes: ``(B, 3, H, W)`` in [0, 1] -> ``(B, 24, H, W)`` in [-1, 1], at the input resolution.
    """

    n_maps = 8

    def __init__(self) -> None:
        super().__init__()
        f = N_FEATURES
        self.e_conv1 = nn.Conv2d(3, f, 3, 1, 1, bias=True)
        self.e_conv2 = nn.Conv2d(f, f, 3, 1, 1, bias=True)
        self.e_conv3 = nn.Conv2d(f, f, 3, 1, 1, bias=True)
        self.e_conv4 = nn.Conv2d(f, f, 3, 1, 1, bias=True)
        self.e_conv5 = nn.Conv2d(2 * f, f, 3, 1, 1, bias=True)
        self.e_conv6 = nn.Conv2d(2 * f, f, 3, 1, 1, bias=True)
        self.e_conv7 = nn.Conv2d(2 * f, 3 * self.n_maps, 3, 1, 1, bias=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _skip_forward(self, x)


class _DepthwiseSeparable(nn.Module):
    """Zero-DCE++'s ``CSDN_Tem``: depthwise 3x3 then pointwise 1x1, both with bias."""

    def __init__(self, in_ch: int, out_ch: int) -> None:
        super().__init__()
        self.depth_conv = nn.Conv2d(in_ch, in_ch, 3, 1, 1, groups=in_ch)
        self.point_conv = nn.Conv2d(in_ch, out_ch, 1, 1, 0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y: torch.Tensor = self.point_conv(self.depth_conv(x))
        return y


class DcePlusPlusNet(nn.Module):
    """Zero-DCE++'s network: DCE-Net with depthwise-separable layers and one 3-channel map (10,561 params).

    Shapes: ``(B, 3, h, w)`` -> ``(B, 3, h, w)`` in [-1, 1]. Resampling by the scale factor is done outside
    (:func:`plusplus_alpha`), so the network itself is resolution-agnostic, as when training at s = 1.
    """

    n_maps = 1

    def __init__(self) -> None:
        super().__init__()
        f = N_FEATURES
        self.e_conv1 = _DepthwiseSeparable(3, f)
        self.e_conv2 = _DepthwiseSeparable(f, f)
        self.e_conv3 = _DepthwiseSeparable(f, f)
        self.e_conv4 = _DepthwiseSeparable(f, f)
        self.e_conv5 = _DepthwiseSeparable(2 * f, f)
        self.e_conv6 = _DepthwiseSeparable(2 * f, f)
        self.e_conv7 = _DepthwiseSeparable(2 * f, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _skip_forward(self, x)


def build_net(variant: str) -> DceNet | DcePlusPlusNet:
    """A freshly initialised (PyTorch default) network of ``variant`` (``zerodce`` or ``zerodce++``)."""
    if variant == "zerodce":
        return DceNet()
    if variant == "zerodce++":
        return DcePlusPlusNet()
    raise OptionError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")


def count_parameters(net: nn.Module) -> int:
    """Number of scalar parameters."""
    return sum(p.numel() for p in net.parameters())


def curve_step(x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
    """One light-enhancement curve step, as in the official code: ``x + a * (x**2 - x)``.

    For x in [0, 1] and a in [-1, 1] the result stays in [0, 1], so no clamping is needed.
    """
    return x + a * (x * x - x)


def apply_curves(x: torch.Tensor, alphas: torch.Tensor, iterations: int) -> torch.Tensor:
    """Iterate the curve ``iterations`` times.

    Args:
        x: ``(B, 3, H, W)`` in [0, 1].
        alphas: ``(B, 3 * n, H, W)``. With n > 1 (Zero-DCE) step t uses maps ``3t .. 3t+2``, so ``iterations``
            must not exceed n; with n = 1 (Zero-DCE++) the one map is reused at every step.
        iterations: number of steps (8 in both official models).

    Returns:
        ``(B, 3, H, W)`` in [0, 1].
    """
    n = alphas.shape[1] // 3
    if n > 1 and iterations > n:
        raise OptionError(f"{n} curve maps allow at most {n} iterations, got {iterations}")
    inplace = not (torch.is_grad_enabled() and (x.requires_grad or alphas.requires_grad))
    if inplace:  # inference: one buffer, fused multiply-add (within 1e-5 of the out-of-place steps)
        x = x.clone()
    for t in range(iterations):
        a = alphas if n == 1 else alphas[:, 3 * t : 3 * t + 3]
        if inplace:
            x.addcmul_(a, (x * x).sub_(x))
        else:
            x = curve_step(x, a)
    return x


def plusplus_alpha(net: DcePlusPlusNet, x: torch.Tensor, scale: int) -> torch.Tensor:
    """Zero-DCE++'s full-resolution curve map: net on a 1/s bilinear copy, map upsampled xs (align corners).

    The official test crops H and W down to multiples of s; we reflect-pad up to multiples of s instead
    (replicate when the frame is too small to reflect) and crop the map back, so the whole frame is kept.

    Args:
        x: ``(B, 3, H, W)`` in [0, 1]; ``scale``: s >= 1.

    Returns:
        ``(B, 3, H, W)`` in [-1, 1].
    """
    if scale == 1:
        alpha: torch.Tensor = net(x)
        return alpha
    h, w = x.shape[-2:]
    ph, pw = -h % scale, -w % scale
    if ph or pw:
        mode = "reflect" if ph < h and pw < w else "replicate"
        x = F.pad(x, (0, pw, 0, ph), mode=mode)
    hp, wp = x.shape[-2:]
    small = F.interpolate(x, size=(hp // scale, wp // scale), mode="bilinear", align_corners=False)
    a = F.interpolate(net(small), size=(hp, wp), mode="bilinear", align_corners=True)
    return a[..., :h, :w]


def save_zerodce_weights(net: nn.Module, path: Path | str, card: dict[str, Any]) -> dict[str, Any]:
    """Write ``net`` as safetensors plus its JSON card (both atomically); return the card with its sha256.

    Args:
        net: a :class:`DceNet` or :class:`DcePlusPlusNet`.
        path: destination ``NAME.safetensors``; the card goes to ``NAME.json``.
        card: facts to record (name, training settings...); ``variant`` and ``params`` are filled in.
    """
    path = Path(path)
    variant = "zerodce" if isinstance(net, DceNet) else "zerodce++"
    state = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    save_tensors(state, path, f"{WEIGHTS_FORMAT}:{variant}")
    digest = sha256_file(path)
    card = {
        "name": card.get("name", path.stem),
        "variant": variant,
        "params": count_parameters(net),
        **{k: v for k, v in card.items() if k != "name"},
        "file": path.name,
        "sha256": digest,
    }
    write_json_atomic(path.with_suffix(".json"), card)
    return card


def load_zerodce_weights(path: Path | str, variant: str) -> tuple[nn.Module, str, str]:
    """Load a safetensors file into a network of ``variant``; return ``(net in eval mode, name, sha256)``.

    The sha256 is of the exact bytes loaded. A card beside the file, if present, must carry the same sha256.
    The name is the card's, else the file stem. Raises :class:`CheckpointError` for a missing, unreadable,
    corrupt or mismatched file (wrong variant, keys or shapes, non-finite values).
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such {variant} weights file")
    try:
        data = path.read_bytes()
        state = load_safetensors_bytes(data)
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise CheckpointError(f"{path}: unreadable or corrupt safetensors file ({exc})") from exc
    digest = hashlib.sha256(data).hexdigest()
    card = read_card(path, digest)
    if card.get("variant") and card["variant"] != variant:
        raise CheckpointError(f"{path}: holds {card['variant']} weights, not {variant}")
    net = build_net(variant)
    expected = net.state_dict()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        raise CheckpointError(f"{path}: not {variant} weights (missing {missing[:3]}, unexpected {unexpected[:3]})")
    for key, tensor in state.items():
        if tensor.shape != expected[key].shape:
            raise CheckpointError(
                f"{path}: {key} has shape {tuple(tensor.shape)}, expected {tuple(expected[key].shape)}"
            )
        if not torch.isfinite(tensor).all():
            raise CheckpointError(f"{path}: {key} holds non-finite values")
    net.load_state_dict({k: v.float() for k, v in state.items()})
    net.eval()
    return net, str(card.get("name") or path.stem), digest
