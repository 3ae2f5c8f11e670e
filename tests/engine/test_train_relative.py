"""The ``relative`` objective: targets are the clean frames as each window's first frame shows them."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from colonlight.correction import LOG_GAIN_SPAN
from colonlight.curves import gain_gamma_lut
from colonlight.errors import OptionError
from colonlight.model import GammaNet
from colonlight.train import (
    SequenceSet,
    TrainConfig,
    batch_loss,
    darken_level_loss,
    exposure_changes,
    objective_text,
    parse_frame_steps,
    restore_loss,
    start_curve,
    temporal_restore_loss,
    train_model,
)


def _scene(rng: np.random.Generator, size: int = 32) -> np.ndarray:
    return (cv2.GaussianBlur(rng.uniform(0.05, 0.9, (size, size, 3)), (0, 0), 1.5) * 255).round().astype(np.uint8)


def test_start_curve_recovers_a_known_global_tone_change_and_is_identity_when_undisturbed() -> None:
    clean = _scene(np.random.default_rng(0), 64)
    assert np.array_equal(start_curve(clean, clean)[np.unique(clean)], np.unique(clean))
    lut = gain_gamma_lut(1.4, 0.7)
    recorded = lut[clean]
    got = start_curve(clean, recorded)
    assert np.abs(got[clean].astype(int) - recorded.astype(int)).max() <= 1


def test_a_steady_clip_exposed_unlike_its_clean_frames_is_its_own_target() -> None:
    """A clip recorded brighter than 'clean' throughout (steady lighting): restore asks the model to darken it to
    the training set's idea of right; relative asks for the frames as they are."""
    rng = np.random.default_rng(1)
    scene = _scene(rng, 48)
    clean = np.stack([scene[i : i + 32, i : i + 32] for i in range(8)])  # the camera moves over one scene
    recorded = gain_gamma_lut(1.5, 0.8)[clean]
    restore = SequenceSet([recorded], 4, 2, [clean])
    relative = SequenceSet([recorded], 4, 2, [clean], relative=True)
    frames = relative.batch([0, 1, 2])
    assert (restore.clean_batch([0]) - frames[:1]).abs().mean() > 0.05
    error = (relative.clean_batch([0, 1, 2]) - frames).abs()
    assert error.mean() <= 0.5 / 255 and error.max() <= 4 / 255  # levels the first frame lacks are interpolated


def test_a_gain_jump_inside_a_window_is_undone_relative_to_its_start() -> None:
    rng = np.random.default_rng(2)
    clean = np.stack([_scene(rng)] * 6)
    gains = [1.0, 1.0, 1.0, 1.6, 1.6, 1.0]
    recorded = np.stack([gain_gamma_lut(g, 1.0)[c] for g, c in zip(gains, clean, strict=True)])
    targets = SequenceSet([recorded], 6, 6, [clean], relative=True).clean_batch([0])[0]
    assert (targets - SequenceSet([clean], 6, 6).batch([0])[0]).abs().max() <= 1.5 / 255  # start undisturbed: clean


def _pair_clip(root: Path, seed: int, n: int = 12, size: int = 32) -> Path:
    rng = np.random.default_rng(seed)
    base = _scene(rng, size)
    exposure = rng.uniform(0.6, 1.5)  # the whole clip's own exposure, which the truth shares in steady windows
    for sub in ("frames", "clean"):
        (root / sub).mkdir(parents=True)
    for i in range(n):
        gain = 1.0 if i % 4 < 2 else rng.uniform(0.6, 1.5)
        cv2.imwrite(str(root / "clean" / f"{i:04d}.png"), base[..., ::-1])
        cv2.imwrite(str(root / "frames" / f"{i:04d}.png"), gain_gamma_lut(exposure * gain, 1.0)[base][..., ::-1])
    return root / "frames"


def test_training_with_the_relative_objective_learns_and_records_it(tmp_path: Path) -> None:
    clips = [_pair_clip(tmp_path / f"c{i}", i) for i in range(3)]
    cfg = TrainConfig(
        size=32, seq_len=6, stride=4, batch=2, lr=3e-3, epochs=3, fps=None, head="gain-gamma", objective="relative"
    )
    res = train_model(clips[:2], clips[2:], tmp_path / "run", cfg, name="rel")
    assert res.card["training"]["objective"].startswith("mean |corrected - clean as the window's first frame")
    assert res.card["seed_frames"] == 0
    assert res.history[-1].train_loss < res.history[0].train_loss


def test_relative_targets_need_clean_frames() -> None:
    with pytest.raises(ValueError, match="clean"):
        SequenceSet([np.zeros((4, 8, 8, 3), np.uint8)], 2, 1, relative=True)


def test_exposure_jitter_is_only_for_the_relative_objective_and_bounded() -> None:
    from colonlight.errors import OptionError

    with pytest.raises(OptionError, match="relative"):
        TrainConfig(objective="restore", exposure_jitter=0.5)
    with pytest.raises(OptionError, match=">= 0"):
        TrainConfig(objective="relative", exposure_jitter=-0.1)
    gain, gamma = exposure_changes(1000, 0.5, np.random.default_rng(0))
    assert gain.log().abs().max() <= 0.5 and gamma.log().abs().max() <= 0.25
    assert gain.log().abs().max() > 0.45 and gamma.log().abs().max() > 0.2  # the span is used, not a corner of it
    again = exposure_changes(1000, 0.5, np.random.default_rng(0))
    assert torch.equal(gain, again[0]) and torch.equal(gamma, again[1])


def test_an_exposure_change_moves_a_windows_targets_with_its_frames() -> None:
    """On a steady window (its own target), the identity correction stays exact under any exposure change, and a
    correction that undoes the change (what a model keyed to absolute brightness learns) is penalised."""
    rng = np.random.default_rng(3)
    scene = _scene(rng, 40)
    clean = np.stack([scene[i : i + 32, i : i + 32].transpose(2, 0, 1) for i in range(6)])  # (T, 3, H, W)
    data = SequenceSet([clean], 6, 6, [clean], relative=True)
    cfg = TrainConfig(size=32, seq_len=6, stride=6, head="gain-gamma", objective="relative")
    identity = GammaNet(head="gain-gamma").eval()  # zero output layer: gain 1, gamma 1
    darken = (torch.tensor([1.0 / 1.5]), torch.tensor([1.0]))
    with torch.no_grad():
        assert float(batch_loss(identity, data, [0], cfg, 0.0, darken)) < 1e-3  # start_curve interpolates
        undo = GammaNet(head="gain-gamma").eval()
        undo.out_linear.bias.copy_(torch.tensor([0.0, math.atanh(math.log(1.5) / LOG_GAIN_SPAN)]))
        assert float(batch_loss(undo, data, [0], cfg, 0.0, darken)) > 0.05


def test_frame_steps_add_windows_of_every_kth_frame_with_their_targets() -> None:
    """Step 2 over a 9-frame clip with windows of 4: frames 0, 2, 4, 6 (one window: start 0 only, at stride 4),
    beside the step-1 windows 0..3 and 4..7; the relative targets are the clean frames of the same frames."""
    levels = np.arange(256, dtype=np.uint8)
    clip = np.stack([np.repeat(np.roll(levels, 10 * i).reshape(16, 16, 1), 3, axis=2) for i in range(9)])
    data = SequenceSet([clip], 4, 4, [clip.copy()], relative=True, frame_steps=(1, 2))
    assert len(data) == 3
    firsts = data.batch([0, 1, 2])[:, :, 0, 0, 0].mul(255).round().long().tolist()
    assert firsts == [[(-10 * i) % 256 for i in frames] for frames in ([0, 1, 2, 3], [4, 5, 6, 7], [0, 2, 4, 6])]
    assert torch.equal(data.clean_batch([2]), data.batch([2]))  # undisturbed: the targets are the frames
    assert TrainConfig(frame_steps=(2, 1, 2)).frame_steps == (1, 2)
    for bad in [(), (0,), (1, -2)]:
        with pytest.raises(OptionError, match="frame steps"):
            TrainConfig(frame_steps=bad)
    assert parse_frame_steps("1,2") == (1, 2)
    with pytest.raises(OptionError, match="'1,x'"):
        parse_frame_steps("1,x")


def test_undisturbed_windows_are_found_exactly_and_weighted_in_both_supervised_terms() -> None:
    """Windows of 4 over 8 frames whose clean frames differ from the recorded ones only in frame 6: the first
    window is undisturbed, the second is not. With weights (3, 1), mean errors of 0.05 (first) and 0.3 (second)
    average (3 x 0.05 + 0.3) / 4 per sample, and frame-to-frame error changes of 0.1 (first) and 0 average
    3 x 0.1 / 4 = 0.075; unweighted, (0.05 + 0.3) / 2 and 0.05."""
    rng = np.random.default_rng(5)
    clip = np.stack([_scene(rng, 16) for _ in range(8)])
    clean = clip.copy()
    clean[6, 0, 0, 0] ^= 1  # one sample of one frame: disturbed
    data = SequenceSet([clip], 4, 4, [clean], relative=True)
    assert data.undisturbed == [True, False]
    assert data.window_weights([0, 1], 1.0) is None
    assert data.window_weights([1, 0], 3.0).tolist() == [1.0, 3.0]
    assert SequenceSet([clip], 4, 4).window_weights([0], 3.0) is None  # no clean frames: nothing to tell
    frames = torch.full((2, 4, 3, 4, 4), 0.5)
    target = frames.clone()
    corrected = frames + torch.tensor([0.1, 0.3])[:, None, None, None, None]
    corrected[0, 1::2] -= 0.1  # window 0: errors 0.1, 0, 0.1, 0 (mean 0.05, changes 0.1)
    weights = torch.tensor([3.0, 1.0])
    out = torch.zeros(2, 4, 8)
    assert float(restore_loss(frames, target, out, "curve", corrected)) == pytest.approx((0.05 + 0.3) / 2)
    assert float(restore_loss(frames, target, out, "curve", corrected, weights)) == pytest.approx((0.15 + 0.3) / 4)
    assert float(temporal_restore_loss(frames, target, out, "curve", corrected)) == pytest.approx(0.05)
    assert float(temporal_restore_loss(frames, target, out, "curve", corrected, weights)) == pytest.approx(0.075)


@pytest.mark.parametrize(
    ("option", "bad_values", "recorded"),
    [
        ("steady_weight", (0.0, -1.0, math.nan, math.inf), "weigh 4 x"),
        ("darken_weight", (0.0, -1.0, math.nan, math.inf), "darker than its target costs 4 x"),
        ("darken_level", (-1.0, math.nan, math.inf), "plus 4 x mean over frames of how far the mean level falls"),
    ],
)
def test_the_supervised_weights_are_checked_and_recorded_in_the_objective(
    option: str, bad_values: tuple[float, ...], recorded: str
) -> None:
    """Each is refused out of range and with the unsupervised objective (no clean frames), and the objective's
    words say it only when it is not neutral."""
    words = option.replace("_", " ")
    for bad in bad_values:
        with pytest.raises(OptionError, match=words):
            TrainConfig(objective="relative", **{option: bad})
    with pytest.raises(OptionError, match="supervised"):
        TrainConfig(objective="paper", **{option: 2.0})
    assert recorded in objective_text(TrainConfig(objective="relative", **{option: 4.0}))
    assert recorded not in objective_text(TrainConfig(objective="relative"))


def test_the_darken_weight_costs_only_samples_corrected_darker_than_their_target() -> None:
    """Errors of -0.1 and +0.3 against the target: a darken weight of 3 triples the first alone ((0.3 + 0.3) / 2),
    the steady weight still weighs whole windows."""
    frames = torch.full((2, 1, 1, 1, 1), 0.5)
    target = torch.full((2, 1, 1, 1, 1), 0.5)
    corrected = torch.tensor([0.4, 0.8]).view(2, 1, 1, 1, 1)
    out = torch.zeros(2, 1, 8)
    assert float(restore_loss(frames, target, out, "curve", corrected)) == pytest.approx(0.2)
    assert float(restore_loss(frames, target, out, "curve", corrected, None, 3.0)) == pytest.approx(0.3)
    weights = torch.tensor([1.0, 3.0])
    assert float(restore_loss(frames, target, out, "curve", corrected, weights, 3.0)) == pytest.approx(1.2 / 4)


def test_the_darken_level_costs_only_frames_whose_mean_falls_below_the_target() -> None:
    """Two frames whose samples err by (-0.2, +0.1) and (+0.1, +0.1): only the first frame's mean (-0.05) is below
    its target's, so the term is 0.05 / 2 over the window; a window weight weighs whole windows; clipped input
    samples are left out."""
    frames = torch.full((1, 2, 1, 1, 2), 0.5)
    target = torch.full((1, 2, 1, 1, 2), 0.5)
    corrected = target + torch.tensor([[-0.2, 0.1], [0.1, 0.1]]).view(1, 2, 1, 1, 2)
    assert float(darken_level_loss(frames, target, corrected)) == pytest.approx(0.025)
    two = torch.cat([corrected, target + 0.1])  # a second window, never below its target
    assert float(
        darken_level_loss(
            frames.expand(2, -1, -1, -1, -1), target.expand(2, -1, -1, -1, -1), two, torch.tensor([3.0, 1.0])
        )
    ) == pytest.approx(0.075 / 4)
    clipped = frames.clone()
    clipped[0, 0, 0, 0, 1] = 1.0  # the +0.1 sample of the first frame was clipped: its mean error is -0.2
    assert float(darken_level_loss(clipped, target, corrected)) == pytest.approx(0.1)
