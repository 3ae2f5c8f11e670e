"""One clip as a job: the types every runner shares and the one way to run a clip.

A :class:`ClipJob` (where a clip comes from, its name, where its outputs go) and a :class:`MethodSpec` (a method
by name and options, cheap to send to another process) go in; a :class:`ClipOutcome` comes out. :func:`run_clip`
never raises for a bad clip: the batch (:mod:`colonlight.batch`, in this process or a pool), the Dask cluster
(:mod:`colonlight.cluster`) and the service (its runners) all run clips through it, so that a
clip is enhanced, skipped and failed the same way everywhere. This module sits below all of them.
"""

from __future__ import annotations

import errno
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import ColonlightError, resource_shortage
from .frames import list_image_frames
from .limits import DEFAULT_METHOD
from .methods import Method, create_method
from .pipeline import ClipOptions, complete_record, discard_partial_outputs, enhance_clip
from .video import probe_video

#: Errors of writing that mean "no room": the clip's partial outputs are removed to free it.
_NO_ROOM = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})


@dataclass(frozen=True)
class ClipJob:
    """One clip of a batch: where it comes from, what it is called and where its outputs go.

    ``problem``: set when discovery already knows the clip cannot be read (a symlink loop, a dangling link);
    the clip then fails with this one-line message without being opened.
    """

    source: Path
    name: str  # relative output path, POSIX separators
    out_dir: Path
    problem: str | None = None
    #: The source as the user named it, what the records say (None: ``source``): a cluster sends the job with an
    #: absolute ``source``, and its outputs must read as a local run's.
    shown: str | None = None

    @property
    def label(self) -> str:
        """The source as records and outcomes name it."""
        return self.shown if self.shown is not None else str(self.source)


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

    name: str = DEFAULT_METHOD
    options: tuple[tuple[str, Any], ...] = ()

    @staticmethod
    def of(name: str, **options: Any) -> MethodSpec:
        return MethodSpec(name, tuple(sorted((k, v) for k, v in options.items() if v is not None)))

    def build(self) -> Method:
        return create_method(self.name, **dict(self.options))


ProgressFn = Callable[[str, str, dict[str, Any]], None]
"""``progress(event, clip_name, data)``; events: ``start`` (data: total), ``frames`` (data: done), ``end``."""

ErrorWording = Callable[[ClipJob, Exception], tuple[str, "str | None"]]
"""``wording(job, exc) -> (error line, detail)`` for a clip that raised: a runner's own words for its users (the
service names no server path); the default is :func:`engine_wording`."""

_METHODS: dict[MethodSpec, Method] = {}


def method_for(spec: MethodSpec) -> Method:
    """The method for ``spec``, built once per process and reused for every clip (a bad checkpoint or device
    raises here: call it before a batch to fail early)."""
    if spec not in _METHODS:
        _METHODS[spec] = spec.build()
    return _METHODS[spec]


def estimate_frames(source: Path, fps: float | None) -> int | None:
    """A rough frame count for progress bars only (container metadata is never used to select frames)."""
    try:
        if source.is_dir():
            return len(list_image_frames(source))
        info = probe_video(source)
        if info.duration_s:
            rate = fps or info.avg_fps
            # the fps filter emits a frame per output tick up to the clip's end, rounded to the nearest:
            # round(duration * rate) (3.0 s at 18 fps: 54, not the 55 that int() + 1 gave)
            return max(1, int(info.duration_s * rate + 0.5)) if rate else None
    except (ColonlightError, OSError):
        return None
    return None


def _is_under(path: str | os.PathLike[str] | None, folder: Path) -> bool:
    if path is None:
        return False
    try:
        return os.path.commonpath([os.path.abspath(os.fsdecode(path)), os.path.abspath(folder)]) == os.path.abspath(
            folder
        )
    except ValueError:
        return False


def _os_error_line(job: ClipJob, exc: OSError) -> str:
    """One line for an OS error while running a clip: a write to its outputs, or a read of its source."""
    cause = exc.strerror or type(exc).__name__
    if exc.errno in _NO_ROOM or _is_under(exc.filename, job.out_dir):
        return f"{job.source}: cannot write its outputs to {job.out_dir}: {cause}"
    where = f" ({os.fsdecode(exc.filename)})" if exc.filename is not None else ""
    return f"{job.source}: {cause}{where}"


def engine_wording(job: ClipJob, exc: Exception) -> tuple[str, str | None]:
    """The engine's words for a clip that raised, each naming the clip's source; a write error that means no
    room (or a write to the clip's outputs) also removes what the clip had written, to free space."""
    if isinstance(exc, ValueError):  # a bad option (OptionError) or frame; the line names the clip
        return f"{job.source}: {exc}", None
    if isinstance(exc, ColonlightError):  # its message names the file already
        return str(exc), None
    if isinstance(exc, OSError):  # a full disk, a read-only remount, an I/O error: this clip fails, the batch goes on
        line = _os_error_line(job, exc)
        if exc.errno in _NO_ROOM or _is_under(exc.filename, job.out_dir):
            discard_partial_outputs(job.out_dir)
        return line, traceback.format_exc()
    shortage = resource_shortage(exc)
    if shortage is not None:
        return f"{job.source}: {shortage}", traceback.format_exc()
    return f"{job.source}: internal error: {type(exc).__name__}: {exc}", traceback.format_exc()


def run_clip(
    job: ClipJob,
    method: MethodSpec | Method,
    opts: ClipOptions,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    *,
    on_frame: Callable[[int], None] | None = None,
    wording: ErrorWording = engine_wording,
) -> ClipOutcome:
    """Run one clip and never raise for a bad clip: the outcome carries the one-line error (``wording``).

    ``method``: a spec (built once per process, :func:`method_for`) or a method already built. A complete earlier
    output is kept (``skipped``) unless ``overwrite``. ``on_frame(n)`` is called after every frame and may raise
    to stop the clip (the exception is worded as any other). Only ``BaseException``s that are not errors (an
    interrupt, ``SystemExit``) propagate.
    """
    t0 = time.perf_counter()

    def failed(error: str, detail: str | None = None) -> ClipOutcome:
        return ClipOutcome(job.name, job.label, "failed", seconds=time.perf_counter() - t0, error=error, detail=detail)

    def frame_done(n: int) -> None:
        if on_frame is not None:
            on_frame(n)
        if progress is not None:
            progress("frames", job.name, {"done": n})

    if job.problem is not None:
        return failed(job.problem)
    started = False
    try:
        built = method if isinstance(method, Method) else method_for(method)
        record = None if overwrite else complete_record(job.out_dir, built, opts)
        if record is not None:
            return ClipOutcome(
                job.name,
                job.label,
                "done",
                frames=record.get("frame_count", 0),
                skipped=True,
                truncated=bool(record.get("truncated")),
                warnings=tuple(record.get("warnings", ())),
            )
        if progress:
            started = True
            progress("start", job.name, {"total": estimate_frames(job.source, opts.fps)})
        result = enhance_clip(
            job.source,
            job.out_dir,
            built,
            opts,
            clip_name=job.name,
            on_frame=frame_done if progress or on_frame else None,
            source_name=job.shown,
        )
        return ClipOutcome(
            job.name,
            job.label,
            "done",
            frames=result.frames,
            seconds=result.seconds,
            truncated=result.truncated,
            warnings=result.warnings,
        )
    except Exception as exc:  # noqa: BLE001 - a bug must not stop the batch; it is reported with its traceback
        return failed(*wording(job, exc))
    finally:
        if started and progress:
            progress("end", job.name, {})
