"""``network_input``: the copy of a frame the network sees is an area average of the whole frame, within about a
level, at any size (a large frame is presampled bilinearly first, for speed, not for a different picture)."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from colonlight.methods.rnn import PRESAMPLE, network_input

SIZE = 48


def _textured(height: int, width: int, noise: float, seed: int = 0) -> np.ndarray:
    """Smooth colour patches plus per-pixel sensor-like noise: what averaging must remove."""
    rng = np.random.default_rng(seed)
    base = rng.random((34, 42, 3)) * 200 + 20
    smooth = cv2.resize(base, (width, height), interpolation=cv2.INTER_CUBIC)
    return np.clip(smooth + rng.normal(0, noise, (height, width, 3)), 0, 255).astype(np.uint8)


def _area(frame: np.ndarray) -> np.ndarray:
    return cv2.resize(frame, (SIZE, SIZE), interpolation=cv2.INTER_AREA)


def test_a_full_hd_frame_reads_as_its_area_average() -> None:
    frame = _textured(1080, 1350, noise=20)
    assert min(frame.shape[:2]) > PRESAMPLE * SIZE  # the presampled branch
    small = network_input(frame, SIZE)
    assert small.shape == (SIZE, SIZE, 3) and small.dtype == np.uint8
    # every pixel's noise averaged away as one area average does: nearest-neighbour sampling is ~35 levels off
    # here, a stride-8 subsample ~8, the Gaussian pyramid used before ~7
    assert np.abs(small.astype(float) - _area(frame)).mean() < 2.0


def test_a_smaller_frame_is_area_averaged_at_once() -> None:
    frame = _textured(PRESAMPLE * SIZE, PRESAMPLE * SIZE + 100, noise=10)
    assert np.array_equal(network_input(frame, SIZE), _area(frame))


def test_a_frame_at_the_size_or_full_resolution_is_used_as_it_is() -> None:
    frame = _textured(SIZE, SIZE, noise=5)
    assert network_input(frame, SIZE) is frame
    big = _textured(100, 120, noise=5)
    assert network_input(big, None) is big


def test_the_method_leaves_the_callers_weights_as_they_were() -> None:
    """The method lays its convolution weights out channels-last for speed; a caller's own LoadedWeights (shared,
    say, by an export or a second method) keeps its layout and is not the method's net."""
    from colonlight.checkpoint import load_weights
    from colonlight.methods.rnn import RecurrentGammaMethod

    weights = load_weights(None)
    before = {k: v.clone() for k, v in weights.net.state_dict().items()}
    method = RecurrentGammaMethod(weights=weights, device="cpu")
    assert method.weights.net is not weights.net and method.weights.sha256 == weights.sha256
    conv = method.weights.net.in_cnv.weight
    assert conv.is_contiguous(memory_format=torch.channels_last) and not conv.is_contiguous()
    for name, value in weights.net.state_dict().items():
        assert value.is_contiguous() and torch.equal(value, before[name]), name
