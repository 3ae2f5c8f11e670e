"""Hostile-input sweep 9, engine side: training states, training settings and a synthetic clip's clean frames
(tests/cli/test_hostile_sweep9.py has the commands).

Defects found: a resume after epoch 999 went back to ``epoch_999`` (``epoch_1000`` sorts before it by name); a
saved state with a negative epoch, a negative or 33-bit seed and a learning rate near 1e300 were tracebacks; clean
frames of another size than their clip were stretched and scored as the truth, and fewer of them than frames were
dropped without a word.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from colonlight import InputError, OptionError, TrainConfig, train_model
from colonlight.evaluation.clips import load_synthetic_clip
from colonlight.synth import SynthConfig, write_clip
from colonlight.train import latest_state


def test_resume_takes_the_highest_epoch_not_the_last_name(tmp_path: Path) -> None:
    states = tmp_path / "checkpoints"
    states.mkdir()
    for epoch in (998, 999, 1000, 1001):
        (states / f"epoch_{epoch:03d}.json").write_text("{}")
    (states / "epoch_\u00b2.json").write_text("{}")  # a digit int() cannot read is no epoch
    assert latest_state(tmp_path) == states / "epoch_1001"


@pytest.mark.parametrize("epoch", [-3, 0, 1.5, True, "1", None])
def test_a_state_whose_epoch_is_no_whole_number_is_one_line(tmp_path: Path, epoch: object) -> None:
    states = tmp_path / "checkpoints"
    states.mkdir()
    (states / "epoch_001.json").write_text(json.dumps({"epoch": epoch}))
    with pytest.raises(InputError, match=r"epoch_001\.json: unreadable training state \(its epoch is not"):
        train_model([], [], tmp_path, TrainConfig(size=16, seq_len=3, epochs=2))


@pytest.mark.parametrize(("field", "value"), [("seed", -1), ("seed", 2**32), ("seed", True), ("lr", 1e300)])
def test_seeds_and_learning_rates_no_run_can_use_are_option_errors(field: str, value: object) -> None:
    with pytest.raises(OptionError, match=field.replace("lr", "learning rate")):
        TrainConfig(**{field: value})  # type: ignore[arg-type]


def test_the_largest_seed_and_learning_rate_are_taken() -> None:
    cfg = TrainConfig(seed=2**32 - 1, lr=1e30)
    assert (cfg.seed, cfg.lr) == (2**32 - 1, 1e30)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cfg = SynthConfig.sample(np.random.default_rng(3), width=48, height=48, n_frames=4)
    return write_clip(tmp_path_factory.mktemp("clip") / "c", cfg, 3, video=False, frames=True)


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_clean_frames_of_another_size_fail_the_clip(synthetic: Path, tmp_path: Path) -> None:
    clip = _copy(synthetic, tmp_path / "c")
    for path in sorted((clip / "clean").iterdir()):
        cv2.imwrite(str(path), cv2.resize(cv2.imread(str(path)), (40, 30)))
    with pytest.raises(InputError, match=r"000000\.png: clean frame of 40x30, the clip's frames are 48x48"):
        load_synthetic_clip(clip)


def test_fewer_clean_frames_than_frames_fail_the_clip(synthetic: Path, tmp_path: Path) -> None:
    clip = _copy(synthetic, tmp_path / "c")
    sorted((clip / "clean").iterdir())[-1].unlink()
    with pytest.raises(InputError, match=r"clean: 3 clean frame\(s\) for the clip's 4 frames"):
        load_synthetic_clip(clip)


def test_matching_clean_frames_are_read_as_before(synthetic: Path) -> None:
    clip = load_synthetic_clip(synthetic, max_frames=3)
    assert clip.clean is not None and len(clip.clean) == len(clip.frames) == 3
    first = cv2.cvtColor(cv2.imread(str(sorted((synthetic / "clean").iterdir())[0])), cv2.COLOR_BGR2RGB)
    assert np.array_equal(clip.clean[0], first)
