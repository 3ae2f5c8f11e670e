"""Temporal tone matching (``colonlight.tone_match``): what the table does on cases with known answers, and how the
``rnn`` method turns it on (ours) or leaves it off (the paper's one-gamma head, the authors' checkpoint)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from colonlight.curves import gain_gamma_lut
from colonlight.errors import MethodOptionError
from colonlight.methods.options import method_kwargs
from colonlight.methods.rnn import RecurrentGammaMethod
from colonlight.metrics import luma
from colonlight.tone_match import (
    DEFAULT_TONE_MATCH,
    SAMPLE_PIXELS,
    ToneMatcher,
    matching_table,
    sample_step,
    subsample,
    usable,
)
from tests.networks import random_head_weights

LEVELS = np.arange(256, dtype=np.float64)


def _scene(seed: int = 0, height: int = 96, width: int = 128) -> np.ndarray:
    """A smooth textured frame with tones from about 40 to 150: no pixel specular, none clipped by a 1.5x gain."""
    rng = np.random.default_rng(seed)
    noise = cv2.resize(rng.random((12, 16, 3)).astype(np.float32), (width, height), interpolation=cv2.INTER_CUBIC)
    return np.clip(40 + 110 * noise, 0, 255).astype(np.uint8)


def _counts(samples: np.ndarray) -> np.ndarray:
    return np.bincount(samples, minlength=256).astype(np.float64)


def _gain(frame: np.ndarray, gain: float) -> np.ndarray:
    return np.clip(np.rint(frame * gain), 0, 255).astype(np.uint8)


def test_equal_distributions_give_the_identity_even_where_levels_are_missing() -> None:
    rng = np.random.default_rng(1)
    samples = rng.integers(0, 256, 5000).astype(np.uint8)
    samples = samples[(samples < 100) | (samples > 110) & (samples < 240)]  # a gap and a missing top
    assert np.array_equal(matching_table(_counts(samples), _counts(samples)), LEVELS)


def test_the_match_undoes_a_known_tone_curve() -> None:
    reference = np.random.default_rng(2).integers(10, 200, 20_000).astype(np.uint8)
    curve = gain_gamma_lut(1.1, 0.8)  # strictly increasing over 10..199, no clipping there (199 -> 230)
    source = curve[reference]
    table = matching_table(_counts(source), _counts(reference))
    back = table[source]
    assert np.abs(back - reference).max() <= 1.0  # each level back where it came from, to rounding
    assert np.all(np.diff(table) >= 0)


def test_a_gain_jump_is_cancelled_in_the_frame_where_it_happens() -> None:
    scene = _scene()
    frames = [scene, scene, _gain(scene, 1.5)]
    level = {}
    for weight in (0.0, 0.5, 1.0):
        matcher = ToneMatcher(weight)
        out = [matcher.table(f, None)[f] for f in frames]
        level[weight] = float(luma(out[2]).mean() - luma(out[1]).mean())
    assert level[0.0] > 0.15  # the jump as it came in (about 0.2 of the range)
    assert abs(level[1.0]) < 0.005  # gone
    assert level[0.5] == pytest.approx(level[0.0] / 2, abs=0.01)  # half of it gone


def test_a_change_the_method_holds_comes_through_geometrically() -> None:
    """The network keeps the level: a change the method's table keeps for n frames is left ``weight ** n`` times."""
    scene = _scene(3)
    matcher = ToneMatcher(0.5)
    brighter = gain_gamma_lut(1.4, 1.0)
    means = [float(luma(matcher.table(scene, None)[scene]).mean())]
    means += [float(luma(matcher.table(scene, brighter)[scene]).mean()) for _ in range(6)]
    target = float(luma(brighter[scene]).mean())
    left = [(target - m) / (target - means[0]) for m in means[1:]]
    assert left == pytest.approx([0.5**n for n in range(1, 7)], abs=0.03)


def test_a_steady_clip_keeps_the_methods_table_exactly() -> None:
    scene = _scene(4)
    table = gain_gamma_lut(1.1, 0.9)
    matcher = ToneMatcher(DEFAULT_TONE_MATCH)
    for _ in range(5):
        assert np.array_equal(matcher.table(scene, table), table)


def test_histograms_come_from_a_bounded_subsample() -> None:
    small = _scene(6)
    assert sample_step(*small.shape[:2]) == 1 and subsample(small) is small
    big = cv2.resize(small, (1920, 1080))
    sample = subsample(big)
    assert sample.shape[0] * sample.shape[1] <= SAMPLE_PIXELS and sample.shape[0] * sample.shape[1] > SAMPLE_PIXELS / 2


def test_highlights_do_not_count() -> None:
    frame = np.full((4, 4, 3), 100, np.uint8)
    frame[0, 0] = 255
    frame[0, 1] = 179  # luma 179: above the metrics' 0.7 (178.5)
    frame[0, 2] = 178  # luma 178: below it
    assert usable(frame).sum() == 14 and not usable(frame)[0, :2].any()


def test_ours_match_by_default_and_the_paper_head_does_not(tmp_path: Path) -> None:
    curve = random_head_weights("curve", tmp_path / "c.safetensors", "c" * 64, inputs="delta")
    gamma = random_head_weights("gamma", tmp_path / "g.pth", "g" * 64)
    ours = RecurrentGammaMethod(weights=curve, device="cpu")
    paper = RecurrentGammaMethod(weights=gamma, device="cpu")
    assert ours.tone_match == DEFAULT_TONE_MATCH and ours.parameters()["tone_match"] == DEFAULT_TONE_MATCH
    assert paper.tone_match == 0.0 and "tone_match" not in paper.parameters()  # the release's records unchanged
    off = RecurrentGammaMethod(weights=curve, device="cpu", tone_match=0.0)
    clip = [_scene(5), _scene(5), _gain(_scene(5), 1.4), _gain(_scene(5), 1.4)]
    a = [r.frame for f in clip for r in ours.stream().push(f)]
    s_on, s_off = ours.stream(), off.stream()
    on_frames = [r for f in clip for r in s_on.push(f)]
    off_frames = [r for f in clip for r in s_off.push(f)]
    assert all("applied_gamma" in r.info for r in on_frames[1:]) and "applied_gamma" not in off_frames[1].info
    assert [r.gamma for r in on_frames] == [r.gamma for r in off_frames]  # the network's own records are the same
    assert not np.array_equal(on_frames[2].frame, off_frames[2].frame)
    assert len(a) == len(clip)


def test_the_option_is_checked_like_every_other() -> None:
    assert method_kwargs("rnn", {"tone_match": "0.25"})["tone_match"] == 0.25
    with pytest.raises(MethodOptionError, match="tone_match must be a number at least 0 and at most 1"):
        method_kwargs("rnn", {"tone_match": "1.5"})
    with pytest.raises(MethodOptionError, match="applies only to method rnn"):
        method_kwargs("he", {"tone_match": "0.5"})
