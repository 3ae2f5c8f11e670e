"""A third hostile-input sweep, of ``train``, ``synth``, ``evaluate``, ``export`` and ``demo``, through the CLI
on real files: a resumed run asked for other settings or fewer epochs than it has, a damaged training state, a
learning rate that diverges, a run folder that is a file, a ``--name`` that is a path, clips re-rendered into a
folder that held another, a clip named twice to ``evaluate``, checkpoints that are a pickled model, an export
that would overwrite its own weights' card. Each is a usage error or one line naming the file and the cause;
nothing already written is lost or left holding NaN.

The commands run in-process (typer's CliRunner: seconds, not a torch import per case); an expected failure that
reaches the entry point as a ``ColonlightError`` is shown as ``colonlight_cli.main.run`` shows it, one line.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight import ColonlightError

from ..commands import PLAIN_CONSOLE
from ..media import make_clip, needs_ffmpeg

pytestmark = [needs_ffmpeg, pytest.mark.timeout(120)]

SHIPPED = Path(__file__).resolve().parents[2] / "colonlight" / "weights" / "colonlight-rnn"
#: A training run of a second or less: 12-frame clips, 16 px, windows of 4.
BASE = ("--fps", "0", "--seq-len", "4", "--stride", "4", "--batch", "2")
TINY = ("--epochs", "1", "--size", "16", *BASE)


def colonlight(*args: str) -> tuple[int, str]:
    """Exit code and output of ``colonlight ARGS``, as the console script gives them: an expected failure (a
    ColonlightError) is one ``error:`` line and exit 1; anything else escaping is a bug (the test fails)."""
    result = CliRunner().invoke(app, list(args), env=PLAIN_CONSOLE)
    if isinstance(result.exception, ColonlightError):
        return 1, result.output + f"error: {result.exception}\n"
    assert result.exception is None or isinstance(result.exception, SystemExit), result.output
    assert "Traceback" not in result.output
    return result.exit_code, result.output


def error_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if line.startswith("error:")]


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("clips")
    make_clip(d / "a.mp4", 12, size=(64, 48))
    return d


@pytest.fixture(scope="module")
def run(clips: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 2-epoch run (head gamma, 16 px)."""
    out = tmp_path_factory.mktemp("run") / "run"
    code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(out), "--epochs", "2", "--size", "16", *BASE)
    assert code == 0, output
    return out


def test_a_resume_with_other_settings_or_fewer_epochs_is_refused_and_changes_nothing(run: Path, clips: Path) -> None:
    """``--head curve`` over a gamma run's state was a RuntimeError traceback (shapes of out_linear); ``--size 24``
    trained on, under a card saying every epoch had been at 24 px; ``--epochs 1`` over 2 saved wrote epoch 2's
    weights under a card saying 1 epoch. Each is one line naming the state, and the run's files stay as they were."""
    before = snapshot(run)
    state = run / "checkpoints" / "epoch_002"
    cases = [
        (("--epochs", "3", "--head", "curve"), "--head 'gamma' (now 'curve')"),
        (("--epochs", "3", "--size", "24"), "--size 16 (now 24)"),
        (("--epochs", "1", "--size", "16"), "has trained 2 epochs, more than --epochs 1"),
    ]
    for changed, says in cases:
        code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(run), *BASE, *changed)
        assert code == 1, output
        lines = error_lines(output)
        assert len(lines) == 1 and lines[0].startswith(f"error: {state}: ") and says in lines[0], output
    assert snapshot(run) == before


@pytest.mark.parametrize(
    ("damage", "names", "says"),
    [
        ("truncate", "epoch_002.safetensors", "unreadable training state (Error while deserializing header"),
        ("list", "epoch_002.json", "unreadable training state (not a JSON object)"),
        ("deep", "epoch_002.json", "unreadable training state (JSON nested too deep to decode)"),
    ],
)
def test_a_damaged_training_state_is_one_line(run: Path, clips: Path, tmp_path: Path, damage: str, names: str,
                                              says: str) -> None:  # fmt: skip
    """A state cut short (a copy of the run interrupted), not a JSON object or nested too deep for the JSON
    decoder was a SafetensorError, TypeError or RecursionError traceback on resume."""
    copy = tmp_path / "run"
    for rel, data in snapshot(run).items():
        (copy / rel).parent.mkdir(parents=True, exist_ok=True)
        (copy / rel).write_bytes(data)
    damaged = copy / "checkpoints" / names
    damaged.write_bytes({"truncate": damaged.read_bytes()[:100], "list": b"[]", "deep": b"[" * 100_000}[damage])
    code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(copy), "--epochs", "3", "--size", "16", *BASE)
    assert code == 1, output
    lines = error_lines(output)
    assert len(lines) == 1 and lines[0].startswith(f"error: {damaged}: {says}"), output


def test_a_learning_rate_that_diverges_writes_no_nan_weights(clips: Path, tmp_path: Path) -> None:
    """``--lr 1e30`` trained to NaN, wrote NaN weights and a card, and exited 0 (the weights then refused to
    load); Zero-DCE's FloatingPointError was a traceback. Both stop in one line with nothing written."""
    for method in ("rnn", "zerodce"):
        out = tmp_path / method
        code, output = colonlight(
            "train", str(clips / "a.mp4"), "-o", str(out), *TINY, "--lr", "1e30", "--method", method
        )
        assert code == 1, output
        lines = error_lines(output)
        assert len(lines) == 1 and "diverged at epoch 1" in lines[0] and "try a lower --lr" in lines[0], output
        assert not out.exists() or not list(out.rglob("*.safetensors")), output


def test_train_refuses_an_output_it_cannot_use_and_a_name_that_is_a_path(clips: Path, tmp_path: Path) -> None:
    """An OUTPUT that is a file (or under one) was a NotADirectoryError traceback after the first epoch;
    ``--name ../x`` wrote the weights outside OUTPUT and ``--name ''`` as a hidden ``.safetensors``."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    for out, says in ((afile, "the output path is a file"), (afile / "run", f"{afile} is a file")):
        code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(out), *TINY)
        assert code == 2 and "--output" in output and says in output, output
    assert afile.read_text() == "x"
    for name in ("../x", "", ".hidden"):
        code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(tmp_path / "run"), *TINY, "--name", name)
        assert code == 2 and "--name" in output and "plain file name" in output, (name, output)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_zerodce_with_no_usable_frame_is_one_line(tmp_path: Path) -> None:
    """Every clip unreadable: train_zerodce's ValueError("no training frames") was a traceback."""
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    code, output = colonlight("train", str(empty), "-o", str(tmp_path / "run"), *TINY, "--method", "zerodce")
    assert code == 1, output
    lines = error_lines(output)
    assert lines == [
        f"error: no training frames: 1 of 1 clips could not be used (the first: {empty}: empty file (0 bytes))"
    ]


def test_synth_rerendered_into_a_folder_leaves_nothing_of_the_old_clip(tmp_path: Path) -> None:
    """A clip rendered with ``--no-video`` was kept as complete when its video was asked for (no clip.mp4);
    a 3-frame clip rendered over a 6-frame one left frames 3..5 of the old one in frames/, clean/ and depth/."""
    out = tmp_path / "s"
    small = ("--width", "32", "--height", "32", "-j", "1")
    assert colonlight("synth", str(out), "--frames", "6", "--no-video", *small)[0] == 0
    code, output = colonlight("synth", str(out), "--frames", "6", "--video", *small)
    assert code == 0, output
    clip = out / "clip_00000"
    assert (clip / "clip.mp4").is_file()
    assert json.loads((clip / "synth.json").read_text())["written"]["video"] is True
    code, output = colonlight("synth", str(out), "--frames", "3", "--no-video", *small)
    assert code == 0, output
    for folder in ("frames", "clean", "depth"):
        assert sorted(p.name for p in (clip / folder).iterdir()) == ["000000.png", "000001.png", "000002.png"]
    assert not (clip / "clip.mp4").exists()  # the 6-frame clip's video is not this clip's


def test_evaluate_takes_each_clip_once_under_a_name_of_its_own(tmp_path: Path) -> None:
    """``a.mp4 a.mp4`` was evaluated twice and counted twice in the summary; ``x/a.mp4`` beside ``a.mp4`` gave
    two rows named ``a``."""
    a = make_clip(tmp_path / "a.mp4", 8, size=(64, 48))
    make_clip(tmp_path / "x" / "a.mp4", 8, size=(64, 48), first_index=50)
    out = tmp_path / "out"
    args = ("--methods", "none", "--no-colmap", "--no-tracker", "--no-oracles", "-q")
    code, output = colonlight("evaluate", str(a), str(a), str(tmp_path / "x"), "-o", str(out), *args)
    assert code == 0, output
    record = json.loads((out / "results.json").read_text())
    assert [c["name"] for c in record["clips"]] == ["a", "a-2"]


def test_evaluate_refuses_a_negative_seed_and_a_single_frame(tmp_path: Path) -> None:
    """``--seed0 -5 --synthetic 1`` was numpy's "expected non-negative integer" traceback after the output
    folder was made; ``--max-frames 1`` failed every clip with "only 1 frame(s)"."""
    out = tmp_path / "out"
    for flag, value in (("--seed0", "-5"), ("--max-frames", "1")):
        code, output = colonlight("evaluate", "--synthetic", "1", "-o", str(out), "--no-colmap", flag, value)
        assert code == 2 and flag in output, output
        assert not out.exists()


@pytest.mark.parametrize(
    ("content", "says"),
    [
        ("model", "it holds a pickled object (tests.cli.test_hostile_sweep3.Tiny), not only tensors"),
        ("random", "its bytes are not a checkpoint torch can read"),
    ],
)
def test_a_pth_that_is_a_pickled_model_or_noise_says_which(tmp_path: Path, content: str, says: str) -> None:
    """torch's first line ("Weights only load failed. In PyTorch 2.6, we changed the default ... Re-running
    `torch.load` with `weights_only` set to `False`", terminal escapes included) said the same of both and
    suggested unpickling a file of unknown origin."""
    pth = tmp_path / "w.pth"
    if content == "model":
        torch.save(Tiny(), pth)
    else:
        pth.write_bytes(bytes(range(256)) * 8)
    code, output = colonlight("export", "-o", str(tmp_path / "m.onnx"), "-w", str(pth))
    assert code == 1, output
    lines = error_lines(output)
    assert len(lines) == 1 and lines[0].startswith(f"error: {pth}: not a readable PyTorch state dict ({says}"), output
    assert "weights_only" not in output and "\\x1b" not in output


class Tiny(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.lin = torch.nn.Linear(2, 2)


def test_export_never_overwrites_the_weights_or_a_card(tmp_path: Path) -> None:
    """``-o wd/colonlight-rnn`` wrote its sidecar over ``wd/colonlight-rnn.json``, the weights' card (the weights
    could not be loaded after), ``-o W.safetensors -w W.safetensors`` the weights themselves; a sidecar path
    that is a folder failed after the graph was written."""
    wd = tmp_path / "wd"
    wd.mkdir()
    for suffix in (".safetensors", ".json"):
        (wd / f"colonlight-rnn{suffix}").write_bytes(SHIPPED.with_suffix(suffix).read_bytes())
    before = snapshot(wd)
    weights = str(wd / "colonlight-rnn.safetensors")
    (wd / "m.onnx.json").mkdir()
    cases = [
        (wd / "colonlight-rnn", wd / "colonlight-rnn.json", "would overwrite the checkpoint being exported"),
        (wd / "colonlight-rnn.safetensors", wd / "colonlight-rnn.safetensors", "would overwrite the checkpoint"),
        (wd / "m.onnx", wd / "m.onnx.json", "a folder is in the way of the export"),
    ]
    for out, named, says in cases:
        code, output = colonlight("export", "-o", str(out), "-w", weights, "--model-size", "16")
        assert code == 1, output
        lines = error_lines(output)
        assert len(lines) == 1 and lines[0].startswith(f"error: {named}: {says}"), output
    (wd / "m.onnx.json").rmdir()
    assert snapshot(wd) == before
    (wd / "x.safetensors").write_bytes(b"")  # the card of other weights beside is not overwritten either
    code, output = colonlight("export", "-o", str(wd / "x.json"), "-w", weights, "--model-size", "16")
    assert code == 1 and f"error: {wd / 'x.json'}: would overwrite the model card of" in output, output


def test_demo_to_an_output_that_is_a_file_is_one_line(tmp_path: Path) -> None:
    """A NotADirectoryError traceback before."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    for out, says in (
        (afile, "the output path is a file, not a folder"),
        (afile / "d", "a parent of the output folder is a file"),
    ):
        code, output = colonlight("demo", "-o", str(out), "--frames", "10", "-q")
        assert code == 2, output
        assert output.strip() == f"error: {out}: {says}", output
    assert afile.read_text() == "x"


def _interrupted_synth(folder: Path, ready: Callable[[int], bool]) -> tuple[int, str]:
    """Exit code and stderr of ``colonlight synth`` (through the console script's entry point), sent SIGINT once
    ``ready(pid)``."""
    script = "from colonlight_cli.entry import run; run()"
    size = ("--frames", "4", "--width", "48", "--height", "40")
    proc = subprocess.Popen(
        [sys.executable, "-c", script, "synth", str(folder), "-n", "5000", *size, "-j", "1"],
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a background shell ignores it
    )
    try:
        deadline = time.monotonic() + 60
        while not ready(proc.pid):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.002)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()  # no renderer left running if the test fails
        proc.wait()
    return proc.returncode, err


def test_ctrl_c_in_a_command_without_its_own_handler_says_how_to_go_on(tmp_path: Path) -> None:
    """typer turns Ctrl-C into a silent exit 130; the console script says what happened, once."""
    folder = tmp_path / "s"
    # a clip written: the interrupt lands in the command
    code, err = _interrupted_synth(folder, lambda _pid: bool(list(folder.glob("*/synth.json"))))
    assert code == 130
    assert err.strip().splitlines()[-1] == "error: interrupted; rerun the same command to resume"
    assert "Traceback" not in err


def test_frame_steps_are_trained_on_and_recorded_and_a_bad_list_is_a_usage_error(clips: Path, tmp_path: Path) -> None:
    """``--frame-steps 1,2`` over a 12-frame clip, windows of 4 at stride 4: 3 windows at step 1, 2 at step 2."""
    out = tmp_path / "run"
    code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(out), *TINY, "--frame-steps", "2,1")
    assert code == 0, output
    training = json.loads((out / "colonlight-rnn.json").read_text())["training"]
    assert training["frame_steps"] == [1, 2] and training["train_sequences"] == 5, training
    for bad in ("0", "1,x", ""):
        code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(tmp_path / "x"), *TINY, "--frame-steps", bad)
        assert code == 2 and "frame steps" in output, output


def test_a_second_run_into_a_folder_another_run_trains_in_is_refused_and_the_first_goes_on(
    clips: Path, tmp_path: Path
) -> None:
    """Two runs into one OUTPUT overwrote each other's epoch states and weights. A real run holds the folder; a
    second is one line naming its pid, writes nothing, and once the first is killed (``kill -9``: the kernel
    drops the lock) a rerun resumes from the epochs the first saved."""
    out = tmp_path / "run"
    script = "from colonlight_cli.main import run; run()"
    argv = [sys.executable, "-c", script, "train", str(clips / "a.mp4"), "-o", str(out), *BASE, "--size", "16"]
    first = subprocess.Popen([*argv, "--epochs", "100000"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 90
        while not list((out / "checkpoints").glob("epoch_*.json")):  # it holds the folder and has saved an epoch
            assert first.poll() is None and time.monotonic() < deadline, first.stderr.read() if first.stderr else ""
            time.sleep(0.05)
        code, output = colonlight("train", str(clips / "a.mp4"), "-o", str(out), *BASE, "--size", "16")
        assert code == 1, output
        lines = error_lines(output)
        assert len(lines) == 1 and f"in use by colonlight pid {first.pid}" in lines[0] and str(out) in lines[0]
        assert not (out / "colonlight-rnn.safetensors").exists()  # the second wrote no weights
        assert first.poll() is None  # and the first trains on
    finally:
        first.kill()
        first.wait()
    saved = sorted((out / "checkpoints").glob("epoch_*.json"))[-1]
    epochs = int(saved.stem.split("_")[1]) + 1
    code, output = colonlight(
        "train", str(clips / "a.mp4"), "-o", str(out), *BASE, "--size", "16", "--epochs", str(epochs)
    )
    assert code == 0, output
    assert json.loads((out / "colonlight-rnn.json").read_text())["training"]["epochs"] == epochs


def _has_loaded(pid: int, library: str) -> bool:
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs Linux's /proc to see the imports happen")
@pytest.mark.parametrize("library", ["_multiarray_umath", "cv2"])
def test_ctrl_c_while_the_command_loads_is_one_line_too(tmp_path: Path, library: str) -> None:
    """A Ctrl-C in the first half second, while the command line's modules load, was a KeyboardInterrupt
    traceback from an import; the console script's entry point (``colonlight_cli.entry``) catches it there too.
    The interrupt is sent once the process has loaded ``library`` (numpy's core, then OpenCV), so it lands while
    the command's modules load (or, on a fast machine, in the command, which says the same)."""
    code, err = _interrupted_synth(tmp_path / "s", lambda pid: _has_loaded(pid, library))
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert code == 130 and err.strip().splitlines()[-1].startswith("error: interrupted"), err
