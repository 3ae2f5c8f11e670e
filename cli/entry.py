"""The console script's entry point: the command's modules load first (a few tenths of a second, more on a cold
disk), and a Ctrl-C while they do is the same one line as a Ctrl-C later, not a traceback from an import; a
SIGTERM then (``kill``, ``docker stop`` right after a start) likewise, with exit code 143."""

from __future__ import annotations

import signal
import sys

from .interrupts import exit_code, signals_interrupt
from .process_start import debug_requested, fill_closed_standard_streams, refuse_a_deleted_working_folder


def run() -> None:
    """Load the command line, then run it (``colonlight_cli.main.run``)."""
    fill_closed_standard_streams()  # before anything opens a file
    refuse_a_deleted_working_folder()
    # the handler is put back once loaded: from there each command handles SIGTERM as it must (serve: uvicorn's)
    with signals_interrupt((signal.SIGTERM,)) as received:
        try:
            from .main import run as run_app
        except KeyboardInterrupt:
            sys.stderr.write("error: interrupted\n")
            raise SystemExit(exit_code(received)) from None
        except (ImportError, MemoryError, OSError) as exc:  # libraries that do not load (under a memory limit)
            if debug_requested():
                raise
            from colonlight.errors import load_failure_cause

            sys.stderr.write(f"error: cannot load colonlight's libraries: {load_failure_cause(exc)}\n")
            raise SystemExit(1) from None
    run_app()
