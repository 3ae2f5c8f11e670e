"""Lighting metrics on cases with known answers."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from colonlight.metrics import border_mask, clip_lighting, content_masks, flicker, luma, psnr


def _clip(levels: list[int], size: int = 16) -> list[np.ndarray]:
    return [np.full((size, size, 3), v, np.uint8) for v in levels]


def test_known_gain_jump_gives_expected_flicker() -> None:
    frames = _clip([100, 100, 150, 150, 100])  # two jumps of 50 levels over 4 steps
    masks = content_masks(frames)
    assert flicker(frames, masks) == pytest.approx(2 * (50 / 255) / 4, rel=1e-5)


def test_constant_clip_has_no_flicker_and_identity_is_perfect() -> None:
    frames = _clip([90] * 6)
    r = clip_lighting(frames, frames, clean=frames)
    assert r.flicker_in == 0 and r.flicker_out == 0 and r.flicker_reduction == 0
    assert r.psnr_in == float("inf")


def test_speculars_and_border_are_left_out() -> None:
    frames = _clip([100, 100, 100])
    for f in frames:
        f[:, :2] = 0  # scope border: black in every frame
    frames[1][4:8, 4:8] = 250  # a specular highlight in frame 1 only
    masks = content_masks(frames)
    assert not masks[0][:, :2].any() and border_mask(frames)[:, :2].all()
    assert not masks[1][4:8, 4:8].any()
    assert flicker(frames, masks) == pytest.approx(0.0, abs=1e-7)


def test_flicker_compares_each_pair_over_the_same_pixels() -> None:
    # a steady scene of a dark and a bright half; the bright half turns specular (> 0.7) in the input's odd
    # frames, so those frames' masks drop it. Per-frame masks would see the steady clean frames flicker
    # between the dark half's mean and the whole frame's mean; pairwise-common pixels see none.
    clean = [np.zeros((16, 16, 3), np.uint8) for _ in range(4)]
    for c in clean:
        c[:, :8], c[:, 8:] = 60, 160
    inputs = [c.copy() for c in clean]
    for f in inputs[1::2]:
        f[:, 8:] = 200
    masks = content_masks(inputs)
    assert masks[0][:, 8:].all() and not masks[1][:, 8:].any()
    assert flicker(clean, masks) == pytest.approx(0.0, abs=1e-7)
    assert flicker(inputs, masks) == pytest.approx(0.0, abs=1e-7)  # the changing half never counts


def test_flicker_reduction_and_psnr() -> None:
    inputs = _clip([100, 160, 100, 160])
    outputs = _clip([100, 110, 100, 110])
    r = clip_lighting(inputs, outputs, clean=_clip([100] * 4), skip=0)
    assert r.flicker_reduction == pytest.approx(1 - 10 / 60, rel=1e-5)
    assert r.psnr_out > r.psnr_in
    a, b = _clip([100])[0], _clip([110])[0]
    assert psnr(a, b, np.ones((16, 16), bool)) == pytest.approx(10 * np.log10(255**2 / 100))
    assert luma(np.full((1, 1, 3), 255, np.uint8))[0, 0] == pytest.approx(1.0, abs=1e-6)


def test_a_clip_without_content_pixels_scores_nan_without_a_warning() -> None:
    """An all-black clip has no content pixels: its levels and PSNR are undefined (NaN, shown as n/a), and
    numpy's "Mean of empty slice" warning must not reach the user of ``colonlight evaluate``."""
    frames = _clip([0] * 5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = clip_lighting(frames, frames, clean=frames)
    assert math.isnan(r.mean_luma_in) and math.isnan(r.mean_luma_out)
    assert math.isnan(r.psnr_in) and math.isnan(r.psnr_out)  # type: ignore[arg-type]
