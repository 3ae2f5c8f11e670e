"""The console script's entry point: the command's modules load first (a few tenths of a second, more on a cold
disk), and a Ctrl-C while they do is the same one line as a Ctrl-C later, not a traceback from an import."""

from __future__ import annotations

import sys


def run() -> None:
    """Load the command line, then run it (``colonlight_cli.main.run``)."""
    try:
        from .main import run as run_app
    except KeyboardInterrupt:
        sys.stderr.write("error: interrupted\n")
        raise SystemExit(130) from None
    run_app()
