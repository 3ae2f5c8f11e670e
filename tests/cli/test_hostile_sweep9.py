"""Hostile-input sweep 9: ``colonlight train``, ``export`` and ``evaluate`` on a user's clips, with tiny real files
(tests/engine/test_hostile_sweep9.py has the engine side).

Defects found: an OUTPUT (or exported file) with ``[/]`` in its name was read as rich markup, a traceback after
everything was written (``[bold]`` vanished from the name shown); ``train --seed -1``, ``--seed 2**32`` and
``--lr 1e300`` were tracebacks; a ``--name`` too long for its temporary trained an epoch, then failed naming the
temporary; ``export -o ""`` was a traceback; an evaluated folder whose name is not UTF-8 was a traceback while the
report was written, after the whole evaluation.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from colonlight import DEFAULT_WEIGHTS

from ..commands import invoke_cli as invoke
from ..commands import run_colonlight

TINY = ["--size", "16", "--seq-len", "3", "--batch", "1", "--epochs", "1"]


def frames(folder: Path, n: int = 5, side: int = 32, seed: int = 0) -> Path:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        # cv2.imwrite takes a str path only: one with a name's surrogate escapes crashed the process
        ok, png = cv2.imencode(".png", rng.integers(0, 255, (side, side, 3), dtype=np.uint8))
        assert ok
        (folder / f"{i:05d}.png").write_bytes(png.tobytes())
    return folder


@pytest.mark.parametrize(("option", "value"), [("--seed", "-1"), ("--seed", str(2**32)), ("--lr", "1e300")])
def test_seeds_and_learning_rates_no_run_can_use_are_usage_errors(tmp_path: Path, option: str, value: str) -> None:
    clip = frames(tmp_path / "a")
    code, output = invoke("train", str(clip), "-o", str(tmp_path / "run"), *TINY, option, value)
    assert code == 2 and option in output
    assert not (tmp_path / "run").exists()


def test_a_folder_without_clips_is_named(tmp_path: Path) -> None:
    empty = tmp_path / "no clips here"
    empty.mkdir()
    code, output = invoke("train", str(empty), "-o", str(tmp_path / "run"), *TINY)
    assert code == 2 and f"no clips found in {empty}" in output, output
    assert not (tmp_path / "run").exists(), "a refused run left a folder holding only its lock file"


@pytest.mark.parametrize(
    "options",
    [["--steady-weight", "4"], ["--frame-steps", "0"], ["--method", "nope"]],
    ids=["steady-weight-unsupervised", "frame-step-0", "unknown-method"],
)
def test_options_no_run_can_use_leave_no_run_folder(tmp_path: Path, options: list[str]) -> None:
    clip = frames(tmp_path / "a")
    code, output = invoke("train", str(clip), "-o", str(tmp_path / "run"), *TINY, *options)
    assert code == 2 and "Invalid value" in output, output
    assert not (tmp_path / "run").exists()


def test_a_name_too_long_for_its_files_is_refused_before_training(tmp_path: Path) -> None:
    clip = frames(tmp_path / "a")
    code, output = invoke("train", str(clip), "-o", str(tmp_path / "run"), *TINY, "--name", "n" * 191)
    assert code == 2 and "--name" in output and "at most 190 bytes" in output
    assert not (tmp_path / "run").exists()


def test_a_run_folder_named_like_markup_is_shown_as_it_is(tmp_path: Path) -> None:
    data = [str(frames(tmp_path / "a")), str(frames(tmp_path / "b", seed=1))]
    run = tmp_path / "run[/]x[bold]"
    code, output = invoke("train", *data, "-o", str(run), *TINY)
    assert code == 0, output
    assert f"weights: {run}/colonlight-rnn.safetensors" in output
    assert (run / "colonlight-rnn.safetensors").is_file()


def test_export_into_the_working_folder_itself_is_one_line(tmp_path: Path) -> None:
    code, output = invoke("export", "-w", str(DEFAULT_WEIGHTS), "-o", "")
    assert code == 1 and "error: .: a folder is in the way of the export" in output


def test_an_export_named_like_markup_is_shown_as_it_is(tmp_path: Path) -> None:
    pytest.importorskip("onnxscript", reason="the export extra (onnxscript) is not installed")
    out = tmp_path / "m[/]x.onnx"
    code, output = invoke("export", "-w", str(DEFAULT_WEIGHTS), "-o", str(out))
    assert code == 0, output
    assert f"wrote {out} (" in output and f"wrote {out}.json" in output


def test_evaluating_a_folder_whose_name_is_not_utf8_writes_its_report(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="the evaluate extra is not installed")
    name = os.fsdecode(b"clip\xff")
    clip = frames(tmp_path / name, n=4, side=64)
    out = tmp_path / "report"
    code, output = run_colonlight("evaluate", str(clip), "-o", str(out), "-m", "none", "--no-colmap", "--no-tracker")
    assert code == 0, output
    assert "clip\\udcff" in (out / "clips.csv").read_text(encoding="utf-8")
    assert (out / "report.html").is_file()
