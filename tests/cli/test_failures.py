"""How an expected failure ends a command (``colonlight_cli.failures.ends_command``): one line and an exit status,
or, with ``--debug``, the traceback; real ``colonlight`` processes for the command-level cases."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from colonlight_cli.failures import FAILED, USAGE, ends_command

from colonlight import InputError, OutputError

from ..commands import PLAIN_CONSOLE, boxed_text


def colonlight(*args: object) -> tuple[int, str]:
    """Exit code and stderr of ``colonlight ARGS`` run as a real process."""
    proc = subprocess.run(
        [sys.executable, "-m", "colonlight_cli.main", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, **PLAIN_CONSOLE},
    )
    return proc.returncode, proc.stderr


def test_an_error_of_the_kinds_is_one_line_and_the_exit_status(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(typer.Exit) as ended, ends_command(USAGE):
        raise InputError("clip.mp4: no video stream")
    assert ended.value.exit_code == USAGE
    assert ended.value.__cause__ is None and ended.value.__suppress_context__
    assert capsys.readouterr().err.strip() == "error: clip.mp4: no video stream"


def test_debug_shows_the_error_itself_and_other_kinds_pass_through() -> None:
    with pytest.raises(InputError), ends_command(FAILED, debug=True):
        raise InputError("clip.mp4: no video stream")
    with pytest.raises(InputError), ends_command(FAILED, kinds=(OutputError,)):  # not this block's to end
        raise InputError("clip.mp4: no video stream")
    with ends_command(FAILED):  # nothing raised: nothing printed, no exit
        pass


def test_camera_file_error_is_one_line_and_debug_gives_the_traceback(tmp_path: Path) -> None:
    """``enhance --camera`` with a file that cannot be read: a usage error, one line; ``--debug`` now shows the
    traceback there too (it printed the same line before)."""
    missing = tmp_path / "camera.txt"
    code, err = colonlight("enhance", tmp_path, "-o", tmp_path / "out", "--camera", missing)
    assert code == USAGE
    assert "Traceback" not in err and err.count("\n") == 1 and str(missing) in err, err
    code, err = colonlight("enhance", tmp_path, "-o", tmp_path / "out", "--camera", missing, "--debug")
    assert code != 0 and "Traceback" in err and "InputError" in err, err


def test_export_to_a_folder_that_is_a_file_names_the_output(tmp_path: Path) -> None:
    pytest.importorskip("onnx", reason="the onnx extra is not installed")
    blocker = tmp_path / "file"
    blocker.write_text("the user's own\n")
    out = blocker / "m.onnx"
    code, err = colonlight("export", "-o", out)
    assert code == FAILED
    assert "Traceback" not in err and err.count("\n") == 1, err
    # named before the graph is built, for what it is (it was mkdir's bare "File exists")
    assert err == f"error: {out}: {blocker} is a file, not a folder\n", err
    assert blocker.read_text() == "the user's own\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_train_into_a_name_too_long_is_a_usage_error(tmp_path: Path) -> None:
    """``train -o`` past NAME_MAX: ``Path.exists`` raised ENAMETOOLONG from the output check, a traceback."""
    code, err = colonlight("train", tmp_path / "clip.mp4", "-o", tmp_path / ("x" * 300), "--epochs", "1")
    assert code == USAGE
    assert "Traceback" not in err and "cannot be used: File name too long" in boxed_text(err), err
    assert list(tmp_path.iterdir()) == []
