"""The console script's entry point: the command's modules load first (a few tenths of a second, more on a cold
disk), and a Ctrl-C while they do is the same one line as a Ctrl-C later, not a traceback from an import; a
SIGTERM then (``kill``, ``docker stop`` right after a start) likewise, with exit code 143."""

from __future__ import annotations

import signal
import sys


def run() -> None:
    """Load the command line, then run it (``colonlight_cli.main.run``)."""
    terminated: list[int] = []

    def on_sigterm(signum: int, frame: object) -> None:
        terminated.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        from .main import run as run_app
    except KeyboardInterrupt:
        sys.stderr.write("error: interrupted\n")
        raise SystemExit(143 if terminated else 130) from None
    finally:
        signal.signal(signal.SIGTERM, previous)  # from here each command handles it as it must (serve: uvicorn's)
    run_app()
