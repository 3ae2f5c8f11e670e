"""The recurrent gamma network: layout, fidelity to the authors' code, state, seeds, guards."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from colonlight.checkpoint import load_weights
from colonlight.correction import correct
from colonlight.methods.rnn import DEFAULT_MODEL_SIZE, GAMMA_MAX, GAMMA_MIN, RecurrentGammaMethod, clamp_gamma
from colonlight.model import GammaNet, parameter_count


def _read_rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def test_parameter_count_and_keys_match_release() -> None:
    net = GammaNet()
    assert parameter_count(net) == 84_097
    prefixes = {k.split(".")[0] for k in net.state_dict()}
    assert prefixes == {"in_cnv", "bn", "RNNcell", "rnn_cnv", "out_linear"}
    assert net.bn.momentum == 0.01


@pytest.mark.parametrize("shape", [(1, 3, 16, 16), (2, 3, 31, 47), (3, 3, 64, 48)])
def test_step_shapes(shape: tuple[int, ...]) -> None:
    net = GammaNet().eval()
    a, (h, c) = net.step(torch.rand(shape))
    assert a.shape == (shape[0],)
    assert h.shape == c.shape == (shape[0], 32, shape[2], shape[3])
    assert (a >= 0).all()


def test_sequence_forward_equals_stepping() -> None:
    torch.manual_seed(1)
    net = GammaNet().eval()
    x = torch.rand(2, 5, 3, 24, 24)
    with torch.no_grad():
        batched = net(x)
        state = None
        for t in range(5):
            a, state = net.step(x[:, t], state)
            assert torch.allclose(a, batched[:, t], atol=1e-6)


def test_state_is_carried_across_frames(authors_checkpoint: Path) -> None:
    """The same frame gives a different a after a history than from a fresh state."""
    w = load_weights(authors_checkpoint)
    frame = torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        a_fresh, _ = w.net.step(frame, None)
        _, state = w.net.step(torch.zeros(1, 3, 32, 32), None)
        a_after, _ = w.net.step(frame, state)
    assert abs(float(a_fresh) - float(a_after)) > 1e-4


@pytest.mark.parametrize("folder", ["frames_256", "frames_native"])
def test_fidelity_to_authors_code(reference_dir: Path, authors_checkpoint: Path, folder: str) -> None:
    """Every a of the authors' code on their checkpoint and frames, reproduced within 1e-4 (full resolution)."""
    expected = json.loads((reference_dir / "expected.json").read_text())["a"][folder]
    frames = sorted((reference_dir / folder).glob("*.png"))
    assert len(frames) == len(expected) == 24
    method = RecurrentGammaMethod(weights=authors_checkpoint, model_size="full", device="cpu")
    stream = method.stream()
    got = [stream.predict_a(_read_rgb(p)) for p in frames]
    assert np.max(np.abs(np.array(got) - np.array(expected))) < 1e-4


def test_fidelity_through_stream_gammas(reference_dir: Path, authors_checkpoint: Path) -> None:
    """The streamed results: seeds unchanged with gamma 1.0, then gamma = 1/a applied with the exact table."""
    expected = json.loads((reference_dir / "expected.json").read_text())["a"]["frames_256"]
    frames = [_read_rgb(p) for p in sorted((reference_dir / "frames_256").glob("*.png"))]
    stream = RecurrentGammaMethod(weights=authors_checkpoint, model_size=256, device="cpu").stream()
    for i, frame in enumerate(frames):
        (res,) = stream.push(frame)
        if i < 2:
            assert res.gamma == 1.0 and res.info["seed"] is True
            assert np.array_equal(res.frame, frame)
        else:
            assert res.gamma == pytest.approx(1.0 / expected[i], abs=1e-4)
            ref = np.rint(255.0 * (frame / 255.0) ** res.gamma).astype(np.uint8)
            assert np.array_equal(res.frame, ref)


def test_a_new_stream_starts_from_zero_state(random_weights: Path) -> None:
    method = RecurrentGammaMethod(weights=random_weights, device="cpu")
    frames = [np.random.default_rng(i).integers(0, 255, (40, 50, 3), dtype=np.uint8) for i in range(4)]
    first = [r.gamma for f in frames for r in method.stream().push(f)]  # fresh stream each frame: seeds only
    assert first == [1.0] * 4
    s1, s2 = method.stream(), method.stream()
    g1 = [s1.push(f)[0].gamma for f in frames]
    g2 = [s2.push(f)[0].gamma for f in frames]
    assert g1 == g2 and g1[2] != 1.0


@pytest.mark.parametrize(
    ("a", "gamma", "clamped"),
    [
        (2.0, 0.5, False),
        (1.0, 1.0, False),
        (0.0, 1.0, True),
        (-1.0, 1.0, True),
        (float("nan"), 1.0, True),
        (float("inf"), 1.0, True),
        (1e-9, GAMMA_MAX, True),
        (1e9, GAMMA_MIN, True),
    ],
)
def test_gamma_guard(a: float, gamma: float, clamped: bool) -> None:
    assert clamp_gamma(a) == (pytest.approx(gamma), clamped)


def test_guard_never_yields_nan_or_black(random_weights: Path) -> None:
    """A network answering a = 0 (dead ReLU) leaves frames unchanged and flags them."""
    method = RecurrentGammaMethod(weights=random_weights, device="cpu")
    with torch.no_grad():
        method.weights.net.out_linear.bias.fill_(-100.0)  # forces a = 0
    frame = np.full((20, 30, 3), 120, np.uint8)
    stream = method.stream()
    results = [stream.push(frame)[0] for _ in range(4)]
    for r in results[2:]:
        assert r.info["clamped"] is True and r.info["a"] == 0.0 and r.gamma == 1.0
        assert np.array_equal(r.frame, frame)


def test_correct_matches_power_and_is_differentiable() -> None:
    x = torch.rand(2, 3, 3, 8, 8, requires_grad=True)
    a = torch.tensor([[1.0, 2.0, 0.5], [1.5, 1.0, 3.0]], requires_grad=True)
    y = correct(x, a)
    assert torch.allclose(y[0, 1], x[0, 1].clamp_min(1e-6) ** 0.5)
    y.mean().backward()
    assert torch.isfinite(a.grad).all() and torch.isfinite(x.grad).all()


def test_identity_when_a_is_one() -> None:
    x = torch.rand(1, 2, 3, 4, 4) * 0.9 + 0.05
    assert torch.allclose(correct(x, torch.ones(1, 2)), x)


def test_rejects_bad_frames(random_weights: Path) -> None:
    stream = RecurrentGammaMethod(weights=random_weights, device="cpu").stream()
    for bad in (np.zeros((10, 10), np.uint8), np.zeros((10, 10, 3), np.float32), np.zeros((10, 10, 4), np.uint8)):
        with pytest.raises(ValueError, match="uint8 RGB"):
            stream.push(bad)


def test_default_model_size_is_the_size_the_weights_were_trained_at(random_weights: Path, tmp_path: Path) -> None:
    assert RecurrentGammaMethod(weights=random_weights, device="cpu").model_size == 64  # its card says 64
    shipped = RecurrentGammaMethod(device="cpu")
    # the shipped card says 32 (trained at 48, run at 32 since session 22); no card: DEFAULT_MODEL_SIZE (48)
    assert shipped.model_size == shipped.weights.input_size == 32 and DEFAULT_MODEL_SIZE == 48
    torch.save(GammaNet().state_dict(), tmp_path / "release-style.pth")  # the authors' format: no card
    assert RecurrentGammaMethod(weights=tmp_path / "release-style.pth", device="cpu").model_size == DEFAULT_MODEL_SIZE
    assert RecurrentGammaMethod(weights=random_weights, model_size=" Auto ", device="cpu").model_size == 64
    assert RecurrentGammaMethod(weights=random_weights, model_size=48, device="cpu").model_size == 48  # asked for


def test_model_size_options(random_weights: Path) -> None:
    assert RecurrentGammaMethod(weights=random_weights, model_size="full", device="cpu").model_size is None
    assert RecurrentGammaMethod(weights=random_weights, model_size="96", device="cpu").model_size == 96
    for bad in ("big", 0, -5):
        with pytest.raises(ValueError):
            RecurrentGammaMethod(weights=random_weights, model_size=bad, device="cpu")
    assert math.isfinite(RecurrentGammaMethod(weights=random_weights, device="cpu").parameters()["gamma_range"][1])
