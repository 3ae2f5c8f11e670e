"""The ``colonlight`` command as a real process, for the tests that need one (exit codes, signals, memory, a second
process, what a terminal shows): how it is launched and in what environment, decided here once."""

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


def boxed_text(output: str) -> str:
    """``output`` with the frame of a usage-error box taken out and its lines joined: the box wraps its message at
    the console's width, wherever a long path (a longer temporary folder) puts the break."""
    return " ".join(output.translate(str.maketrans(dict.fromkeys("│╭╮╰╯─", " "))).split())
