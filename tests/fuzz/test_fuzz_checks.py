"""The fuzz suite's checks can fail: each kind of half-written or noisy output is caught on a real batch's output."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from colonlight.atomic import TMP_MARK

from .checks import check_batch
from .test_fuzz_cli import enhance_args, run_in_process


def cut_frame(out: Path, console: str) -> str:
    frame = out / "good" / "frames" / "000003.png"
    frame.write_bytes(frame.read_bytes()[:100])
    return console


def leave_temporary(out: Path, console: str) -> str:
    (out / "good" / "frames" / f".000099.png.x{TMP_MARK}.png").write_bytes(b"")
    return console


def lose_gammas(out: Path, console: str) -> str:
    (out / "good" / "gammas.json").unlink()
    return console


def miscount(out: Path, console: str) -> str:
    path = out / "good" / "gammas.json"
    gammas = json.loads(path.read_text())
    gammas["frame_count"] += 1
    path.write_text(json.dumps(gammas))
    return console


def traceback_shown(out: Path, console: str) -> str:
    return console + 'Traceback (most recent call last):\n  File "x.py", line 1\n'


def stray_file(out: Path, console: str) -> str:
    (out / "good" / "half.bin").write_bytes(b"\0")
    return console


@pytest.mark.parametrize("spoil", [cut_frame, leave_temporary, lose_gammas, miscount, traceback_shown, stray_file])
def test_checks_catch_spoiled_outputs(
    seeds: dict[str, Path], tmp_path: Path, spoil: Callable[[Path, str], str]
) -> None:
    inputs = tmp_path / "in"
    inputs.mkdir()
    shutil.copyfile(seeds["mkv-audio"], inputs / "good.mkv")
    out = tmp_path / "out"
    code, console = run_in_process(enhance_args([inputs], out, video=False))
    clips = {"good": inputs / "good.mkv"}
    check_batch(out, console, code, clips, False, must_succeed={"good"})  # sound as written
    console = spoil(out, console)
    with pytest.raises(AssertionError):
        check_batch(out, console, code, clips, False, must_succeed={"good"})
