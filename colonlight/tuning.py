"""Process-wide tuning for running clips: torch's thread count and glibc's malloc.

These settings belong to a whole process, so they are applied once, at the entry of a process that runs clips
(``colonlight enhance``, ``demo`` and ``stream``, a pool worker's initialiser; the service does its own at start-up),
never by a library function such as :func:`colonlight.run_batch`, which runs in whatever process calls it.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

from .limits import available_cores

if TYPE_CHECKING:
    from .jobs import MethodSpec

#: glibc's mallopt parameters (malloc.h) and the values set for a clip worker: see :func:`reuse_frame_memory`.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD = 32 << 20  # glibc's largest allowed value (HEAP_MAX_SIZE / 2 on 64-bit)
_TRIM_THRESHOLD = 128 << 20


def reuse_frame_memory() -> bool:
    """Let glibc's malloc serve frame-sized buffers (a few MB, several per frame) from memory it keeps, instead of
    a fresh ``mmap`` each (page faults on every first touch, ``munmap`` on free). Process-wide; returns whether
    it was applied (glibc only; skipped if the user set ``MALLOC_MMAP_THRESHOLD_``/``MALLOC_TRIM_THRESHOLD_``).

    Measured on a 20 s 1350x1080 clip: minor page faults 380k -> 76k, system CPU -0.5 s; peak memory +11 MiB.
    """
    if not sys.platform.startswith("linux") or any(
        k in os.environ for k in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
    ):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))


def network_threads(spec: MethodSpec, workers: int) -> int:
    """torch threads for a clip worker: one for the recurrent net on a small copy of the frame (a 3 ms step that
    a second OpenMP thread barely speeds up while its spinning starves the decode and encode threads), else the
    worker's share of the cores."""
    cores = available_cores()
    size = dict(spec.options).get("model_size")
    if spec.name == "rnn" and str(size).lower() != "full":
        return 1
    return max(1, cores // max(1, workers))


def tune_for_clips(threads: int, *, load_torch: bool = False) -> None:
    """Tune this process for running clips: ``threads`` torch threads and :func:`reuse_frame_memory`.

    torch's threads are set when torch is loaded (the method was built first, so a method without torch never
    imports it), or with ``load_torch`` (a pool worker, before its first clip builds the method)."""
    if load_torch:
        import torch  # noqa: F401 - loaded now so that its threads are set before any clip
    torch_module = sys.modules.get("torch")
    if torch_module is not None:
        torch_module.set_num_threads(max(1, threads))
    reuse_frame_memory()
