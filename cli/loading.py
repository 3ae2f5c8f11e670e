"""Loading a method at a command's start, the one way ``enhance`` and ``stream`` do it."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

from colonlight import Method, MethodSpec, warm_method

from .failures import USAGE, ends_command


@contextmanager
def imports_frozen() -> Iterator[None]:
    """The cyclic GC off while the model loads (torch alone is ~10^5 long-lived objects, which it would walk again
    and again: -0.1 s CPU of a ~1 s load), then everything imported so far moved out of its sight for good, so
    that the full collections frame-rate allocation triggers (~0.1 s each, all threads stopped) become cheap.
    Measured: -0.8 s wall on a 20 s 1350x1080 clip."""
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()


def load_method_or_exit(spec: MethodSpec, debug: bool) -> Method:
    """The method of ``spec``, built now: a bad checkpoint or an absent device stops the command here, as a usage
    error (exit status 2, one line; the traceback with ``--debug``)."""
    with ends_command(USAGE, debug):  # OptionError, CheckpointError, DeviceError
        return warm_method(spec)
