"""The ``colonlight`` command as a real process, for the tests that need one (exit codes, signals, memory, a second
process, what a terminal shows), or in this process for the rest: how it is run and in what environment, and how
its output is read, decided here once."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

#: A wide, colourless console: rich neither wraps an error line nor colours it, so a test can match it whole.
PLAIN_CONSOLE = {"COLUMNS": "400", "NO_COLOR": "1", "TERM": "dumb"}


def colonlight_command(*args: object) -> list[str]:
    """``colonlight ARGS``: the installed console script where there is one (what a user runs), else the module."""
    exe = Path(sys.executable).parent / "colonlight"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "colonlight_cli.main"]
    return [*cmd, *map(str, args)]


def colonlight_env() -> dict[str, str]:
    """This environment without the user's ``COLONLIGHT_*`` settings, on the CPU, with unbuffered output: a process
    under test runs with its defaults and says what it does as it does it."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("COLONLIGHT_")}
    env.update({"COLONLIGHT_DEVICE": "cpu", "PYTHONUNBUFFERED": "1"})
    return env


def run_colonlight(
    *args: str, env: dict[str, str] | None = None, cwd: Path | None = None, timeout: float = 240
) -> tuple[int, str]:
    """Run ``python -m colonlight_cli.main ARGS`` on a :data:`PLAIN_CONSOLE` (``env`` added); its exit code and its
    output (stdout and stderr), checked to hold no traceback: whatever it is told, it answers in lines."""
    proc = subprocess.run(
        [sys.executable, "-m", "colonlight_cli.main", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        cwd=cwd,
        env={**os.environ, **PLAIN_CONSOLE, **(env or {})},
    )
    output = proc.stdout + proc.stderr
    assert "Traceback" not in output, output
    return proc.returncode, output


def invoke_cli(*args: str) -> tuple[int, str]:
    """``colonlight ARGS`` in this process (typer's CliRunner) on a wide, colourless console: its exit code and its
    output, checked to have ended without an exception other than its exit and to hold no traceback."""
    from colonlight_cli.main import app  # here, not at the top: the tests that only start processes do not load it
    from typer.testing import CliRunner

    result = CliRunner().invoke(app, list(args), env={"COLUMNS": "400", "NO_COLOR": "1"})
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output, result.output
    return result.exit_code, result.output


def boxed_text(output: str) -> str:
    """``output`` with the frames of rich's boxes (a usage error, --help's panels) taken out and its lines joined:
    a box wraps its text at the console's width, wherever a long path (a longer temporary folder) puts the break,
    and a message wrapped over lines reads as one."""
    return " ".join(output.translate(str.maketrans(dict.fromkeys("│╭╮╰╯─", " "))).split())
