"""Interrupting the commands that write files and have no signal handler of their own (``synth``, ``train``,
``export``; ``evaluate`` and ``demo`` share the same code): real ``colonlight`` processes, real signals.

* SIGKILL mid-clip left ``synth``'s ``.clip.mp4.*.colonlight-tmp.mp4`` (the video's temporary, alive for the
  whole render) in the clip folder, and the rerun, which redid the clip, never removed it; ``demo`` (its input
  clip) and ``train --synthetic`` (its data) the same. A temporary an export or a training run was writing when
  killed stayed likewise.
* SIGTERM killed these commands on the spot: exit -15 with no word, temporaries left, a render pool's semaphores
  reported leaked. Now it stops them as Ctrl-C does: one line, exit 143, nothing half-written, and the rerun
  finishes with the bytes of an uninterrupted run.
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

from colonlight.atomic import TMP_MARK

from ..media import needs_ffmpeg
from ..outputs import tree_bytes

pytestmark = needs_ffmpeg

INTERRUPTED = "error: interrupted; rerun the same command to resume"
SYNTH = ("--frames", "40", "--width", "64", "--height", "48", "-j", "1")


def colonlight(*args: object) -> list[str]:
    exe = Path(sys.executable).parent / "colonlight"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-c", "from colonlight_cli.entry import run; run()"]
    return [*cmd, *map(str, args)]


def run(*args: object) -> None:
    done = subprocess.run(colonlight(*args), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def interrupt_when(args: list[str], ready: Callable[[], bool], signum: int) -> tuple[int, str]:
    """Start ``colonlight ARGS``, send ``signum`` once ``ready()``; exit code and stderr."""
    proc = subprocess.Popen(
        args,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 60
        while not ready():
            assert proc.poll() is None, f"finished before the signal (exit {proc.returncode})"
            assert time.monotonic() < deadline
            time.sleep(0.005)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    return proc.returncode, err


def temporaries(root: Path) -> list[Path]:
    return [p for p in root.rglob(f"*{TMP_MARK}*")]


def with_users_file(out: Path) -> Path:
    out.mkdir(parents=True)
    mine = out / "notes.txt"
    mine.write_text("the user's own\n")
    return mine


@pytest.fixture(scope="module")
def synth_clean(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    out = tmp_path_factory.mktemp("synth") / "clean"
    with_users_file(out)
    run("synth", out, *SYNTH)
    return tree_bytes(out)


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_synth_stopped_mid_clip_then_rerun(tmp_path: Path, synth_clean: dict[str, bytes], signum: int) -> None:
    """Stopped while the clip's video is being written: SIGKILL leaves its temporary, which the rerun removes;
    SIGTERM is one line and exit 143, with nothing left. Either way the rerun gives the clean run's bytes and
    the user's file is untouched."""
    out = tmp_path / "out"
    mine = with_users_file(out)
    code, err = interrupt_when(colonlight("synth", out, *SYNTH), lambda: bool(temporaries(out)), signum)
    if signum == signal.SIGKILL:
        assert code == -signal.SIGKILL and temporaries(out)  # what the next run must clean
    else:
        assert code == 143, err
        assert [line for line in err.splitlines() if line.strip()] == [INTERRUPTED]
        assert not temporaries(out)
    assert not (out / "clip_00000" / "synth.json").exists()  # not marked complete
    run("synth", out, *SYNTH)
    assert not temporaries(out)
    assert tree_bytes(out) == synth_clean
    assert mine.read_text() == "the user's own\n"


def test_synth_workers_stopped_mid_clip_stop_at_once(tmp_path: Path) -> None:
    """``synth -j 2`` stopped by SIGTERM while both workers render: they used to finish the clips they held (the
    parent waited for them, up to a whole clip's render, past ``docker stop``'s grace) and any temporary of a
    worker killed later stayed. Now the workers are killed mid-clip, no clip is marked complete, nothing
    half-written stays, and the rerun renders both."""
    out = tmp_path / "out"
    args = ("-n", "2", "--frames", "120", "--width", "64", "--height", "48", "-j", "2")
    code, err = interrupt_when(colonlight("synth", out, *args), lambda: bool(temporaries(out)), signal.SIGTERM)
    assert code == 143, err
    assert [line for line in err.splitlines() if line.strip()] == [INTERRUPTED]
    assert not temporaries(out)
    assert not list(out.glob("clip_*/synth.json"))  # neither clip was left to finish
    run("synth", out, *args)
    assert not temporaries(out)
    assert len(list(out.glob("clip_*/synth.json"))) == 2


@pytest.fixture(scope="module")
def train_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data = tmp_path_factory.mktemp("train-data")
    run("synth", data, "-n", "3", "--frames", "24", "--width", "48", "--height", "48", "--no-video", "-j", "1")
    return data


def train_args(data: Path, out: Path) -> list[str]:
    clips = sorted(data.glob("clip_*"))
    return colonlight(
        "train",
        *clips[:2],
        "--val",
        clips[2],
        "-o",
        out,
        "--size",
        "16",
        "--epochs",
        "4",
        "--seq-len",
        "3",
        "--batch",
        "2",
    )


def without_timings(files: dict[str, bytes]) -> dict[str, object]:
    """The run's files with the cards' timings and the command (it names the run folder) taken out."""

    def scrub(value: object) -> object:
        if isinstance(value, dict):
            return {k: scrub(v) for k, v in value.items() if k not in ("seconds", "command")}
        if isinstance(value, list):
            return [scrub(v) for v in value]
        return value

    return {
        name: scrub(json.loads(data)) if name.endswith(".json") else data
        for name, data in files.items()
        if not name.startswith(".colonlight")  # the lock file
    }


def test_train_sigterm_mid_run_then_rerun_gives_the_same_weights(train_data: Path, tmp_path: Path) -> None:
    """SIGTERM after the first epoch's state: one line, exit 143; a temporary of a state save cut short by a
    SIGKILL (planted: the window is too short to hit) is removed by the rerun, which resumes and writes the
    weights of an uninterrupted run, byte for byte."""
    clean = tmp_path / "clean"
    run(*train_args(train_data, clean)[1:])
    out = tmp_path / "out"
    mine = with_users_file(out)
    first = out / "checkpoints" / "epoch_001.json"
    code, err = interrupt_when(train_args(train_data, out), first.exists, signal.SIGTERM)
    assert code == 143, err
    assert "Traceback" not in err
    assert [line for line in err.splitlines() if "interrupted" in line] == [INTERRUPTED]
    assert not temporaries(out)
    assert not (out / "colonlight-rnn.safetensors").exists()
    stale = out / "checkpoints" / f".epoch_002.safetensors.k1lled00{TMP_MARK}.safetensors"
    stale.write_bytes(b"half a state")
    run(*train_args(train_data, out)[1:])
    assert not temporaries(out)
    assert mine.read_text() == "the user's own\n"
    mine.unlink()
    assert (out / "colonlight-rnn.safetensors").read_bytes() == (clean / "colonlight-rnn.safetensors").read_bytes()
    assert without_timings(tree_bytes(out)) == without_timings(tree_bytes(clean))


def test_export_removes_its_own_stale_temporaries_only(tmp_path: Path) -> None:
    """An export killed while writing the graph or its sidecar left their temporaries beside ``-o``, in a folder
    of the user's; the next export removes those and nothing else there."""
    out = tmp_path / "models"
    mine = with_users_file(out)
    others = out / f".other.onnx.x1{TMP_MARK}.onnx"  # another output's temporary: not this export's to remove
    others.write_bytes(b"x")
    stale = [out / f".m.onnx.k1lled00{TMP_MARK}.onnx", out / f".m.onnx.json.k1lled01{TMP_MARK}.json"]
    for p in stale:
        p.write_bytes(b"cut short")
    run("export", "-o", out / "m.onnx")
    assert not any(p.exists() for p in stale)
    assert others.exists() and mine.read_text() == "the user's own\n"
    assert sorted(os.listdir(out)) == sorted([others.name, "m.onnx", "m.onnx.json", "notes.txt"])
