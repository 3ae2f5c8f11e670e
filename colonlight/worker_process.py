"""A pool worker's tie to the process that started it: every process pool of colonlight (the batch's clip
workers, the generator's and the evaluation's render workers) dies with its parent, however the parent dies, and
is killed mid-job when its parent stops early (:func:`stop_workers`; :func:`map_in_workers` for a plain map)."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.process import BaseProcess
from typing import Any, TypeVar

_Job = TypeVar("_Job")
_Result = TypeVar("_Result")

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


def stop_workers(workers: Iterable[BaseProcess], timeout: float = 10.0) -> None:
    """SIGKILL ``workers`` mid-task and reap them. An interrupted parent must not wait for their work (a clip can
    take minutes to render, and ``docker stop`` allows ten seconds); what they half-wrote is the caller's to sweep."""
    workers = list(workers)
    for proc in workers:
        proc.kill()
    for proc in workers:
        proc.join(timeout=timeout)


def map_in_workers(
    fn: Callable[[_Job], _Result],
    jobs: Iterable[_Job],
    *,
    workers: int,
    initializer: Callable[..., None] = die_with_parent,
    initargs: tuple[Any, ...] | None = None,
    on_stop: Callable[[], None] = lambda: None,
) -> Iterator[_Result]:
    """``fn(job)`` for each job, in order, from ``workers`` spawned processes that die with this one
    (``initializer`` must call :func:`die_with_parent`; its ``initargs`` default to this process's pid).

    If the loop stops early (an interrupt, a job's error, the caller breaking off) the workers are killed mid-job
    at once rather than left to finish the jobs they hold, and ``on_stop()`` then sweeps what they half-wrote."""
    ctx = multiprocessing.get_context("spawn")  # never fork a process that holds torch threads
    before = set(multiprocessing.active_children())
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=ctx,
        initializer=initializer,
        initargs=(os.getpid(),) if initargs is None else initargs,
    )
    try:
        # not pool.map: its iterator cancels the futures it holds before the workers are killed, and the pool's
        # manager thread then fails on them ("InvalidStateError: CANCELLED") with a traceback on stderr
        futures = [pool.submit(fn, job) for job in jobs]
        for future in futures:
            yield future.result()
    except BaseException:  # GeneratorExit (the caller broke off) included
        stop_workers(p for p in multiprocessing.active_children() if p not in before)
        pool.shutdown(wait=True, cancel_futures=True)
        on_stop()
        raise
    pool.shutdown(wait=True)


__all__ = ["die_with_parent", "map_in_workers", "stop_workers"]
