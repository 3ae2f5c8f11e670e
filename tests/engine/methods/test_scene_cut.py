"""Scene cuts (``colonlight.scene_cut``): lighting changes keep the pixels' brightness order and a cut does not;
at a cut the ``rnn`` stream starts afresh, exactly as a new stream would, and the paper's head never does."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from colonlight.curves import gain_gamma_lut
from colonlight.errors import MethodOptionError
from colonlight.methods import FrameResult
from colonlight.methods.options import method_kwargs
from colonlight.methods.rnn import RecurrentGammaMethod
from colonlight.scene_cut import (
    DEFAULT_SCENE_CUT,
    THUMB_SIDE,
    SceneCutDetector,
    mean_ranks,
    rank_correlation,
    thumbnail,
)
from colonlight.synth import SynthConfig, generate_clip
from tests.networks import random_head_weights

WIDTH, HEIGHT, FRAMES = 128, 96, 12


def _run(method: RecurrentGammaMethod, frames: list[np.ndarray]) -> list[FrameResult]:
    """One clip through a fresh stream of ``method``."""
    stream = method.stream()
    return [r for f in frames for r in stream.push(f)]


def _clip(seed: int, **overrides: object) -> list[np.ndarray]:
    cfg = SynthConfig.sample(
        np.random.default_rng(seed), split="heldout", width=WIDTH, height=HEIGHT, n_frames=FRAMES, **overrides
    )
    return [f.image for f in generate_clip(cfg, seed=seed)]


@pytest.fixture(scope="module")
def scenes() -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Two steady held-out clips whose views differ: the test's cut is between them."""
    first, second = _clip(11, steady=True), _clip(12, steady=True)
    corr = rank_correlation(thumbnail(first[-1]), thumbnail(second[0]))
    assert corr < DEFAULT_SCENE_CUT, f"the two scenes must differ for this test to mean anything ({corr:.2f})"
    return first, second


def test_ties_take_their_mean_rank() -> None:
    thumb = np.array([[0, 0], [5, 9]], dtype=np.uint8)
    assert mean_ranks(thumb).tolist() == [1.5, 1.5, 3.0, 4.0]


def test_lighting_changes_keep_the_order_and_a_flat_frame_has_none(
    scenes: tuple[list[np.ndarray], list[np.ndarray]],
) -> None:
    frame = scenes[0][0]
    for gain, gamma in ((1.6, 1.0), (0.5, 1.0), (1.0, 0.5), (1.0, 2.0), (1.3, 0.7)):  # 1.6x clips the highlights
        assert rank_correlation(thumbnail(frame), thumbnail(gain_gamma_lut(gain, gamma)[frame])) > 0.9
    flat = np.full_like(frame, 90)
    assert rank_correlation(thumbnail(frame), thumbnail(flat)) == 0.0
    assert thumbnail(np.zeros((1, 1, 3), np.uint8)).shape == (THUMB_SIDE, THUMB_SIDE)  # any size has a thumbnail


def test_a_disturbed_clip_has_no_cut() -> None:
    """Gain jumps, tone-curve changes and exposure lag are lighting, not new scenes. (A fold that fills the view
    can be: README, session 23.)"""
    cfg = SynthConfig.sample(
        np.random.default_rng(21), split="heldout", width=WIDTH, height=HEIGHT, n_frames=48, close_occluder="forbid"
    )
    frames = [f.image for f in generate_clip(cfg, seed=21)]
    jumps = np.abs(np.diff([f.mean() for f in frames]))
    assert jumps.max() > 8, "the clip must change its lighting, or this proves little"
    detector = SceneCutDetector(DEFAULT_SCENE_CUT)
    assert {detector.judge(f) for f in frames} == {"continues"}


def test_a_frame_of_another_size_is_judged_by_its_content(
    scenes: tuple[list[np.ndarray], list[np.ndarray]],
) -> None:
    """``--content auto`` may move the content box within a scene: a slightly cropped frame is no cut; a frame
    with no order to keep (flat) is featureless at any size, and the next frame is judged against the last
    frame that had one."""
    first, second = scenes
    detector = SceneCutDetector(DEFAULT_SCENE_CUT)
    assert detector.judge(first[0]) == "continues" and detector.judge(first[1]) == "continues"
    assert detector.judge(np.ascontiguousarray(first[2][4:-4, 6:-6])) == "continues"
    assert detector.judge(np.full((HEIGHT // 2, WIDTH // 2, 3), 90, np.uint8)) == "featureless"
    assert detector.judge(first[-1]) == "continues"
    assert detector.judge(np.zeros_like(first[0])) == "featureless"
    assert detector.judge(second[0]) == "cut"
    # a frame with two levels has an order: judged, not held
    two_levels = np.zeros_like(first[0])
    two_levels[: HEIGHT // 2] = 200
    assert detector.judge(two_levels) != "featureless"


@pytest.mark.parametrize("which", ["darkest", "median", "brightest"])
def test_a_featureless_frame_is_held_and_the_clip_goes_on_as_without_it(
    scenes: tuple[list[np.ndarray], list[np.ndarray]], which: str
) -> None:
    """A dropout or a flash inside a clip: the frame passes through the last frame's table, records the last
    gamma, and the frames after it are byte for byte what they are without it (no cut, nothing learnt from it)."""
    first = scenes[0]
    ours = RecurrentGammaMethod(device="cpu")
    plain = _run(ours, first)
    at = len(first) // 2
    before = first[at - 1]
    level = {"darkest": before.min(), "median": int(np.median(before)), "brightest": before.max()}[which]
    flashed = _run(ours, first[:at] + [np.full_like(before, level)] + first[at:])
    held = flashed[at]
    assert held.info == {"held": True} and held.gamma == plain[at - 1].gamma
    # the last table, read off the frame before: where its input had this level, its output has the held one's
    written = plain[at - 1].frame[before == level]
    assert written.size and np.all(held.frame == written[0]) and np.all(written == written[0])
    assert not np.array_equal(plain[at - 1].frame, before), "the frame before must be corrected to mean anything"
    assert not any(r.info.get("scene_cut") for r in flashed)
    for with_flash, without in zip(flashed[at + 1 :], plain[at:], strict=True):
        assert np.array_equal(with_flash.frame, without.frame) and with_flash.gamma == without.gamma
        assert with_flash.info == without.info


def test_a_clip_of_featureless_frames_passes_unchanged() -> None:
    """Constant and alternating black-and-white video: nothing to correct, nothing to learn, no error."""
    ours = RecurrentGammaMethod(device="cpu")
    frames = [np.full((HEIGHT, WIDTH, 3), v, np.uint8) for v in (0, 255, 0, 255, 128, 128, 128)]
    results = list(_run(ours, frames))
    assert [r.info for r in results] == [{"held": True}] * len(frames)
    assert all(np.array_equal(r.frame, f) and r.gamma == 1.0 for r, f in zip(results, frames, strict=True))


def test_the_stream_starts_afresh_at_a_cut(scenes: tuple[list[np.ndarray], list[np.ndarray]]) -> None:
    first, second = scenes
    ours = RecurrentGammaMethod(device="cpu")  # the shipped model: cuts on by default
    assert ours.scene_cut == DEFAULT_SCENE_CUT and ours.parameters()["scene_cut"] == DEFAULT_SCENE_CUT
    stream = ours.stream()
    joined = [r for f in first + second for r in stream.push(f)]
    new_stream = ours.stream()
    fresh = [r for f in second for r in new_stream.push(f)]
    assert [i for i, r in enumerate(joined) if r.info.get("scene_cut")] == [len(first)]
    for after, new in zip(joined[len(first) :], fresh, strict=True):  # byte for byte what a new stream gives
        assert np.array_equal(after.frame, new.frame) and after.gamma == new.gamma
    # without it the network carries the first scene's lighting into the second
    off = RecurrentGammaMethod(device="cpu", scene_cut=0.0)
    assert "scene_cut" not in off.parameters()
    off_stream = off.stream()
    carried = [r for f in first + second for r in off_stream.push(f)]
    assert not any(r.info.get("scene_cut") for r in carried)
    assert not np.array_equal(carried[len(first)].frame, fresh[0].frame)


def test_the_paper_head_never_cuts(tmp_path: Path) -> None:
    gamma = random_head_weights("gamma", tmp_path / "g.pth", "g" * 64)
    paper = RecurrentGammaMethod(weights=gamma, device="cpu")
    assert paper.scene_cut == 0.0 and "scene_cut" not in paper.parameters()  # the release's records unchanged


def test_the_option_is_checked_like_every_other() -> None:
    assert method_kwargs("rnn", {"scene_cut": "0.3"})["scene_cut"] == 0.3
    with pytest.raises(MethodOptionError, match="scene_cut must be a number at least 0 and at most 1"):
        method_kwargs("rnn", {"scene_cut": "-0.1"})
    with pytest.raises(MethodOptionError, match="applies only to method rnn"):
        method_kwargs("clahe", {"scene_cut": "0.5"})
