"""What a command mends or refuses about the process it was started in, before anything else is loaded.

Standard streams it was started without (``2>&-``, ``<&-``, a parent that closed them): a closed descriptor 0, 1 or
2 is the next number ``open`` returns, so the first file the command opened (a frame, a manifest) would take it,
and whatever is then written to that stream (by Python, FFmpeg or a library that writes to descriptor 2 whatever
``sys.stderr`` is) would land in the output. Each closed one is opened on the null device first. ``sys.stdin`` and
``sys.stdout`` stay None, so that ``stream -`` and ``stream --pipe`` can say which one was closed; ``sys.stderr``
becomes a writer to the null device, so that a command's report is dropped, not a crash. A current folder that
no longer exists is refused in one line. Whether tracebacks were asked for is decided here, before typer parses.
"""

from __future__ import annotations

import os
import sys


def fill_closed_standard_streams() -> None:
    """Open each closed standard descriptor on the null device; give a closed ``sys.stderr`` a null writer."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    if sys.stderr is None:
        sys.stderr = open(2, "w", encoding="utf-8", errors="replace", closefd=False)  # noqa: SIM115 - for good


def refuse_a_deleted_working_folder() -> None:
    """Exit 1 with one line when the current folder no longer exists: loading torch there dies with "Intel oneMKL
    FATAL ERROR: Cannot load libtorch_cpu.so", and a relative path could not be found anyway. (Plain text: this
    runs before the console and the engine are loaded.)"""
    try:
        os.getcwd()
    except FileNotFoundError:
        sys.stderr.write("error: the current folder no longer exists (deleted, or moved away): cd to one that does\n")
        raise SystemExit(1) from None


def debug_requested() -> bool:
    """``--debug`` anywhere on the command line, or ``COLONLIGHT_DEBUG`` set (not to 0): show tracebacks. Read from
    the raw arguments, as the entry point needs it before (or without) typer's parsing."""
    return os.environ.get("COLONLIGHT_DEBUG", "") not in ("", "0") or "--debug" in sys.argv
