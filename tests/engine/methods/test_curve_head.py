"""The ``curve`` head: a monotone tone curve per frame, the same in training (torch), inference (a LUT) and
export (its ONNX test is in test_onnx_export.py, one test for the heads with raw outputs)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from colonlight.checkpoint import load_weights, save_weights
from colonlight.correction import (
    CURVE_KNOTS,
    CURVE_SEGMENTS,
    SLOPE_OFFSET,
    apply_curve,
    curve_slopes_from_raw,
    curve_values,
)
from colonlight.curves import curve_lut
from colonlight.errors import OptionError
from colonlight.methods.rnn import CURVE_SUMMARY_AT, RecurrentGammaMethod, curve_correction
from colonlight.model import GammaNet
from colonlight.train import TrainConfig, restore_loss, train_model

LEVELS = np.arange(256, dtype=np.float64) / 255.0


def test_zero_outputs_are_the_identity_in_torch_and_as_a_table() -> None:
    frames = torch.rand(2, 3, 3, 8, 8)
    assert torch.equal(apply_curve(frames, curve_slopes_from_raw(torch.zeros(2, 3, CURVE_SEGMENTS))), frames)
    lut, values, gamma, clamped = curve_correction([0.0] * CURVE_SEGMENTS)
    assert lut is not None and np.array_equal(lut, np.arange(256, dtype=np.uint8))
    assert values == pytest.approx(list(CURVE_KNOTS)) and gamma == pytest.approx(1.0) and not clamped


def test_torch_curve_and_table_agree_and_the_table_is_monotone() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        z = rng.normal(0.0, 1.5, CURVE_SEGMENTS)
        lut, _values, _gamma, _clamped = curve_correction(list(z))
        assert lut is not None and np.all(np.diff(lut.astype(int)) >= 0)
        levels = torch.tensor(LEVELS, dtype=torch.float64)
        slopes = curve_slopes_from_raw(torch.tensor(z, dtype=torch.float64))
        in_torch = apply_curve(levels, slopes).numpy()
        assert np.max(np.abs(np.rint(255 * in_torch) - lut)) <= 1  # float rounding at a .5 only


def test_the_slopes_are_softplus_of_the_outputs_from_the_identity() -> None:
    z = np.linspace(-3, 3, CURVE_SEGMENTS)
    values, clamped = curve_values(list(z))
    slopes = np.diff(values) / np.diff(CURVE_KNOTS)
    assert slopes == pytest.approx(np.log1p(np.exp(z + SLOPE_OFFSET))) and not clamped
    _values, clamped = curve_values([80.0] * CURVE_SEGMENTS)
    assert clamped  # beyond the steepest allowed slope
    with pytest.raises(ValueError):
        curve_values([math.nan] * CURVE_SEGMENTS)


def test_non_finite_outputs_leave_the_frame_alone_flagged() -> None:
    lut, values, gamma, clamped = curve_correction([math.inf] + [0.0] * (CURVE_SEGMENTS - 1))
    assert lut is None and values == [] and gamma == 1.0 and clamped


def test_a_summary_gamma_at_its_bound_is_not_a_clamped_correction() -> None:
    """What the README says of very dark clips: the summary gamma is reported within [0.125, 4] without a flag,
    because the curve, not the summary, is applied; ``clamped`` is for a slope at its cap."""
    z = [3.0] * 4 + [-6.0] * (CURVE_SEGMENTS - 4)  # steep in the darks (slopes near 3.6, far below the cap)
    lut, values, gamma, clamped = curve_correction(z)
    at_middle = float(np.interp(CURVE_SUMMARY_AT, CURVE_KNOTS, values))
    assert math.log(at_middle) / math.log(CURVE_SUMMARY_AT) < 0.125  # the power law through it is below the range
    assert gamma == 0.125 and not clamped and lut is not None
    assert lut[int(CURVE_SUMMARY_AT * 255)] > 255 * CURVE_SUMMARY_AT**0.125 - 2  # and the curve is applied as it is


def test_curve_lut_refuses_a_curve_that_is_not_one() -> None:
    with pytest.raises(OptionError):
        curve_lut([0.0, 0.5, 1.0], [0.0, 0.6, 0.5])  # decreasing
    with pytest.raises(OptionError):
        curve_lut([0.0, 1.0], [0.0, 0.5, 1.0])  # lengths differ


def _fit_z(target: np.ndarray) -> torch.Tensor:
    """Raw outputs whose curve is closest to ``target(levels)`` (least squares, by gradient descent)."""
    z = torch.zeros(CURVE_SEGMENTS, dtype=torch.float64, requires_grad=True)
    levels = torch.tensor(LEVELS, dtype=torch.float64)
    want = torch.tensor(target, dtype=torch.float64)
    opt = torch.optim.Adam([z], lr=0.05)
    for _ in range(600):
        opt.zero_grad()
        loss = ((apply_curve(levels, curve_slopes_from_raw(z)) - want) ** 2).mean()
        loss.backward()
        opt.step()
    return z.detach()


def test_the_curve_undoes_a_gain_and_a_shoulder_that_one_gamma_cannot() -> None:
    """A recorder's response with a highlight shoulder after a gain: the curve inverts it to within a few levels;
    the best single gamma is several times worse."""
    clean = LEVELS[:200]  # values the recorder did not clip
    recorded = 1.0 - (1.0 - np.clip(1.6 * clean, 0, 1)) ** 1.8  # gain, then a shoulder
    keep = recorded < 0.98
    inverse = np.interp(LEVELS, recorded[keep], clean[keep])
    z = _fit_z(inverse)
    lut, _values, _gamma, _clamped = curve_correction(z.tolist())
    assert lut is not None
    idx = np.rint(255 * recorded[keep]).astype(int)
    curve_err = np.abs(lut[idx] / 255.0 - clean[keep]).mean()
    gammas = np.linspace(0.2, 5.0, 400)
    gamma_err = min(np.abs(recorded[keep] ** g - clean[keep]).mean() for g in gammas)
    assert curve_err < 0.012 and gamma_err > 3 * curve_err


def _curve_weights(tmp_path: Path, bias: np.ndarray) -> Path:
    torch.manual_seed(0)
    net = GammaNet(head="curve")
    with torch.no_grad():
        net.out_linear.weight.zero_()
        net.out_linear.bias.copy_(torch.tensor(bias, dtype=torch.float32))
    path = tmp_path / "curve.safetensors"
    save_weights(net.eval(), path, {"name": "curve-test", "input_size": 32, "head": "curve", "seed_frames": 0})
    return path


def test_method_applies_the_predicted_curve_and_records_it(tmp_path: Path) -> None:
    bias = np.linspace(1.0, -0.5, CURVE_SEGMENTS)  # brightens the darks, a constant curve on every frame
    method = RecurrentGammaMethod(_curve_weights(tmp_path, bias), device="cpu")
    params = method.parameters()
    assert method.seeds == 0 and params["head"] == "curve" and params["curve_knots"] == list(CURVE_KNOTS)
    assert load_weights(tmp_path / "curve.safetensors").head == "curve"
    values, _ = curve_values(list(bias.astype(np.float32).astype(np.float64)))
    want = curve_lut(CURVE_KNOTS, values)
    frame = np.random.default_rng(1).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    stream = method.stream()
    for _ in range(3):
        (res,) = stream.push(frame)
        assert np.array_equal(res.frame, cv2.LUT(frame, want))
        assert res.info["curve"] == pytest.approx(list(values), abs=1e-6)
        at = float(np.interp(CURVE_SUMMARY_AT, CURVE_KNOTS, values))
        assert res.gamma == pytest.approx(math.log(at) / math.log(CURVE_SUMMARY_AT), abs=1e-5) and res.gamma < 1


def test_restore_loss_is_near_zero_for_the_inverse_curve() -> None:
    torch.manual_seed(0)
    clean = torch.rand(1, 3, 3, 16, 16) * 0.5 + 0.05
    frames = clean**0.5 * 0.9  # a contrast and gain change
    z = _fit_z(np.clip((LEVELS / 0.9) ** 2, 0, 1))
    out = z.float().expand(1, 3, CURVE_SEGMENTS)
    assert float(restore_loss(frames, clean, out, "curve")) < 0.004
    assert float(restore_loss(frames, clean, torch.zeros(1, 3, CURVE_SEGMENTS), "curve")) > 0.05


def _pair_clip(root: Path, seed: int, n: int = 12, size: int = 32) -> Path:
    """A synthetic-style clip folder: frames/ (tone-curve and gain changes) beside clean/."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.uniform(0.1, 0.7, (size, size, 3)), (0, 0), 1.5)
    for sub in ("frames", "clean"):
        (root / sub).mkdir(parents=True)
    for i in range(n):
        gain, k = (1.0, 1.0) if i % 3 == 0 else (rng.uniform(0.6, 1.4), rng.uniform(0.6, 1.6))
        for sub, img in (("clean", base), ("frames", np.clip(gain * base**k, 0, 1))):
            cv2.imwrite(str(root / sub / f"{i:04d}.png"), (img[..., ::-1] * 255).round().astype(np.uint8))
    return root / "frames"


def test_training_with_the_curve_head_and_the_temporal_term_learns_and_is_recorded(tmp_path: Path) -> None:
    clips = [_pair_clip(tmp_path / f"c{i}", i) for i in range(3)]
    cfg = TrainConfig(
        size=32,
        seq_len=6,
        stride=4,
        batch=2,
        lr=3e-3,
        epochs=3,
        fps=None,
        head="curve",
        objective="restore",
        temporal=1.0,
    )
    res = train_model(clips[:2], clips[2:], tmp_path / "run", cfg, name="curve")
    assert res.card["head"] == "curve" and "monotone tone curve" in res.card["architecture"]
    assert res.history[-1].train_loss < res.history[0].train_loss
    assert load_weights(res.weights).net.out_linear.out_features == CURVE_SEGMENTS


def test_a_curve_head_started_from_a_gain_gamma_checkpoint_starts_with_its_corrections(tmp_path: Path) -> None:
    """``--head curve --init <gain-gamma checkpoint>``: the output layer is the checkpoint's, mapped to curves, so
    on a real clip the new network's corrected frames are within about a grey level of the checkpoint's from the
    first step on (a zero output layer would start at the identity, as far off as the checkpoint's corrections are
    large). The gain-gamma checkpoint makes corrections of a trained model's size: the shipped default's backbone,
    with its curve output layer projected onto the gain-gamma head (the map's pseudo-inverse)."""
    from colonlight.checkpoint import DEFAULT_WEIGHTS
    from colonlight.correction import apply_head, gain_gamma_to_curve_map
    from colonlight.synth import SynthConfig, generate_clip
    from colonlight.train import initial_net

    mapping = gain_gamma_to_curve_map()
    assert mapping.shape == (CURVE_SEGMENTS, 2) and np.all(np.isfinite(mapping))
    default = load_weights(DEFAULT_WEIGHTS).net
    assert default.head == "curve"
    gain_gamma = initial_net(TrainConfig(head="gain-gamma", inputs=default.inputs, init=str(DEFAULT_WEIGHTS)))
    back = torch.from_numpy(np.linalg.pinv(mapping)).to(default.out_linear.weight.dtype)
    with torch.no_grad():
        gain_gamma.out_linear.weight.copy_(back @ default.out_linear.weight)
        gain_gamma.out_linear.bias.copy_(back @ default.out_linear.bias)
    start = tmp_path / "gain-gamma.safetensors"
    save_weights(gain_gamma, start, {"name": "gain-gamma", "head": "gain-gamma", "inputs": default.inputs})
    shipped = load_weights(start).net
    assert shipped.head == "gain-gamma"
    curve = initial_net(TrainConfig(head="curve", inputs=shipped.inputs, init=str(start))).eval()
    assert curve.head == "curve" and curve.inputs == shipped.inputs
    cfg = SynthConfig.sample(np.random.default_rng(31), split="heldout", width=48, height=48, n_frames=24)
    frames = torch.stack([torch.from_numpy(f.image).permute(2, 0, 1).float() / 255 for f in generate_clip(cfg, 31)])
    with torch.inference_mode():
        ours = apply_head(frames, curve(frames[None])[0], "curve")
        theirs = apply_head(frames, shipped(frames[None])[0], "gain-gamma")
    off = float((ours - theirs).abs().mean() * 255)
    moved = float((theirs - frames).abs().mean() * 255)
    assert off < 1.5 and moved > 4 * off, (off, moved)


@pytest.mark.parametrize("head", ["gamma", "curve"])
def test_an_overflowing_output_is_recorded_as_null_not_nan(tmp_path: Path, head: str) -> None:
    """Finite weights can still overflow to infinity on a frame: the frame is left unchanged, flagged, and its
    record stays JSON (which has no NaN or infinity; a strict reader refuses them)."""
    torch.manual_seed(0)
    net = GammaNet(head=head)
    with torch.no_grad():
        net.out_linear.weight.fill_(3e38)  # finite, but times any positive feature it overflows
        net.out_linear.bias.fill_(3e38)
    path = tmp_path / "overflow.safetensors"
    save_weights(net.eval(), path, {"name": "overflow", "input_size": 32, "head": head, "seed_frames": 0})
    frame = np.random.default_rng(2).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    (res,) = RecurrentGammaMethod(path, device="cpu").stream().push(frame)
    raw = res.info["a"] if head == "gamma" else res.info["z"]
    assert None in (raw if isinstance(raw, list) else [raw]), res.info
    assert res.info["clamped"] and res.gamma == 1.0 and np.array_equal(res.frame, frame)
    json.dumps(res.info, allow_nan=False)
