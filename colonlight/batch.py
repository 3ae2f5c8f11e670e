"""Batch runs: run the clips that discovery found (in this process, in a local pool of worker processes, or on a
Dask cluster), skip finished ones, and keep a manifest. Finding and naming clips: :mod:`colonlight.discovery`.

What a batch guarantees (the README's reliability section says the same for users):

* it never stops for one clip: every failure, expected or not, is one line naming the clip and the cause, and a
  ``failed`` manifest entry; a write error (a full disk) also removes what that clip had written, to free space;
* one batch per output folder (:mod:`colonlight.outdir`), so no manifest entry is lost to a concurrent batch;
* the manifest is rewritten atomically after every clip; if it cannot be written (a full disk) the last
  complete version stays and the write is retried after the next clip and at the end;
* an interrupt (``KeyboardInterrupt``: Ctrl-C, or SIGTERM as the CLI maps it) stops the workers, removes every
  temporary of the clips that were running and propagates; complete clips are kept, a rerun resumes;
* pool workers die with the batch process, even when it is killed with SIGKILL (Linux: ``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import signal
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import __version__
from .atomic import read_json, remove_stale_temporaries, write_json_atomic
from .discovery import MANIFEST_FILE as MANIFEST_FILE  # the batch's API; the name discovery keeps clear of
from .discovery import VIDEO_SUFFIXES, discover_clips  # noqa: F401 - re-exported (the batch's API)
from .errors import ColonlightError
from .jobs import (  # noqa: F401 - the job types and run_clip, re-exported (the batch's API)
    ClipJob,
    ClipOutcome,
    MethodSpec,
    ProgressFn,
    estimate_frames,
    method_for,
    run_clip,
)
from .limits import available_cores
from .methods import Method
from .outdir import output_lock
from .pipeline import GAMMAS_FILE, ClipOptions, remove_unfinished_video
from .tuning import network_threads, tune_for_clips
from .worker_process import die_with_parent, stop_workers

#: How names that are not valid UTF-8 appear in the manifest (and in every gammas.json): see atomic.json_bytes.
PATH_ENCODING = "utf-8, surrogateescape (a byte 0xNN that is not UTF-8 is written as \\udcNN; os.fsencode restores it)"


# ----------------------------------------------------------------------------------------------- running


def warm_method(spec: MethodSpec) -> Method:
    """Build the method of ``spec`` in this process now (a bad checkpoint or device fails here, not mid-batch)."""
    return method_for(spec)


@dataclass
class Manifest:
    """``OUT/manifest.json``: every clip ever run into OUT (entries of earlier runs are kept), rewritten atomically
    after each clip so that it is current even after a crash.

    A write that fails (a full disk) leaves the previous, complete manifest in place; :attr:`unsaved` then holds
    the error and the next :meth:`record` (or :meth:`save`) tries again. ``problems``: the paths of this run
    that were not clips and could not be searched (replaced by every run).
    """

    path: Path
    settings: dict[str, Any]
    clips: dict[str, dict[str, Any]] = field(default_factory=dict)
    problems: list[dict[str, str]] = field(default_factory=list)
    unsaved: OSError | None = None

    @staticmethod
    def open(out_root: Path, settings: dict[str, Any]) -> Manifest:
        path = Path(out_root) / MANIFEST_FILE
        clips: dict[str, dict[str, Any]] = {}
        try:
            for entry in read_json(path).get("clips", []):
                clips[entry["clip"]] = entry
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass
        return Manifest(path, settings, clips)

    def record(self, outcome: ClipOutcome) -> None:
        entry: dict[str, Any] = {
            "clip": outcome.name,
            "source": outcome.source,
            "status": outcome.status,
            "frames": outcome.frames,
            "seconds": round(outcome.seconds, 3),
        }
        if outcome.skipped:
            entry["skipped"] = True
        if outcome.error:
            entry["error"] = outcome.error
        if outcome.truncated:
            entry["truncated"] = True
        if outcome.warnings:
            entry["warnings"] = list(outcome.warnings)
        self.clips[outcome.name] = entry
        self.save()

    def save(self) -> bool:
        """Write the manifest; False (the error kept in :attr:`unsaved`) if it cannot be written now."""
        doc: dict[str, Any] = {
            "colonlight_version": __version__,
            "path_encoding": PATH_ENCODING,
            "settings": self.settings,
            "clips": [self.clips[k] for k in sorted(self.clips)],
        }
        if self.problems:
            doc["problems"] = self.problems
        try:
            write_json_atomic(self.path, doc)
        except OSError as exc:
            self.unsaved = exc
            return False
        self.unsaved = None
        return True


class ManifestError(ColonlightError):
    """The manifest could not be written at the end of a batch (the clips' own outputs are complete)."""


def default_workers(n_clips: int) -> int:
    """One worker per two cores (each clip already keeps a decoder, the model and encoders busy), at most one per
    clip."""
    return max(1, min(n_clips, available_cores() // 2))


#: Signals that stop a batch; held back while pool workers are started, so that a worker never starts with
#: Python's default Ctrl-C handler (it ignores SIGINT: the batch process decides, see _run_pool).
_STOP_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})
#: In a pool worker: the queue its progress events go to (handed over at start, see _init_pool_worker).
_EVENTS: Any = None


def _init_pool_worker(threads: int, parent_pid: int, events: Any) -> None:
    """A clip worker process: bound to the batch process's life, deaf to Ctrl-C (the terminal sends it to the
    whole process group; the batch process stops the workers itself), torch threads, then the imports frozen
    out of the cyclic GC (see cli/loading.py). The process-wide tuning of a clip worker happens here, at its entry."""
    import gc

    global _EVENTS
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    _EVENTS = events
    tune_for_clips(threads, load_torch=True)
    gc.freeze()


def _run_in_worker(job: ClipJob, spec: MethodSpec, opts: ClipOptions, overwrite: bool) -> ClipOutcome:
    progress: ProgressFn | None = None
    events = _EVENTS
    if events is not None:
        last = [0.0]

        def progress(event: str, name: str, data: dict[str, Any]) -> None:
            now = time.monotonic()
            if event == "frames" and now - last[0] < 0.2:
                return  # throttle cross-process chatter
            last[0] = now
            events.put((event, name, data))

    return run_clip(job, spec, opts, overwrite, progress)


def _remove_temporaries_of(jobs: Sequence[ClipJob]) -> None:
    """After an interrupt: delete the temporaries, and a video published before its ``gammas.json``, of the clips
    that may have been running (a complete clip, which has its ``gammas.json``, was not running: its folder is not
    searched). A worker stopped mid-clip does not clean up itself."""
    for job in jobs:
        out_dir = Path(job.out_dir)
        if out_dir.is_dir() and not (out_dir / GAMMAS_FILE).exists():
            remove_stale_temporaries(out_dir)
            remove_unfinished_video(out_dir)


def run_batch(
    jobs: Sequence[ClipJob],
    spec: MethodSpec,
    opts: ClipOptions,
    out_root: Path,
    *,
    workers: int = 1,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    on_outcome: Callable[[ClipOutcome], None] | None = None,
    cluster: str | None = None,
    problems: Sequence[Any] = (),
) -> list[ClipOutcome]:
    """Run every job; a failing clip is recorded and the others go on. Returns outcomes in job order.

    Holds the output folder's lock throughout (OutputError if it cannot be used or another batch holds it).
    ``problems``: discovery's :class:`~colonlight.discovery.PathProblem` list, kept in the manifest. Raises
    ManifestError at the end if the manifest could not be written (the clips' outputs are complete).
    """
    out_root = Path(out_root)
    with output_lock(out_root):
        manifest = Manifest.open(out_root, {"method": spec.name, "options": dict(spec.options), **vars(opts)})
        manifest.problems = [
            {"path": p.path, "error": p.message, "status": "failed" if p.failed else "skipped"} for p in problems
        ]
        outcomes: dict[str, ClipOutcome] = {}

        def done(outcome: ClipOutcome) -> None:
            outcomes[outcome.name] = outcome
            manifest.record(outcome)
            if on_outcome:
                on_outcome(outcome)

        try:
            if cluster:
                from .cluster import run_on_cluster

                run_on_cluster(cluster, jobs, spec, opts, overwrite, done, progress)
            elif workers <= 1 or len(jobs) <= 1:  # in this process, tuned (or not) by its entry, not here
                for i, job in enumerate(jobs):
                    try:
                        done(run_clip(job, spec, opts, overwrite, progress))
                    except BaseException:
                        _remove_temporaries_of(jobs[i : i + 1])
                        raise
            else:
                _run_pool(jobs, spec, opts, overwrite, workers, progress, done)
        except BaseException:
            remove_stale_temporaries(out_root, recursive=False)  # a manifest write cut short
            raise
        if manifest.unsaved is not None and not manifest.save():
            exc = manifest.unsaved
            raise ManifestError(
                f"{manifest.path}: cannot write the manifest: {exc.strerror or exc}; the previous manifest is kept "
                "and the clips' own outputs are complete (rerun to record them)"
            )
    return [outcomes[j.name] for j in jobs if j.name in outcomes]


def _run_pool(
    jobs: Sequence[ClipJob],
    spec: MethodSpec,
    opts: ClipOptions,
    overwrite: bool,
    workers: int,
    progress: ProgressFn | None,
    done: Callable[[ClipOutcome], None],
) -> None:
    """The clips on a pool of ``workers`` spawned processes.

    A worker that dies (the kernel's OOM killer, a crash in a decoder) breaks the whole pool: the clips it took
    with it are run again, the ones that were running in a pool of one worker, where a second death fails that
    clip only ("the worker process running this clip died ..."); the rest of the batch goes on in a new pool.
    Every round settles at least one clip, so this ends. On any exception (an interrupt) the workers are killed, the
    temporaries of unfinished clips removed, and the exception propagates.
    """
    todo = list(jobs)
    while todo:
        lost, suspects, death = _pool_round(todo, spec, opts, overwrite, workers, progress, done)
        if not lost:
            return
        isolate = suspects or lost
        while isolate:  # one worker takes its clips in order: the first one lost is the one it was running
            isolate, _, death = _pool_round(isolate, spec, opts, overwrite, 1, progress, done)
            if isolate:
                guilty, isolate = isolate[0], isolate[1:]
                done(
                    ClipOutcome(
                        guilty.name,
                        str(guilty.source),
                        "failed",
                        error=f"{guilty.source}: the worker process running this clip died ({death})",
                    )
                )
        todo = [j for j in lost if suspects and j not in suspects]


def _death(exitcodes: Sequence[int | None]) -> str:
    """Why a pool's worker died, from its processes' exit codes (the pool SIGTERMs the others after a death)."""
    codes = [c for c in exitcodes if c not in (None, 0, -signal.SIGTERM)] or [c for c in exitcodes if c]
    if not codes:
        return "it exited"
    code = codes[0]
    if code is not None and code < 0:
        name = signal.Signals(-code).name
        return f"killed by {name}" + ("; out of memory?" if -code == signal.SIGKILL else "")
    return f"exit status {code}"


def _pool_round(
    jobs: Sequence[ClipJob],
    spec: MethodSpec,
    opts: ClipOptions,
    overwrite: bool,
    workers: int,
    progress: ProgressFn | None,
    done: Callable[[ClipOutcome], None],
) -> tuple[list[ClipJob], list[ClipJob], str]:
    """One pool over ``jobs`` until they are done or the pool breaks. Returns the jobs lost with a broken pool,
    those of them that were running (or queued to a worker) when it broke, and why the worker died."""
    ctx = mp.get_context("spawn")  # never fork a process that holds torch threads
    events = ctx.Queue() if progress else None  # one per pool: a dead worker may have held the queue's lock

    def drain() -> None:
        while events is not None and progress is not None:
            try:
                item = events.get_nowait()
            except queue.Empty:
                return
            progress(*item)

    before = set(mp.active_children())
    spawned: list[Any] = []
    pool: ProcessPoolExecutor | None = None
    futures: dict[Future[ClipOutcome], ClipJob] = {}
    finished_jobs: set[str] = set()
    lost: list[ClipJob] = []
    suspects: list[ClipJob] = []
    try:
        # Workers start with SIGINT/SIGTERM blocked (they inherit this thread's mask through fork and exec) and
        # unblock them only once their initializer ignores SIGINT: a Ctrl-C never hits a worker's startup.
        # A signal that arrives meanwhile is delivered here when the mask is restored.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        try:
            pool = ProcessPoolExecutor(
                max_workers=workers,
                mp_context=ctx,
                initializer=_init_pool_worker,
                initargs=(network_threads(spec, workers), os.getpid(), events),
            )
            for job in jobs:
                futures[pool.submit(_run_in_worker, job, spec, opts, overwrite)] = job
            spawned = [p for p in mp.active_children() if p not in before]
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        pending = set(futures)
        running: set[Future[ClipOutcome]] = set()
        order = {f: i for i, f in enumerate(futures)}
        while pending:
            running |= {f for f in pending if f.running()}
            finished = {f for f in pending if f.done()}
            drain()
            for fut in sorted(finished, key=order.__getitem__):
                pending.discard(fut)
                job = futures[fut]
                try:
                    outcome = fut.result()
                except BrokenProcessPool:
                    lost.append(job)
                    if fut in running:
                        suspects.append(job)
                    continue
                except Exception as exc:  # noqa: BLE001 - e.g. a result that cannot be unpickled: this clip fails
                    outcome = ClipOutcome(
                        job.name, str(job.source), "failed", error=f"{job.source}: worker failed: {exc}"
                    )
                finished_jobs.add(job.name)
                done(outcome)
            if pending and not finished:
                time.sleep(0.05)
        drain()
    except BaseException:
        stop_workers(p for p in mp.active_children() if p not in before)  # the pool's: they stop now, mid-clip
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        _remove_temporaries_of([j for j in jobs if j.name not in finished_jobs])
        raise
    finally:
        if events is not None:
            events.close()
    pool.shutdown(wait=True)
    if lost:
        _remove_temporaries_of(lost)
    lost.sort(key=lambda j: jobs.index(j))
    suspects.sort(key=lambda j: jobs.index(j))
    return lost, suspects, _death([p.exitcode for p in spawned])
