"""Training: the paper's loss, a short run lowers it, per-epoch states resume to the same result."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from colonlight.checkpoint import load_weights
from colonlight.errors import InputError
from colonlight.model import GammaNet
from colonlight.train import (
    SPECULAR_THRESHOLD,
    SequenceSet,
    TrainConfig,
    export_epoch,
    sequence_loss,
    train_model,
    window_starts,
)


def _flicker_clip(folder: Path, seed: int, n: int = 20, size: int = 48) -> Path:
    """A textured scene whose brightness and contrast jump from frame to frame."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.uniform(0.15, 0.6, (size, size, 3)), (0, 0), 2.0)
    base[..., 0] *= 1.3
    folder.mkdir(parents=True)
    for i in range(n):
        gamma = 1.0 if i < 2 else rng.uniform(0.5, 2.0)
        frame = np.clip(base**gamma, 0, 1)
        cv2.imwrite(str(folder / f"{i:04d}.png"), (frame[..., ::-1] * 255).round().astype(np.uint8))
    return folder


def test_windows() -> None:
    assert window_starts(20, 10, 5) == [0, 5, 10]
    assert window_starts(9, 10, 5) == []
    assert window_starts(10, 10, 5) == [0]


def test_loss_is_zero_for_identical_frames_and_masks_speculars() -> None:
    x = torch.full((1, 6, 3, 16, 16), 0.4)
    assert float(sequence_loss(x, torch.ones(1, 6))) == pytest.approx(0.0, abs=1e-6)
    y = torch.rand(1, 6, 3, 16, 16) * 0.5
    y[:, 2:] = 0.95  # targets entirely specular: no pixel counts, whatever they look like
    assert float(sequence_loss(y, torch.ones(1, 6))) == pytest.approx(0.0, abs=1e-6)
    y[:, 2:, :, :8] = 0.3  # half the target visible again: now it counts
    assert float(sequence_loss(y, torch.ones(1, 6))) > 0.05
    assert SPECULAR_THRESHOLD == 0.7


def test_loss_prefers_the_gamma_that_undoes_a_disturbance() -> None:
    base = torch.rand(1, 1, 3, 32, 32) * 0.6 + 0.05
    frames = torch.cat([base, base, base**2.0, base**2.0], dim=1)  # targets darkened by gamma 2
    right = torch.tensor([[1.0, 1.0, 2.0, 2.0]])  # a = 2 -> I ** (1/2) restores them
    wrong = torch.tensor([[1.0, 1.0, 0.7, 0.7]])
    assert float(sequence_loss(frames, right)) < 1e-4 < float(sequence_loss(frames, wrong))


def test_brightness_anchor_adds_the_weighted_mean_shift_and_is_off_by_default() -> None:
    torch.manual_seed(0)
    frames = torch.rand(2, 5, 3, 16, 16) * 0.9
    a = torch.tensor([[1.0, 1.0, 1.5, 0.8, 1.2], [1.0, 1.0, 1.0, 1.0, 1.0]])
    paper = sequence_loss(frames, a)
    assert float(sequence_loss(frames, a, anchor=0.0)) == float(paper)
    # expected: per target, the shift of its mean over the pixels the loss keeps (input <= 0.7), averaged
    shifts = []
    for b in range(2):
        for t in range(2, 5):
            keep = frames[b, t].mean(dim=0) <= SPECULAR_THRESHOLD
            shift = (frames[b, t].clamp_min(1e-8) ** (1 / a[b, t]) - frames[b, t])[:, keep].mean()
            shifts.append(abs(float(shift)))
    expected = float(paper) + 0.3 * float(np.mean(shifts))
    assert float(sequence_loss(frames, a, anchor=0.3)) == pytest.approx(expected, rel=1e-4)
    assert shifts[3:] == [0.0, 0.0, 0.0]  # a = 1 moves nothing, so costs nothing
    assert TrainConfig().anchor == 0.0


def test_short_training_lowers_loss_and_resumes_identically(tmp_path: Path) -> None:
    clips = [_flicker_clip(tmp_path / f"c{i}", seed=i) for i in range(3)]
    cfg = TrainConfig(size=32, epochs=3, batch=2, lr=2e-3, seed=0)
    torch.set_num_threads(1)
    full = train_model(clips[:2], clips[2:], tmp_path / "full", cfg)
    losses = [h.train_loss for h in full.history]
    assert losses[-1] < losses[0]
    assert full.card["training"]["history"][-1]["val_loss"] is not None

    partial = train_model(clips[:2], clips[2:], tmp_path / "part", TrainConfig(**{**vars(cfg), "epochs": 1}))
    assert len(partial.history) == 1
    partial_state = load_weights(partial.weights).net.state_dict()  # before the resumes below overwrite it
    resumed = train_model(clips[:2], clips[2:], tmp_path / "part", cfg)  # continues from epoch 1
    assert [h.epoch for h in resumed.history] == [1, 2, 3]
    a, b = load_weights(full.weights).net.state_dict(), load_weights(resumed.weights).net.state_dict()
    for k in a:
        assert torch.allclose(a[k].float(), b[k].float(), atol=1e-6), k
    # a resume with another learning rate uses it for the remaining epochs (not the saved optimizer's)
    slower = train_model(clips[:2], clips[2:], tmp_path / "part", TrainConfig(**{**vars(cfg), "epochs": 4, "lr": 1e-4}))
    state = json.loads((tmp_path / "part" / "checkpoints" / "epoch_004.json").read_text())
    assert [g["lr"] for g in state["param_groups"]] == [1e-4] and len(slower.history) == 4
    card = json.loads(full.weights.with_suffix(".json").read_text())
    assert card["input_size"] == 32 and card["training"]["epochs"] == 3 and len(card["sha256"]) == 64

    # any saved epoch exports as the weights and card the run would have written had it stopped there
    first = export_epoch(tmp_path / "full", 1)
    assert first.weights == tmp_path / "full" / "colonlight-rnn-epoch001.safetensors"
    first_state = load_weights(first.weights).net.state_dict()  # the 1-epoch run's weights
    for k in first_state:
        assert torch.allclose(first_state[k].float(), partial_state[k].float(), atol=1e-6), k
    assert first.card["training"]["shipped_epoch"] == 1 and len(first.card["training"]["history"]) == 1
    last = export_epoch(tmp_path / "full", 3, tmp_path / "last.safetensors")
    assert last.card["sha256"] == card["sha256"]
    same = {k: v for k, v in card["training"].items() if k != "history"}
    assert {k: v for k, v in last.card["training"].items() if k not in ("history", "shipped_epoch")} == same
    with pytest.raises(InputError, match=r"no saved state for epoch 7 \(epochs saved: 1, 2, 3\)"):
        export_epoch(tmp_path / "full", 7)


def test_export_epoch_refuses_damaged_or_foreign_states_in_one_line(tmp_path: Path) -> None:
    from safetensors.torch import save_file

    state = tmp_path / "checkpoints" / "epoch_001"
    state.parent.mkdir(parents=True)
    save_file({"model.x": torch.zeros(1)}, str(state.with_suffix(".safetensors")))
    cases = {
        "{not json": "unreadable training state",
        "[1]": "no model card to export",
        '{"epoch": 1, "history": []}': "no model card to export",
        '{"card": {"head": "zzz", "training": {}}, "history": []}': "do not match its card (unknown head 'zzz'",
        '{"card": {"head": "gamma", "training": {}}, "history": []}': "do not match its card",
    }
    for text, message in cases.items():
        state.with_suffix(".json").write_text(text)
        with pytest.raises(InputError, match=re.escape(message)) as err:
            export_epoch(tmp_path, 1)
        assert "\n" not in str(err.value)
    # tensors that fit the card's network, but a card without its training record or name
    net = {f"model.{k}": v for k, v in GammaNet(head="gain-gamma").state_dict().items()}
    save_file(net, str(state.with_suffix(".safetensors")))
    for card, missing in (
        ({"head": "gain-gamma", "name": "n"}, "'training'"),
        ({"head": "gain-gamma", "training": {}}, "'name'"),
    ):
        state.with_suffix(".json").write_text(json.dumps({"card": card, "history": []}))
        with pytest.raises(InputError, match=re.escape(f"do not match its card ({missing})")):
            export_epoch(tmp_path, 1)
    assert not list(tmp_path.glob("*-epoch001.*"))  # nothing written on the way to an error


def test_sequence_set_batches(tmp_path: Path) -> None:
    clip = np.zeros((12, 3, 8, 8), np.uint8)
    clip[:, 0] = np.arange(12)[:, None, None]
    ds = SequenceSet([clip], seq_len=10, stride=2)
    assert len(ds) == 2
    batch = ds.batch([1])
    assert batch.shape == (1, 10, 3, 8, 8)
    assert float(batch[0, 0, 0, 0, 0]) == pytest.approx(2 / 255)


def test_train_on_synthetic_folders_reads_their_lossless_frames_beside_clean(tmp_path: Path) -> None:
    """``colonlight synth`` then ``colonlight train`` on the same folder: each clip folder is one clip, read from
    its frames/ (frame for frame beside clean/), not from its H.264 clip.mp4 (at 30 fps, which the 18 fps
    extraction would thin out, so clean/ would not match it)."""
    from colonlight_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    clips = tmp_path / "clips"
    made = runner.invoke(
        app, ["synth", str(clips), "-n", "2", "--frames", "12", "--width", "48", "--height", "48", "--fps", "30"]
    )
    assert made.exit_code == 0, made.output
    assert all((c / "clip.mp4").is_file() for c in clips.iterdir())
    run = tmp_path / "run"
    res = runner.invoke(
        app,
        [
            "train", str(clips), "-o", str(run), "--head", "gain-gamma", "--objective", "restore", "--epochs", "1",
            "--size", "16", "--seq-len", "4", "--stride", "4", "--batch", "2",
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    card = json.loads((run / "colonlight-rnn.json").read_text())
    assert card["head"] == "gain-gamma" and card["training"]["objective"].startswith("mean |corrected - clean|")


def test_steady_and_darken_options_from_the_command_line_are_trained_with_and_recorded(tmp_path: Path) -> None:
    """Two steady synthetic clips (recorded frames are their clean ones; one trains, one validates): every
    window is undisturbed, so the weight applies to all of them; the card records it; a weight of 0, or one with
    the unsupervised objective (which has no clean frames to tell steady windows by), is a usage error before
    anything is read."""
    from colonlight_cli.main import app
    from typer.testing import CliRunner

    runner = CliRunner()
    clips = tmp_path / "clips"
    made = runner.invoke(
        app, ["synth", str(clips), "-n", "2", "--frames", "8", "--width", "32", "--height", "32", "--steady", "1"]
    )
    assert made.exit_code == 0, made.output
    common = ["--epochs", "1", "--size", "16", "--seq-len", "4", "--stride", "4", "--batch", "2", "--head", "curve"]
    run = tmp_path / "run"
    options = ["--objective", "relative", "--steady-weight", "3", "--darken-weight", "2", "--darken-level", "5"]
    res = runner.invoke(app, ["train", str(clips), "-o", str(run), *common, *options])
    assert res.exit_code == 0, res.output
    training = json.loads((run / "colonlight-rnn.json").read_text())["training"]
    assert training["steady_weight"] == 3.0 and "weigh 3 x" in training["objective"], training
    assert training["darken_weight"] == 2.0 and "darker than its target costs 2 x" in training["objective"], training
    assert training["darken_level"] == 5.0 and "plus 5 x mean over frames" in training["objective"], training
    assert training["train_undisturbed_sequences"] == training["train_sequences"] == 2, training  # one clip validates
    for extra, named in (
        (["--objective", "relative", "--steady-weight", "0"], "steady weight"),
        (["--steady-weight", "2"], "steady weight"),
        (["--objective", "relative", "--darken-weight", "-1"], "darken weight"),
        (["--darken-weight", "2"], "darken weight"),
        (["--objective", "relative", "--darken-level", "-1"], "darken level"),
        (["--darken-level", "2"], "darken level"),
    ):
        res = runner.invoke(app, ["train", str(clips), "-o", str(tmp_path / "x"), *common, *extra])
        assert res.exit_code == 2 and named in res.output, res.output
        assert not (tmp_path / "x" / "colonlight-rnn.json").exists()


def test_a_clip_that_cannot_be_read_is_left_out_and_named_not_fatal(tmp_path: Path) -> None:
    """One unreadable video among the training clips costs that clip, not the run: its reason reaches the
    caller as it is found, and the card lists it; with no usable clip left the run is an InputError saying so."""
    good = [_flicker_clip(tmp_path / f"c{i}", seed=i) for i in range(3)]
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video")
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    cfg = TrainConfig(size=32, seq_len=8, stride=6, batch=2, epochs=1, lr=1e-3, seed=0)
    heard: list[str] = []
    res = train_model([good[0], broken, good[1]], [empty, good[2]], tmp_path / "run", cfg, on_skip=heard.append)
    assert len(heard) == 2 and "broken.mp4" in heard[0] and "empty.mp4" in heard[1], heard
    assert res.skipped == heard and res.card["training"]["skipped_clips"] == heard
    assert res.card["training"]["train_clips"] == 2 and res.card["training"]["val_clips"] == 1
    assert res.history[0].val_loss is not None and load_weights(res.weights).net is not None
    with pytest.raises(InputError, match=r"2 of 2 clips could not be used"):
        train_model([broken, empty], [], tmp_path / "none", cfg)
