"""The gain-gamma head: its correction (torch and LUT agree), loading by shape, the method, the supervised objective."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from colonlight.checkpoint import load_weights, save_weights
from colonlight.correction import apply_gain_gamma, gain_gamma_from_raw, gain_gamma_values
from colonlight.curves import gain_gamma_lut, gamma_lut
from colonlight.errors import CheckpointError
from colonlight.methods.rnn import GAIN_MAX, GAIN_MIN, RecurrentGammaMethod, clamp_gain_gamma
from colonlight.model import GammaNet
from colonlight.train import TrainConfig, restore_loss, train_model


def test_lut_is_the_formula_and_gain_one_is_the_gamma_lut() -> None:
    v = np.arange(256) / 255.0
    for gain, gamma in ((1.7, 0.6), (0.5, 1.4), (2.5, 2.0)):
        want = np.rint(255 * np.minimum(1.0, gain * v**gamma)).astype(np.uint8)
        assert np.array_equal(gain_gamma_lut(gain, gamma), want)
    for gamma in (0.3, 1.0, 2.2):
        assert np.array_equal(gain_gamma_lut(1.0, gamma), gamma_lut(gamma))
    with pytest.raises(ValueError):
        gain_gamma_lut(0.0, 1.0)


def test_raw_zero_is_the_identity_and_torch_matches_the_float_mapping() -> None:
    gain, gamma = gain_gamma_from_raw(torch.zeros(3, 2))
    assert torch.allclose(gain, torch.ones(3)) and torch.allclose(gamma, torch.ones(3))
    z = torch.tensor([[0.3, -0.8], [-1.5, 0.9]], dtype=torch.float64)
    g_t, k_t = gain_gamma_from_raw(z)
    for row, g, k in zip(z.tolist(), g_t.tolist(), k_t.tolist(), strict=True):
        assert gain_gamma_values(*row) == pytest.approx((g, k), rel=1e-12)
    x = torch.rand(1, 2, 3, 8, 8)
    out = apply_gain_gamma(x, g_t[None].float(), k_t[None].float())
    assert out.max() <= 1.0 and torch.allclose(out[0, 0], (g_t[0] * x[0, 0] ** k_t[0]).clamp_max(1).float(), atol=1e-6)


def test_clamp_keeps_ranges_and_leaves_non_finite_frames_alone() -> None:
    assert clamp_gain_gamma(float("nan"), 0.0) == (1.0, 1.0, True)
    gain, gamma, clamped = clamp_gain_gamma(0.0, 0.0)
    assert (gain, gamma, clamped) == (1.0, 1.0, False)
    gain, _, clamped = clamp_gain_gamma(0.0, 50.0)  # tanh saturates: gain e^1.2 = 3.32 is inside the range
    assert GAIN_MIN <= gain <= GAIN_MAX and not clamped


def _gain_gamma_weights(tmp_path: Path, bias: tuple[float, float]) -> Path:
    torch.manual_seed(0)
    net = GammaNet(head="gain-gamma")
    with torch.no_grad():
        net.out_linear.weight.zero_()
        net.out_linear.bias.copy_(torch.tensor(bias))
    path = tmp_path / "gg.safetensors"
    save_weights(net.eval(), path, {"name": "gg-test", "input_size": 32, "head": "gain-gamma", "seed_frames": 0})
    return path


def test_head_is_read_from_the_weights_and_checked_against_the_card(tmp_path: Path) -> None:
    path = _gain_gamma_weights(tmp_path, (0.0, 0.0))
    w = load_weights(path)
    assert w.head == "gain-gamma" and w.seed_frames == 0 and w.net.out_linear.out_features == 2
    card = json.loads(path.with_suffix(".json").read_text())
    card["head"] = "gamma"
    path.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(CheckpointError, match="head"):
        load_weights(path)


def test_method_applies_the_predicted_gain_and_gamma_from_the_first_frame(tmp_path: Path) -> None:
    z0, z1 = 0.2, -0.3  # constant outputs: a known gain and gamma on every frame
    method = RecurrentGammaMethod(_gain_gamma_weights(tmp_path, (z0, z1)), device="cpu")
    assert method.seeds == 0 and method.parameters()["head"] == "gain-gamma"
    gain, gamma = gain_gamma_values(z0, z1)
    frame = np.random.default_rng(1).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    stream = method.stream()
    for _ in range(3):
        (res,) = stream.push(frame)
        assert res.gamma == pytest.approx(gamma) and res.info["gain"] == pytest.approx(gain)
        assert np.array_equal(res.frame, cv2.LUT(frame, gain_gamma_lut(gain, gamma)))


def test_restore_loss_is_zero_for_the_inverse_correction_and_ignores_clipped_samples() -> None:
    torch.manual_seed(0)
    clean = torch.rand(1, 3, 3, 16, 16) * 0.8 + 0.05
    g, k = 0.7, 1.3
    frames = g * clean**k  # a recorder's gain and contrast change
    # inverse: clean = g**(-1/k) * frames ** (1/k)
    gain, gamma = g ** (-1 / k), 1 / k
    z = torch.tensor([np.arctanh(np.log(gamma) / 2.0), np.arctanh(np.log(gain) / 1.2)], dtype=torch.float32)
    out = z.expand(1, 3, 2)
    assert float(restore_loss(frames, clean, out, "gain-gamma")) < 1e-5
    assert float(restore_loss(frames, clean, torch.zeros(1, 3, 2), "gain-gamma")) > 0.01
    saturated = frames.clone()
    saturated[..., :8] = 1.0  # clipped by the recorder: no information, so no loss there
    bad = clean.clone()
    bad[..., :8] = 0.0
    assert float(restore_loss(saturated, bad, out, "gain-gamma")) < 1e-5


def _pair_clip(root: Path, seed: int, n: int = 14, size: int = 32) -> Path:
    """A synthetic-style clip folder: frames/ (gain jumps) beside clean/."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.uniform(0.1, 0.7, (size, size, 3)), (0, 0), 1.5)
    for sub in ("frames", "clean"):
        (root / sub).mkdir(parents=True)
    for i in range(n):
        gain = 1.0 if i % 3 == 0 else rng.uniform(0.5, 1.6)
        for sub, img in (("clean", base), ("frames", np.clip(gain * base, 0, 1))):
            cv2.imwrite(str(root / sub / f"{i:04d}.png"), (img[..., ::-1] * 255).round().astype(np.uint8))
    return root / "frames"


def test_supervised_training_records_its_head_objective_and_seeds(tmp_path: Path) -> None:
    clips = [_pair_clip(tmp_path / f"c{i}", i) for i in range(3)]
    cfg = TrainConfig(
        size=32, seq_len=6, stride=4, batch=2, lr=3e-3, epochs=3, fps=None, head="gain-gamma", objective="restore"
    )
    res = train_model(clips[:2], clips[2:], tmp_path / "run", cfg, name="gg")
    card = res.card
    assert card["head"] == "gain-gamma" and card["seed_frames"] == 0
    assert "clean" in card["training"]["objective"]
    assert res.history[-1].train_loss < res.history[0].train_loss
    assert load_weights(res.weights).head == "gain-gamma"


def test_supervised_objective_without_clean_frames_is_a_clear_error(tmp_path: Path) -> None:
    from colonlight.errors import InputError

    folder = _pair_clip(tmp_path / "c", 0)
    import shutil

    shutil.rmtree(folder.parent / "clean")
    cfg = TrainConfig(size=32, seq_len=6, stride=4, epochs=1, fps=None, head="gain-gamma", objective="restore")
    with pytest.raises(InputError, match="clean"):
        train_model([folder], [], tmp_path / "run", cfg)
    with pytest.raises(ValueError, match="objective"):
        TrainConfig(objective="nonsense")
