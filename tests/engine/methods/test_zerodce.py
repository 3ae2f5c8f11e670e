"""Zero-DCE / Zero-DCE++: architecture, curves, losses against the official code, weights files, methods,
training."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import save_file
from torch import nn

from colonlight.errors import CheckpointError
from colonlight.methods import create_method
from colonlight.methods import zerodce as zd
from colonlight.methods.zerodce import (
    DceNet,
    DcePlusPlusNet,
    LossWeights,
    ZeroDceMethod,
    ZeroDcePlusPlusMethod,
    apply_curves,
    colour_constancy_loss,
    count_parameters,
    exposure_loss,
    illumination_smoothness_loss,
    plusplus_alpha,
    save_zerodce_weights,
    spatial_consistency_loss,
    train_zerodce,
    zerodce_loss,
)


def _frame(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    light = 30 + 60 * np.exp(-(((yy - h / 2) / (h / 2 + 1)) ** 2 + ((xx - w / 2) / (w / 2 + 1)) ** 2))
    rgb = np.stack([light * 1.5, light * 0.8, light * 0.6], -1) + rng.normal(0, 5, (h, w, 3))
    return np.clip(rgb, 0, 255).astype(np.uint8)


def _random_weights(tmp_path: Path, variant: str, seed: int = 0) -> Path:
    torch.manual_seed(seed)
    net = DceNet() if variant == "zerodce" else DcePlusPlusNet()
    path = tmp_path / f"{variant}.safetensors"
    save_zerodce_weights(net, path, {"name": f"random-{variant}"})
    return path


# ---------- architecture ----------


def test_parameter_counts() -> None:
    dce, pp = DceNet(), DcePlusPlusNet()
    assert count_parameters(dce) == 79_416
    assert count_parameters(pp) == 10_561
    layers = [getattr(dce, f"e_conv{i}") for i in range(1, 8)]
    assert [count_parameters(m) for m in layers] == [896, 9248, 9248, 9248, 18464, 18464, 13848]
    layers = [getattr(pp, f"e_conv{i}") for i in range(1, 8)]
    assert [count_parameters(m) for m in layers] == [158, 1376, 1376, 1376, 2720, 2720, 835]
    x = torch.rand(1, 3, 13, 17)
    assert dce(x).shape == (1, 24, 13, 17) and pp(x).shape == (1, 3, 13, 17)


def test_curve_is_the_official_update() -> None:
    x = torch.rand(2, 3, 5, 7)
    a = torch.rand(2, 24, 5, 7) * 2 - 1
    want = x.clone()
    for t in range(8):  # model.py: x = x + r * (torch.pow(x, 2) - x)
        want = want + a[:, 3 * t : 3 * t + 3] * (torch.pow(want, 2) - want)
    torch.testing.assert_close(apply_curves(x, a, 8), want)
    out = apply_curves(x, torch.sign(a), 8)  # extreme maps stay in [0, 1] without clamping
    assert out.min() >= 0 and out.max() <= 1
    torch.testing.assert_close(apply_curves(x, torch.zeros_like(a), 8), x)
    one = torch.rand(2, 3, 5, 7) * 2 - 1
    want = x.clone()
    for _ in range(8):
        want = want + one * (want * want - want)
    torch.testing.assert_close(apply_curves(x, one, 8), want)  # Zero-DCE++: one map reused
    with pytest.raises(ValueError):
        apply_curves(x, a, 9)


def test_plusplus_resampling_matches_the_official_forward() -> None:
    torch.manual_seed(1)
    net = DcePlusPlusNet().eval()
    x = torch.rand(1, 3, 24, 36)  # multiples of s: no padding involved
    with torch.no_grad():
        small = F.interpolate(x, scale_factor=1 / 12, mode="bilinear")
        want = nn.UpsamplingBilinear2d(scale_factor=12)(net(small))
        torch.testing.assert_close(plusplus_alpha(net, x, 12), want)
        torch.testing.assert_close(plusplus_alpha(net, x, 1), net(x))
        for h, w in [(13, 17), (5, 7), (1, 1), (25, 40)]:  # reflect (or replicate) padding, then crop back
            assert plusplus_alpha(net, torch.rand(1, 3, h, w), 12).shape == (1, 3, h, w)


# ---------- losses against a transcription of the official Myloss.py ----------


def _official_spa(org: torch.Tensor, enhance: torch.Tensor) -> torch.Tensor:
    k = {
        "left": [[0, 0, 0], [-1, 1, 0], [0, 0, 0]],
        "right": [[0, 0, 0], [0, 1, -1], [0, 0, 0]],
        "up": [[0, -1, 0], [0, 1, 0], [0, 0, 0]],
        "down": [[0, 0, 0], [0, 1, 0], [0, -1, 0]],
    }
    org_pool = nn.AvgPool2d(4)(torch.mean(org, 1, keepdim=True))
    enh_pool = nn.AvgPool2d(4)(torch.mean(enhance, 1, keepdim=True))
    e = 0
    for kernel in k.values():
        weight = torch.FloatTensor(kernel)[None, None]
        e = e + torch.pow(F.conv2d(org_pool, weight, padding=1) - F.conv2d(enh_pool, weight, padding=1), 2)
    return torch.mean(e)


def _official_exp(x: torch.Tensor) -> torch.Tensor:
    mean = nn.AvgPool2d(16)(torch.mean(x, 1, keepdim=True))
    return torch.mean(torch.pow(mean - torch.FloatTensor([0.6]), 2))


def _official_col(x: torch.Tensor) -> torch.Tensor:
    mr, mg, mb = torch.split(torch.mean(x, [2, 3], keepdim=True), 1, dim=1)
    drg, drb, dgb = torch.pow(mr - mg, 2), torch.pow(mr - mb, 2), torch.pow(mb - mg, 2)
    return torch.mean(torch.pow(torch.pow(drg, 2) + torch.pow(drb, 2) + torch.pow(dgb, 2), 0.5))


def _official_tv(x: torch.Tensor) -> torch.Tensor:
    b, _, h, w = x.shape
    h_tv = torch.pow(x[:, :, 1:, :] - x[:, :, : h - 1, :], 2).sum()
    w_tv = torch.pow(x[:, :, :, 1:] - x[:, :, :, : w - 1], 2).sum()
    return 2 * (h_tv / ((h - 1) * w) + w_tv / (h * (w - 1))) / b


@pytest.mark.parametrize("shape", [(2, 3, 32, 48), (3, 3, 37, 50)])  # 37 x 50: pooling floors
def test_losses_match_the_official_code(shape: tuple[int, ...]) -> None:
    torch.manual_seed(0)
    org, enh = torch.rand(shape), torch.rand(shape)
    alphas = torch.rand(shape[0], 24, *shape[2:]) * 2 - 1
    torch.testing.assert_close(spatial_consistency_loss(enh, org), _official_spa(org, enh))
    torch.testing.assert_close(spatial_consistency_loss(org, enh), _official_spa(org, enh))  # symmetric
    torch.testing.assert_close(exposure_loss(enh), _official_exp(enh))
    torch.testing.assert_close(colour_constancy_loss(enh), _official_col(enh))
    torch.testing.assert_close(illumination_smoothness_loss(alphas), _official_tv(alphas))
    total, terms = zerodce_loss(org, enh, alphas)  # the training script's weights
    want = _official_spa(org, enh) + 10 * _official_exp(enh) + 5 * _official_col(enh) + 200 * _official_tv(alphas)
    torch.testing.assert_close(total, want)
    assert set(terms) == {"spatial", "exposure", "colour_constancy", "illumination_smoothness"}
    total, terms = zerodce_loss(org, enh, alphas, LossWeights.for_variant("zerodce", colour_constancy=0.0))
    torch.testing.assert_close(total, want - 5 * _official_col(enh))  # colonoscopy retraining: no L_col
    assert "colour_constancy" not in terms
    assert LossWeights.for_variant("zerodce++").illumination_smoothness == 1600


def test_loss_values_on_simple_inputs() -> None:
    gray = torch.full((1, 3, 32, 32), 0.6)
    assert float(exposure_loss(gray)) == pytest.approx(0.0, abs=1e-12)
    assert colour_constancy_loss(gray) == pytest.approx(0.0, abs=1e-5)
    assert illumination_smoothness_loss(torch.ones(2, 24, 8, 8)) == 0
    assert spatial_consistency_loss(gray, gray) == 0
    gray.requires_grad_(True)
    colour_constancy_loss(gray).backward()
    assert torch.isfinite(gray.grad).all()  # no NaN gradient at exactly gray


# ---------- weights files ----------


def test_missing_default_weights_raise_checkpoint_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(zd.DEFAULT_WEIGHTS, "zerodce", tmp_path / "nope.safetensors")
    monkeypatch.setitem(zd.DEFAULT_WEIGHTS, "zerodce++", tmp_path / "nope++.safetensors")
    with pytest.raises(CheckpointError, match="missing"):
        ZeroDceMethod()
    with pytest.raises(CheckpointError, match="missing"):
        create_method("zerodce++")


def test_bad_weights_files(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError):
        ZeroDceMethod(weights=tmp_path / "absent.safetensors")
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00" * 100)
    with pytest.raises(CheckpointError):
        ZeroDceMethod(weights=junk)
    pp = _random_weights(tmp_path, "zerodce++")
    with pytest.raises(CheckpointError):
        ZeroDceMethod(weights=pp)  # wrong variant
    bare = tmp_path / "bare.safetensors"  # no card, wrong keys
    save_file({"w": torch.zeros(3)}, str(bare))
    with pytest.raises(CheckpointError):
        ZeroDcePlusPlusMethod(weights=bare)
    card = json.loads(pp.with_suffix(".json").read_text())
    card["sha256"] = "0" * 64
    pp.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(CheckpointError, match="sha256"):
        ZeroDcePlusPlusMethod(weights=pp)


# ---------- methods ----------


@pytest.mark.parametrize("variant", ["zerodce", "zerodce++"])
def test_method_interface_and_edge_frames(tmp_path: Path, variant: str) -> None:
    path = _random_weights(tmp_path, variant)
    method = create_method(variant, weights=str(path))
    params = method.parameters()
    assert json.loads(json.dumps(params)) == params
    assert params["weights"] == str(path) and params["iterations"] == 8
    info = method.model_info()
    assert info == {"name": f"random-{variant}", "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    stream = method.stream()
    for h, w in [(1, 1), (5, 7), (13, 17), (40, 30)]:
        (res,) = stream.push(_frame(h, w))
        assert res.frame.shape == (h, w, 3) and res.frame.dtype == np.uint8 and res.gamma is None
    black = np.zeros((20, 26, 3), np.uint8)
    white = np.full((20, 26, 3), 255, np.uint8)
    np.testing.assert_array_equal(stream.push(black)[0].frame, black)  # 0 and 1 are fixed points of the curve
    np.testing.assert_array_equal(stream.push(white)[0].frame, white)
    assert stream.flush() == []
    with pytest.raises(ValueError):
        stream.push(np.zeros((4, 4, 3), np.float32))


def test_zerodce_full_resolution_is_the_network_on_the_frame(tmp_path: Path) -> None:
    path = _random_weights(tmp_path, "zerodce")
    frame = _frame(30, 40)
    full = ZeroDceMethod(weights=path, max_side=None)
    x = torch.from_numpy(frame).permute(2, 0, 1)[None].float() / 255
    with torch.no_grad():
        want = (apply_curves(x, full.net(x), 8)[0].permute(1, 2, 0) * 255).round().byte().numpy()
    np.testing.assert_array_equal(full.enhance(frame), want)
    np.testing.assert_array_equal(ZeroDceMethod(weights=path, max_side=40).enhance(frame), want)  # fits: same
    small = ZeroDceMethod(weights=path, max_side=16).enhance(frame)  # net on 16 x 12, maps upsampled
    assert small.shape == frame.shape
    assert np.abs(small.astype(int) - want).mean() < 10  # random smooth-ish maps: close, not equal
    with pytest.raises(ValueError):
        ZeroDceMethod(weights=path, iterations=9)


def test_zerodce_plusplus_scale_one_is_the_network_on_the_frame(tmp_path: Path) -> None:
    path = _random_weights(tmp_path, "zerodce++")
    frame = _frame(13, 17)
    method = ZeroDcePlusPlusMethod(weights=path, scale=1, iterations=4)
    assert method.parameters()["scale"] == 1
    x = torch.from_numpy(frame).permute(2, 0, 1)[None].float() / 255
    with torch.no_grad():
        want = (apply_curves(x, method.net(x), 4)[0].permute(1, 2, 0) * 255).round().byte().numpy()
    np.testing.assert_array_equal(method.enhance(frame), want)


# ---------- training ----------


def test_training_lowers_the_loss_and_writes_weights_and_card(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(16):  # dim reddish frames, floats in [0, 1]
        yy, xx = np.mgrid[0:48, 0:48] / 48
        light = 0.1 + 0.25 * np.exp(-((yy - rng.random()) ** 2 + (xx - rng.random()) ** 2) * 4)
        rgb = np.stack([light * 1.4, light * 0.8, light * 0.6], -1) + rng.normal(0, 0.02, (48, 48, 3))
        frames.append(np.clip(rgb, 0, 1).astype(np.float32))
    out = tmp_path / "zerodce-colon.safetensors"
    result = train_zerodce(iter(frames), variant="zerodce", epochs=4, batch=8, size=32, seed=0, out_path=out)
    losses = [e.loss for e in result.history]
    assert all(b < a for a, b in zip(losses, losses[1:], strict=False)), losses
    card = json.loads(out.with_suffix(".json").read_text())
    assert card == result.card
    assert card["variant"] == "zerodce" and card["params"] == 79_416
    assert card["sha256"] == hashlib.sha256(out.read_bytes()).hexdigest()
    assert card["training"]["loss_weights"]["colour_constancy"] == 0.0
    assert card["training"]["lr"] == 1e-4 and card["training"]["grad_clip"] == 0.1
    method = ZeroDceMethod(weights=out)
    assert method.model_info() == {"name": "zerodce-colon", "sha256": card["sha256"]}
    again = train_zerodce(
        frames, variant="zerodce", epochs=1, batch=8, size=32, seed=0, out_path=tmp_path / "b.safetensors"
    )
    assert again.history[0].loss == pytest.approx(losses[0], rel=1e-5)  # seeded: repeatable

    pp = train_zerodce(
        frames, variant="zerodce++", epochs=3, batch=8, size=32, seed=0, out_path=tmp_path / "pp.safetensors"
    )
    assert pp.history[-1].loss < pp.history[0].loss
    assert pp.card["params"] == 10_561 and pp.card["training"]["loss_weights"]["illumination_smoothness"] == 1600
    ZeroDcePlusPlusMethod(weights=tmp_path / "pp.safetensors")


@pytest.mark.parametrize("variant", ["zerodce", "zerodce++"])
def test_shipped_weights_load_and_brighten_a_dark_frame(variant: str) -> None:
    """The trained weights in the package load through their card (sha256 checked) and lift a dark frame."""
    if not zd.DEFAULT_WEIGHTS[variant].is_file():
        pytest.skip(f"{variant} weights are not installed in this checkout")
    method = create_method(variant)
    card = json.loads(zd.DEFAULT_WEIGHTS[variant].with_suffix(".json").read_text())
    assert method.model_info() == {"name": variant, "sha256": card["sha256"]}
    assert card["training"]["loss_weights"]["colour_constancy"] == 0.0  # the paper's retraining
    dark = np.full((48, 64, 3), 40, np.uint8)
    stream = method.stream()
    (out,) = stream.push(dark) + stream.flush()
    assert out.frame.mean() > 80
