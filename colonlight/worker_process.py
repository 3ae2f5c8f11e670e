"""A pool worker's tie to the process that started it: every process pool of colonlight (the batch's clip
workers, the generator's and the evaluation's render workers) dies with its parent, however the parent dies."""

from __future__ import annotations

import contextlib
import os
import signal
import sys

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent_pid: int) -> None:
    """Have the kernel SIGKILL this worker when its parent dies, however it dies (``kill -9`` included: no
    ``atexit`` or signal handler of the parent runs then). Linux's ``PR_SET_PDEATHSIG``; elsewhere only the
    check below. The parent may have died before the ``prctl``: then it is not our parent any more.

    The kernel watches the parent *thread* that started the worker: a pool must start all its workers in a
    thread that outlives the pool (``ProcessPoolExecutor`` does so on ``submit``/``map``, in the calling thread,
    when there is no ``max_tasks_per_child``)."""
    if sys.platform.startswith("linux"):
        import ctypes

        # no prctl in this libc: the ppid check still catches a dead parent
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)


__all__ = ["die_with_parent"]
