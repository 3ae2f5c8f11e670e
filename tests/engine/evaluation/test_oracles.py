"""The oracle corrections (colonlight.evaluation.oracles) on frames made from a clean frame by a known curve:
each oracle must give the curve's inverse back, and its output must match the clean frame up to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from colonlight.curves import apply_lut, gain_gamma_lut, gamma_lut
from colonlight.evaluation.oracles import (
    CURVE_LABEL,
    GAIN_GAMMA_LABEL,
    GAMMA_LABEL,
    level_stats,
    oracle_curve,
    oracle_frames,
    oracle_gain_gamma,
    oracle_gamma,
)
from colonlight.methods.rnn import GAIN_MAX, GAIN_MIN, GAMMA_MAX, GAMMA_MIN


@pytest.fixture(scope="module")
def clean() -> np.ndarray:
    """A clean 96-px frame of the project's generator (a real wall: shading, texture, noise)."""
    from colonlight.synth import SynthConfig, generate_clip

    cfg = SynthConfig.sample(np.random.default_rng(4), split="train", width=96, height=96, n_frames=1, steady=True)
    return next(iter(generate_clip(cfg, 4))).clean


def _error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


@pytest.mark.parametrize("curve_gamma", [0.7, 1.5])
def test_oracle_gamma_recovers_the_inverse_of_a_known_gamma(clean: np.ndarray, curve_gamma: float) -> None:
    """input = clean through gamma g, so the best gamma back is 1/g (within rounding of the two tables)."""
    frame = apply_lut(clean, gamma_lut(curve_gamma))
    g = oracle_gamma(frame, clean)
    assert g == pytest.approx(1 / curve_gamma, rel=0.01)
    out = apply_lut(frame, gamma_lut(g))
    assert _error(out, clean) < 0.4  # grey levels: rounding only (the input lost no more)
    assert _error(frame, clean) > 10 * _error(out, clean)
    # least squares: no gamma does better than the oracle's, the true inverse included
    stats = level_stats(frame, clean)
    best = stats.cost(gamma_lut(g).astype(np.float64))
    assert best <= stats.cost(gamma_lut(1 / curve_gamma).astype(np.float64)) + 1e-9
    for other in np.exp(np.linspace(np.log(GAMMA_MIN), np.log(GAMMA_MAX), 60)):
        assert best <= stats.cost(gamma_lut(other).astype(np.float64)) + 1e-9


def test_oracle_gamma_stays_in_the_products_clamp_range(clean: np.ndarray) -> None:
    dark = apply_lut(clean, gamma_lut(10.0))  # would need 1/10 < GAMMA_MIN to undo
    assert oracle_gamma(dark, clean) == pytest.approx(GAMMA_MIN, rel=0.01)
    bright = apply_lut(clean, gamma_lut(0.2))  # would need 5 > GAMMA_MAX
    assert oracle_gamma(bright, clean) == pytest.approx(GAMMA_MAX, rel=0.01)
    for g in (oracle_gamma(dark, clean), oracle_gamma(bright, clean)):
        assert GAMMA_MIN <= g <= GAMMA_MAX


@pytest.mark.parametrize(("gain", "gamma"), [(0.6, 1.4), (0.7, 0.75)])
def test_oracle_gain_gamma_recovers_the_inverse_of_a_known_gain_and_gamma(
    clean: np.ndarray, gain: float, gamma: float
) -> None:
    """input = g * clean ** k (a recorder's exposure and contrast change), so the best gain and gamma back are
    g ** (-1/k) and 1/k; one gamma cannot undo both, so the oracle gamma does much worse on the same frame. (Both
    cases darken: the clean frame has saturated samples, and a brightened frame loses what clipping hides.)"""
    v = np.arange(256) / 255.0
    frame = apply_lut(clean, np.rint(255 * np.minimum(1.0, gain * v**gamma)).astype(np.uint8))
    found_gain, found_gamma = oracle_gain_gamma(frame, clean)
    assert found_gamma == pytest.approx(1 / gamma, rel=0.03)
    assert found_gain == pytest.approx(gain ** (-1 / gamma), rel=0.03)
    out = apply_lut(frame, gain_gamma_lut(found_gain, found_gamma))
    assert _error(out, clean) < 0.6  # rounding of the two tables only
    assert _error(frame, clean) > 10 * _error(out, clean)
    # least squares: no gain and gamma of a grid over the clamp ranges (nor the true inverse) does better
    stats = level_stats(frame, clean)
    best = stats.cost(gain_gamma_lut(found_gain, found_gamma).astype(np.float64))
    truth = stats.cost(gain_gamma_lut(gain ** (-1 / gamma), 1 / gamma).astype(np.float64))
    assert best <= truth + 1e-9
    for g in np.exp(np.linspace(np.log(GAIN_MIN), np.log(GAIN_MAX), 25)):
        for k in np.exp(np.linspace(np.log(GAMMA_MIN), np.log(GAMMA_MAX), 25)):
            assert best <= stats.cost(gain_gamma_lut(g, k).astype(np.float64)) + 1e-9
    gamma_only = apply_lut(frame, gamma_lut(oracle_gamma(frame, clean)))
    assert _error(gamma_only, clean) > 3 * _error(out, clean)


def test_oracle_gain_gamma_of_an_undisturbed_frame_is_the_identity(clean: np.ndarray) -> None:
    gain, gamma = oracle_gain_gamma(clean, clean)
    assert np.array_equal(apply_lut(clean, gain_gamma_lut(gain, gamma)), clean)
    assert gain == pytest.approx(1.0, abs=0.01) and gamma == pytest.approx(1.0, abs=0.01)


def test_oracle_curve_recovers_a_monotone_non_gamma_curve(clean: np.ndarray) -> None:
    """An S-curve v - 0.1 sin(2 pi v) (monotone, no gamma fits it): the curve oracle inverts it, up to the
    levels the 8-bit S-curve merged (where its slope is below 1), which no table can separate again."""
    v = np.arange(256) / 255.0
    s_curve = np.clip(np.rint(255 * (v - 0.1 * np.sin(2 * np.pi * v))), 0, 255).astype(np.uint8)
    assert np.all(np.diff(s_curve.astype(int)) >= 0)
    frame = apply_lut(clean, s_curve)
    lut = oracle_curve(frame, clean)
    assert lut.dtype == np.uint8 and lut.shape == (256,)
    assert np.all(np.diff(lut.astype(int)) >= 0)  # monotone non-decreasing
    # the least-squares answer for a monotone curve is the mean clean value behind each input level
    for u in np.unique(frame):
        assert lut[u] == np.rint(clean[frame == u].mean()), u
    injective = [c for c in np.unique(clean) if np.count_nonzero(s_curve == s_curve[c]) == 1]
    assert len(injective) > 100
    assert np.array_equal(lut[s_curve[injective]], injective)  # exact inverse where the curve kept levels apart
    out = apply_lut(frame, lut)
    assert _error(out, clean) < 0.3 and _error(frame, clean) > 20 * _error(out, clean)
    # one gamma cannot do this: the curve oracle is much better here
    g = oracle_gamma(frame, clean)
    assert _error(apply_lut(frame, gamma_lut(g)), clean) > 5 * _error(out, clean)


def test_oracle_curve_is_isotonic_least_squares_and_fills_unseen_levels() -> None:
    """Samples that disagree: level 10 -> clean 50 and 30 (mean 40), level 20 -> 20 (below: pooled with 10,
    weights 2 and 1 -> 100/3); levels never seen are interpolated between their neighbours."""
    frame = np.array([[10, 10, 20, 200]], np.uint8)
    clean = np.array([[50, 30, 20, 220]], np.uint8)
    lut = oracle_curve(frame, clean)
    assert lut[10] == lut[20] == round(100 / 3)
    assert lut[200] == 220
    assert lut[110] == round(33.33 + (220 - 33.33) * 90 / 180)  # interpolated
    assert lut[0] == lut[10] and lut[255] == 220  # held flat beyond the ends
    assert np.all(np.diff(lut.astype(int)) >= 0)


def test_oracle_frames_and_bad_input(clean: np.ndarray) -> None:
    frames = [apply_lut(clean, gamma_lut(0.8)), apply_lut(clean, gamma_lut(1.25))]
    out, gammas = oracle_frames(frames, [clean, clean], GAMMA_LABEL)
    assert gammas[0] == pytest.approx(1.25, rel=0.01) and gammas[1] == pytest.approx(0.8, rel=0.01)
    assert all(_error(o, clean) < 0.4 for o in out)
    out, gammas = oracle_frames(frames, [clean, clean], GAIN_GAMMA_LABEL)
    assert gammas[0] == pytest.approx(1.25, rel=0.01) and gammas[1] == pytest.approx(0.8, rel=0.01)
    assert all(_error(o, clean) < 0.4 for o in out)
    out, gammas = oracle_frames(frames, [clean, clean], CURVE_LABEL)
    assert gammas == [None, None] and all(_error(o, clean) < 0.4 for o in out)
    with pytest.raises(ValueError, match="2 frames but 1 clean"):
        oracle_frames(frames, [clean], CURVE_LABEL)
    with pytest.raises(ValueError, match="unknown oracle"):
        oracle_frames(frames, [clean, clean], "oracle-magic")
    with pytest.raises(ValueError, match="one shape"):
        oracle_curve(clean, clean[:10])
