"""Lookup tables: bit-exact against the formula, identity and limits."""

from __future__ import annotations

import numpy as np
import pytest

from colonlight.curves import apply_gamma, apply_lut, gamma_lut

V = np.arange(256, dtype=np.float64)


@pytest.mark.parametrize("gamma", [0.125, 1 / 2.1, 0.5, 1 / 1.1, 1.0, 1.37, 2.0, 4.0, 0.7391])
def test_lut_is_bit_identical_to_formula(gamma: float) -> None:
    expected = np.array([round(255 * (v / 255) ** gamma) for v in V], dtype=np.uint8)
    assert np.array_equal(gamma_lut(gamma), expected)


def test_many_random_gammas_bit_exact() -> None:
    rng = np.random.default_rng(0)
    for gamma in rng.uniform(0.125, 4.0, 300):
        assert np.array_equal(gamma_lut(gamma), np.rint(255 * (V / 255) ** gamma).astype(np.uint8))


@pytest.mark.parametrize("shape", [(1, 1, 3), (7, 5, 3), (1080, 1350, 3), (4, 4)])
def test_apply_matches_per_pixel_formula(shape: tuple[int, ...]) -> None:
    frame = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    out = apply_gamma(frame, 0.6)
    assert out.shape == frame.shape and out.dtype == np.uint8
    assert np.array_equal(out, np.rint(255 * (frame / 255.0) ** 0.6).astype(np.uint8))


def test_identity_and_fixed_points() -> None:
    frame = np.random.default_rng(2).integers(0, 256, (9, 9, 3), dtype=np.uint8)
    assert np.array_equal(apply_gamma(frame, 1.0), frame)
    for g in (0.125, 4.0):
        lut = gamma_lut(g)
        assert lut[0] == 0 and lut[255] == 255


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_gamma_raises(bad: float) -> None:
    with pytest.raises(ValueError, match="gamma"):
        gamma_lut(bad)


def test_bad_lut_or_frame() -> None:
    with pytest.raises(ValueError):
        apply_lut(np.zeros((2, 2, 3), np.uint8), np.zeros(255, np.uint8))
    with pytest.raises(ValueError):
        apply_lut(np.zeros((2, 2, 3), np.float32), np.zeros(256, np.uint8))
