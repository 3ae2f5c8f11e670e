"""The fuzz suite's properties, checked on what a real run left: its console text, its output folder, its memory.

"Complete" is what ``colonlight.pipeline`` and ``colonlight.batch`` promise: a clip is done exactly when its
``gammas.json`` exists, and then every output it lists is whole (``frame_count`` frames, each a readable image of
one size, ``times.txt``/``rgb.txt`` with a line per frame, ``enhanced.mp4`` with as many frames), matching its
``done`` manifest entry. A failed clip has a ``failed`` entry with a one-line reason naming the file, and leaves
nothing behind (no frame, no video, no temporary, no folder). Nowhere a traceback.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import cv2
import numpy as np

from colonlight.atomic import TMP_MARK
from colonlight.discovery import OUTPUT_MARKER

T = TypeVar("T")

#: Words that only a bug puts in front of a user: an exception's traceback or the batch's "internal error".
BUG_MARKS = ("Traceback (most recent call last)", "internal error")
CLIP_FILES = {"gammas.json", "times.txt", "rgb.txt", "enhanced.mp4", "frames"}


class Hang(AssertionError):
    """A case ran past its time bound."""


def bounded(fn: Callable[[], T], seconds: float, what: str) -> T:
    """``fn()`` in a thread, failing with :class:`Hang` if it has not returned after ``seconds`` (the thread is
    left behind, a daemon: a hung decoder cannot be stopped from Python)."""
    box: dict[str, Any] = {}

    def run() -> None:
        try:
            box["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box["error"] = exc

    t = threading.Thread(target=run, daemon=True, name="fuzz-case")
    t.start()
    t.join(seconds)
    if t.is_alive():
        raise Hang(f"{what} did not finish within {seconds:g} s")
    if "error" in box:
        raise box["error"]
    return box["value"]


def no_bug_marks(text: str, where: str) -> None:
    for mark in BUG_MARKS:
        assert mark not in text, f"{where} shows {mark!r}:\n{text[-3000:]}"


def temporaries(root: Path) -> list[Path]:
    return [p for p in Path(root).rglob("*") if TMP_MARK in p.name]


def read_image(path: Path) -> np.ndarray:
    image = cv2.imdecode(np.fromfile(str(path), np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None, f"{path} is not a whole image"
    return image


def video_frames(path: Path) -> int:
    import av

    with av.open(str(path)) as c:
        return sum(1 for _ in c.decode(video=0))


def check_complete_clip(clip_dir: Path, video: bool) -> dict[str, Any]:
    """Everything a done clip lists is there and whole; returns its gammas.json."""
    assert (clip_dir / "gammas.json").is_file(), f"{clip_dir}: a done clip without a gammas.json"
    gammas = json.loads((clip_dir / "gammas.json").read_text(encoding="utf-8"))
    n = gammas["frame_count"]
    assert n >= 2 and len(gammas["frames"]) == n, f"{clip_dir}: frame_count {n}, {len(gammas['frames'])} records"
    assert [f["index"] for f in gammas["frames"]] == list(range(n)), f"{clip_dir}: frame indices not 0..{n - 1}"
    frames = sorted((clip_dir / "frames").iterdir())
    assert [p.name for p in frames] == [f"{i:06d}.png" for i in range(n)], f"{clip_dir}: frames {frames[:5]}..."
    shapes = {read_image(p).shape for p in frames}
    assert len(shapes) == 1, f"{clip_dir}: frames of several sizes {shapes}"
    assert len((clip_dir / "times.txt").read_text().splitlines()) == n
    assert len((clip_dir / "rgb.txt").read_text().splitlines()) == n + 3
    if video:
        assert video_frames(clip_dir / "enhanced.mp4") == n, f"{clip_dir}: enhanced.mp4 is not {n} frames"
    else:
        assert not (clip_dir / "enhanced.mp4").exists()
    assert {p.name for p in clip_dir.iterdir()} <= CLIP_FILES, f"{clip_dir}: {sorted(os.listdir(clip_dir))}"
    return gammas


def check_nothing_left(clip_dir: Path) -> None:
    """A failed clip leaves nothing: no frame, no video, no listing, no temporary, not even its folder."""
    left = sorted(str(p.relative_to(clip_dir)) for p in clip_dir.rglob("*")) if clip_dir.exists() else []
    assert not clip_dir.exists(), f"{clip_dir}: a failed clip left {left[:8]}"


def check_batch(
    out: Path, console: str, exit_code: int, clips: dict[str, Path], video: bool, must_succeed: set[str]
) -> dict[str, dict[str, Any]]:
    """The properties of a finished ``colonlight enhance`` of ``clips`` (name -> source) into ``out``.

    Returns the manifest's entries by clip name.
    """
    no_bug_marks(console, "the console")
    assert exit_code in (0, 1), f"exit {exit_code}:\n{console[-3000:]}"
    assert not temporaries(out), f"temporaries left: {temporaries(out)}"
    empty = [p for p in out.rglob("*") if p.is_dir() and not any(p.iterdir())]
    assert not empty, f"empty folders left: {empty}"
    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    entries = {e["clip"]: e for e in manifest["clips"]}
    assert set(entries) == set(clips), f"manifest clips {sorted(entries)} != {sorted(clips)}"
    assert {p.name for p in out.iterdir()} <= {*clips, "manifest.json", OUTPUT_MARKER}, sorted(os.listdir(out))
    for name, source in clips.items():
        entry = entries[name]
        assert entry["status"] in ("done", "failed"), entry
        if entry["status"] == "done":
            gammas = check_complete_clip(out / name, video)
            assert entry["frames"] == gammas["frame_count"], (entry, gammas["frame_count"])
            assert bool(entry.get("truncated")) == bool(gammas.get("truncated")), entry
            if entry.get("truncated"):
                assert any(ln.startswith("warning") and name in ln for ln in console.splitlines()), console
        else:
            assert name not in must_succeed, f"{name} failed: {entry.get('error')}"
            error = entry.get("error", "")
            assert error.startswith(str(source)) and "\n" not in error, f"not one line naming the file: {error!r}"
            no_bug_marks(error, f"{name}'s error")
            lines = [ln for ln in console.splitlines() if ln.startswith("failed")]
            assert len(lines) == 1 and source.name in lines[0], f"one 'failed' line expected:\n{console}"
            check_nothing_left(out / name)
    assert exit_code == (1 if any(e["status"] == "failed" for e in entries.values()) else 0), (exit_code, entries)
    return entries


# ------------------------------------------------------------------------------------ a real process, measured

_LAUNCHER = (
    "import os, subprocess, sys\n"
    "p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
    "_, status, usage = os.wait4(p.pid, 0)\n"
    "sys.stdout.write(f'{os.waitstatus_to_exitcode(status)} {usage.ru_maxrss}')\n"
)


def run_measured(cmd: list[str], timeout: float) -> tuple[int, str, int]:
    """Run ``cmd`` in its own process group; its exit code, stderr and peak RSS in bytes. Hang (the whole group
    killed) past ``timeout``. A tiny launcher forks it, as Linux carries a process's peak RSS across exec (a child
    forked straight from pytest would report pytest's size)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _LAUNCHER, *cmd], stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True
    )
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise Hang(f"{' '.join(cmd)} did not finish within {timeout:g} s") from None
    code, maxrss_kib = (int(x) for x in stdout.split())
    return code, stderr.decode(errors="replace"), maxrss_kib * 1024
