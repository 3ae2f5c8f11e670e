"""Batch runs: find the clips under the inputs, plan where each one's outputs go, skip finished ones, run the
rest (in this process, in a local pool of worker processes, or on a Dask cluster) and keep a manifest.

Naming (a stable interface): a clip named directly on the command line (a video file or a folder of frames) is
written to ``OUT/<its name, suffix dropped>``; a clip found inside a given folder keeps its path relative to that
folder, suffix dropped (``videos/site1/p7.mp4`` -> ``OUT/site1/p7``).
"""

from __future__ import annotations

import fnmatch
import multiprocessing as mp
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import __version__
from .atomic import write_json_atomic
from .errors import ColonlightError
from .frames import IMAGE_SUFFIXES, is_image_folder, list_image_frames
from .methods import Method, create_method
from .pipeline import ClipOptions, complete_record, enhance_clip
from .video import is_video, probe_video

MANIFEST_FILE = "manifest.json"
#: Suffixes taken as videos even before probing, so that a broken file with such a name is reported, not ignored.
VIDEO_SUFFIXES = frozenset(
    ".mp4 .m4v .mov .avi .mkv .mpg .mpeg .ts .mts .m2ts .webm .wmv .flv .3gp .ogv .mxf .vob".split()
)
_SIDE_SUFFIXES = frozenset(".json .txt .csv .md .yaml .yml .xml .log .ini".split())


@dataclass(frozen=True)
class ClipJob:
    """One clip of a batch: where it comes from, what it is called and where its outputs go."""

    source: Path
    name: str  # relative output path, POSIX separators
    out_dir: Path


@dataclass
class ClipOutcome:
    name: str
    source: str
    status: str  # done | failed
    frames: int = 0
    seconds: float = 0.0
    skipped: bool = False
    error: str | None = None
    detail: str | None = None  # traceback of an unexpected error (shown with --debug)
    truncated: bool = False  # done from a source that looks cut short (the frames that decode)
    warnings: tuple[str, ...] = ()  # one line each, without the path


@dataclass(frozen=True)
class MethodSpec:
    """A method by name and options: cheap to send to worker processes, which build (and cache) the method."""

    name: str = "rnn"
    options: tuple[tuple[str, Any], ...] = ()

    @staticmethod
    def of(name: str, **options: Any) -> MethodSpec:
        return MethodSpec(name, tuple(sorted((k, v) for k, v in options.items() if v is not None)))

    def build(self) -> Method:
        return create_method(self.name, **dict(self.options))


# ----------------------------------------------------------------------------------------------- discovery


def _strip_suffix(rel: Path) -> Path:
    return rel.with_suffix("") if rel.suffix else rel


def _walk(root: Path) -> Iterable[tuple[Path, Path]]:
    """Yield ``(source, relative name)`` for the clips under ``root``, in sorted order."""
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        here = Path(dirpath)
        for d in list(dirnames):
            sub = here / d
            if is_image_folder(sub):
                dirnames.remove(d)  # a frame folder is one clip: do not descend
                yield sub, sub.relative_to(root)
        for fname in sorted(filenames):
            if fname.startswith("."):
                continue
            p = here / fname
            suffix = p.suffix.lower()
            if suffix in IMAGE_SUFFIXES or suffix in _SIDE_SUFFIXES:
                continue
            if suffix in VIDEO_SUFFIXES or is_video(p):
                yield p, _strip_suffix(p.relative_to(root))


def discover_clips(inputs: Sequence[Path], out_root: Path, pattern: str | None = None) -> list[ClipJob]:
    """The clips under ``inputs`` (files and folders, walked recursively), with their output folders.

    ``pattern`` (a glob) keeps clips whose relative path or file name matches. Two clips that would share an
    output folder are told apart by their suffix (``clip-mp4``, ``clip-avi``).
    """
    found: list[tuple[Path, Path]] = []
    for inp in inputs:
        inp = Path(inp)
        if inp.is_dir() and not is_image_folder(inp):
            found.extend(_walk(inp))
        else:  # a file, a frame folder, or a path that does not exist (reported when the clip runs)
            found.append((inp, Path(_strip_suffix(Path(inp.name)))))
    if pattern:
        found = [
            (src, rel)
            for src, rel in found
            if fnmatch.fnmatch(src.name, pattern) or fnmatch.fnmatch(rel.as_posix(), pattern)
            or fnmatch.fnmatch((rel.parent / src.name).as_posix(), pattern)
        ]
    counts: dict[str, int] = {}
    for _, rel in found:
        counts[rel.as_posix()] = counts.get(rel.as_posix(), 0) + 1
    jobs, seen = [], set()
    for src, rel in found:
        name = rel.as_posix()
        if counts[name] > 1 and src.suffix:
            name = f"{name}-{src.suffix.lstrip('.').lower()}"
        if (src.resolve(), name) in seen:
            continue
        seen.add((src.resolve(), name))
        jobs.append(ClipJob(source=src, name=name, out_dir=Path(out_root) / name))
    return jobs


def estimate_frames(source: Path, fps: float | None) -> int | None:
    """A rough frame count for progress bars only (container metadata is never used to select frames)."""
    try:
        if source.is_dir():
            return len(list_image_frames(source))
        info = probe_video(source)
        if info.duration_s:
            rate = fps or info.avg_fps
            return int(info.duration_s * rate) + 1 if rate else None
    except (ColonlightError, OSError):
        return None
    return None


# ----------------------------------------------------------------------------------------------- running

ProgressFn = Callable[[str, str, dict[str, Any]], None]
"""``progress(event, clip_name, data)``; events: ``start`` (data: total), ``frames`` (data: done), ``end``."""

_WORKER_METHODS: dict[MethodSpec, Method] = {}


def _method_for(spec: MethodSpec) -> Method:
    """The method for ``spec``, built once per process and reused for every clip."""
    if spec not in _WORKER_METHODS:
        _WORKER_METHODS[spec] = spec.build()
    return _WORKER_METHODS[spec]


def run_clip(
    job: ClipJob,
    spec: MethodSpec,
    opts: ClipOptions,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
) -> ClipOutcome:
    """Run one clip and never raise for a bad clip: the outcome carries the one-line error."""
    t0 = time.perf_counter()
    try:
        method = _method_for(spec)
        record = None if overwrite else complete_record(job.out_dir, method, opts)
        if record is not None:
            return ClipOutcome(job.name, str(job.source), "done", frames=record.get("frame_count", 0), skipped=True,
                               truncated=bool(record.get("truncated")), warnings=tuple(record.get("warnings", ())))
        if progress:
            progress("start", job.name, {"total": estimate_frames(job.source, opts.fps)})
        result = enhance_clip(
            job.source,
            job.out_dir,
            method,
            opts,
            clip_name=job.name,
            on_frame=(lambda n: progress("frames", job.name, {"done": n})) if progress else None,
        )
        return ClipOutcome(job.name, str(job.source), "done", frames=result.frames, seconds=result.seconds,
                           truncated=result.truncated, warnings=result.warnings)
    except ColonlightError as exc:
        return ClipOutcome(job.name, str(job.source), "failed", seconds=time.perf_counter() - t0, error=str(exc))
    except ValueError as exc:  # bad option values reach here from method construction
        return ClipOutcome(job.name, str(job.source), "failed", seconds=time.perf_counter() - t0, error=f"{job.source}: {exc}")
    except Exception as exc:  # noqa: BLE001 - a bug must not stop the batch; it is reported with its traceback
        return ClipOutcome(
            job.name,
            str(job.source),
            "failed",
            seconds=time.perf_counter() - t0,
            error=f"{job.source}: internal error: {type(exc).__name__}: {exc}",
            detail=traceback.format_exc(),
        )
    finally:
        if progress:
            progress("end", job.name, {})


@dataclass
class Manifest:
    """``OUT/manifest.json``: every clip ever run into OUT (entries of earlier runs are kept), rewritten atomically
    after each clip so that it is current even after a crash."""

    path: Path
    settings: dict[str, Any]
    clips: dict[str, dict[str, Any]] = field(default_factory=dict)

    @staticmethod
    def open(out_root: Path, settings: dict[str, Any]) -> Manifest:
        import json

        path = Path(out_root) / MANIFEST_FILE
        clips: dict[str, dict[str, Any]] = {}
        try:
            for entry in json.loads(path.read_text(encoding="utf-8")).get("clips", []):
                clips[entry["clip"]] = entry
        except (OSError, ValueError, KeyError, TypeError):
            pass
        return Manifest(path, settings, clips)

    def record(self, outcome: ClipOutcome) -> None:
        entry: dict[str, Any] = {"clip": outcome.name, "source": outcome.source, "status": outcome.status,
                                 "frames": outcome.frames, "seconds": round(outcome.seconds, 3)}
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

    def save(self) -> None:
        write_json_atomic(
            self.path,
            {
                "colonlight_version": __version__,
                "settings": self.settings,
                "clips": [self.clips[k] for k in sorted(self.clips)],
            },
        )


def default_workers(n_clips: int) -> int:
    """One worker per two cores (each clip already keeps a decoder, the model and encoders busy), at most one per clip."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(n_clips, cores // 2))


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


def _init_worker(threads: int) -> None:
    import torch

    torch.set_num_threads(max(1, threads))
    reuse_frame_memory()


def _init_pool_worker(threads: int) -> None:
    """A clip worker process: torch threads, then the imports frozen out of the cyclic GC (see cli/enhance.py)."""
    import gc

    _init_worker(threads)
    gc.freeze()


def network_threads(spec: MethodSpec, workers: int) -> int:
    """torch threads for a clip worker: one for the recurrent net on a small copy of the frame (a 3 ms step that
    a second OpenMP thread barely speeds up while its spinning starves the decode and encode threads), else the
    worker's share of the cores."""
    cores = os.cpu_count() or 1
    size = dict(spec.options).get("model_size")
    if spec.name == "rnn" and str(size).lower() != "full":
        return 1
    return max(1, cores // max(1, workers))


def _run_in_worker(job: ClipJob, spec: MethodSpec, opts: ClipOptions, overwrite: bool, events: Any) -> ClipOutcome:
    progress: ProgressFn | None = None
    if events is not None:
        last = [0.0]

        def progress(event: str, name: str, data: dict[str, Any]) -> None:
            now = time.monotonic()
            if event == "frames" and now - last[0] < 0.2:
                return  # throttle cross-process chatter
            last[0] = now
            events.put((event, name, data))

    return run_clip(job, spec, opts, overwrite, progress)


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
) -> list[ClipOutcome]:
    """Run every job; a failing clip is recorded and the others go on. Returns outcomes in job order."""
    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    manifest = Manifest.open(out_root, {"method": spec.name, "options": dict(spec.options), **vars(opts)})
    outcomes: dict[str, ClipOutcome] = {}

    def done(outcome: ClipOutcome) -> None:
        outcomes[outcome.name] = outcome
        manifest.record(outcome)
        if on_outcome:
            on_outcome(outcome)

    if cluster:
        from .cluster import run_on_cluster

        run_on_cluster(cluster, jobs, spec, opts, overwrite, done, progress)
    elif workers <= 1 or len(jobs) <= 1:
        _init_worker(network_threads(spec, 1))
        for job in jobs:
            done(run_clip(job, spec, opts, overwrite, progress))
    else:
        _run_pool(jobs, spec, opts, overwrite, workers, progress, done)
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
    ctx = mp.get_context("spawn")  # never fork a process that holds torch threads
    with ctx.Manager() as manager:
        events = manager.Queue() if progress else None
        with ProcessPoolExecutor(
            max_workers=workers, mp_context=ctx, initializer=_init_pool_worker,
            initargs=(network_threads(spec, workers),),
        ) as pool:
            futures: dict[Future[ClipOutcome], ClipJob] = {
                pool.submit(_run_in_worker, job, spec, opts, overwrite, events): job for job in jobs
            }
            pending = set(futures)
            while pending:
                finished = {f for f in pending if f.done()}
                if events is not None and progress is not None:
                    while not events.empty():
                        progress(*events.get_nowait())
                for fut in finished:
                    pending.discard(fut)
                    job = futures[fut]
                    try:
                        done(fut.result())
                    except Exception as exc:  # noqa: BLE001 - a worker died: record it, go on
                        done(ClipOutcome(job.name, str(job.source), "failed", error=f"{job.source}: worker failed: {exc}"))
                if pending and not finished:
                    time.sleep(0.05)
            if events is not None and progress is not None:
                while not events.empty():
                    progress(*events.get_nowait())
