"""Scale-out on a Dask distributed cluster: one task per clip, on workers that share the inputs and outputs.

``colonlight enhance ... --cluster tcp://HOST:8786`` (or ``COLONLIGHT_CLUSTER``) sends the batch here instead of
the local pool. Every clip is one Dask task running :func:`colonlight.jobs.run_clip` on a worker, which builds the
method once per worker process (``method_for`` caches it) and writes the clip's outputs itself, so the workers
must see the inputs, the weights and the output folder **at the same paths** as this machine (a shared
filesystem: NFS, a cluster filesystem, the same volume in every container).

Retries and resume. Dask reschedules the tasks of a worker that dies (up to
``distributed.scheduler.allowed-failures`` times per task); a clip restarted elsewhere simply runs again: its
outputs are written atomically, ``gammas.json`` is removed first and written last, and stale temporaries are
removed before anything else, so the retried clip's files are byte-identical to an uninterrupted run. A clip
whose outputs are complete (same method, model and settings) is skipped by the worker, as in a local run.

Checks, so that a misconfigured cluster fails loudly and early:

* the scheduler must answer within ``COLONLIGHT_CLUSTER_TIMEOUT`` seconds (default 10) and at least one worker
  must be connected within the same time, else a one-line :class:`ColonlightError`;
* before a batch, every connected worker must import the same colonlight version and see this machine's output
  folder (a token file written here and read there), the weights file and the input clips, else a one-line
  :class:`ColonlightError` naming the worker and the path;
* every task checks again on the worker that runs it (workers may join later): a clip whose source, output
  folder (created here before the task is sent) or model the worker does not share becomes a failed outcome
  with a clear message, and the rest goes on;
* while a batch runs, at least one worker must stay connected: when none has been for
  ``COLONLIGHT_CLUSTER_TIMEOUT`` seconds (every worker died, none restarted), the clips not finished fail with one
  line each instead of waiting for a worker forever;
* a clip the worker reports done must be visible here (its ``gammas.json``, with the reported frame count), else
  it is a failed outcome: outputs that landed on a worker's own disk are not taken for done.

The checks leave nothing behind: the pre-flight token file is removed before the first clip is sent (a token
file per clip would not do: a task whose result is lost with its worker is run again, and must pass again).

Progress: workers send ``start``/``frames``/``end`` events through the scheduler's event log (topic
``colonlight-progress``), best effort and throttled; the batch only depends on the task results.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import queue
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, TypedDict

from . import __version__
from .errors import ColonlightError, MissingExtraError, OptionError
from .extras import install_command
from .jobs import ClipJob, ClipOutcome, MethodSpec, ProgressFn, method_for, run_clip
from .pipeline import ClipOptions

#: The scheduler's event topic for progress events (one topic, so the scheduler's capped log does not grow per run).
PROGRESS_TOPIC = "colonlight-progress"
#: Prefix of the token file the pre-flight check writes into the output folder (and removes) to see that workers
#: share it.
MARKER_NAME = ".colonlight-cluster-check"
#: Seconds to wait for a worker's outputs to become visible here (network filesystems' attribute caches).
VISIBLE_TIMEOUT = 5.0
#: Seconds between two checks, during a batch, that a worker is still connected.
WORKER_CHECK_INTERVAL = 1.0
#: Seconds between two ``frames`` events of one clip.
FRAME_EVENT_INTERVAL = 0.5
#: At most this many input clips are checked on every worker before a batch (every task checks its own).
PROBE_SOURCES = 32
SHARED_FS_HINT = "the workers need the inputs, weights and outputs at the same paths (a shared filesystem)"


#: Longest ``COLONLIGHT_CLUSTER_TIMEOUT`` (a day): ``inf`` or ``1e300`` overflowed Dask's deadlines (``time_t``),
#: so that even a live scheduler was "unreachable"; NaN and negative values were silently taken as 0.5 s.
MAX_CLUSTER_TIMEOUT = 86400.0


def cluster_timeout() -> float:
    """Seconds to wait for the scheduler, for a first worker, and for a worker again when none is left mid-batch:
    ``COLONLIGHT_CLUSTER_TIMEOUT``, default 10, at least 0.5; a value that is not a number of seconds from 0 to a
    day is a one-line error."""
    raw = os.environ.get("COLONLIGHT_CLUSTER_TIMEOUT", "").strip()
    try:
        value = float(raw) if raw else 10.0
    except ValueError:
        value = math.nan
    if not 0 <= value <= MAX_CLUSTER_TIMEOUT:  # NaN fails this too
        raise OptionError(
            f"COLONLIGHT_CLUSTER_TIMEOUT must be a number of seconds from 0 to {MAX_CLUSTER_TIMEOUT:g}, got {raw!r}"
        )
    return max(0.5, value)


# ------------------------------------------------------------------------------------------ on the workers


@dataclass(frozen=True)
class TaskCheck:
    """What a task verifies on its worker before running the clip."""

    out_dir_seen: bool  # the client created the clip's output folder: the worker must see it
    source_seen: bool  # the client saw the source: if the worker does not, the filesystem is not shared
    model: dict[str, Any] | None  # the client's model_info(), when it built the method
    run: str | None  # progress events: run id, None for no events


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):  # not inside a worker (called directly, e.g. in a test)
        return "this process"


class ProgressEvent(TypedDict):
    """One progress event as a worker logs it under :data:`PROGRESS_TOPIC`."""

    run: str
    event: str
    clip: str
    data: dict[str, Any]


def _progress_sender(run: str) -> ProgressFn:
    """A ``progress`` callback that forwards events to the scheduler's event log (throttled, never raising)."""
    from distributed import get_worker

    worker = get_worker()
    last: dict[str, float] = {}

    def progress(event: str, clip: str, data: dict[str, Any]) -> None:
        now = time.monotonic()
        if event == "frames" and now - last.get(clip, 0.0) < FRAME_EVENT_INTERVAL:
            return
        last[clip] = now
        with contextlib.suppress(Exception):  # progress is best effort
            message: ProgressEvent = {"run": run, "event": event, "clip": clip, "data": dict(data)}
            worker.log_event(PROGRESS_TOPIC, message)

    return progress


def _read_token(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError):
        return None


def cluster_task(job: ClipJob, spec: MethodSpec, opts: ClipOptions, overwrite: bool, check: TaskCheck) -> ClipOutcome:
    """The Dask task of one clip: check that this worker shares the clip's files, then :func:`run_clip`."""
    worker = _worker_address()

    def failed(message: str) -> ClipOutcome:
        return ClipOutcome(job.name, str(job.source), "failed", error=message)

    if check.source_seen and not Path(job.source).exists():
        return failed(f"{job.source}: not found on worker {worker}; {SHARED_FS_HINT}")
    if check.out_dir_seen and not Path(job.out_dir).is_dir():
        return failed(f"{job.out_dir}: worker {worker} does not see this output folder; {SHARED_FS_HINT}")
    if check.model is not None:
        try:
            theirs = method_for(spec).model_info()
        except Exception:  # noqa: BLE001 - run_clip reports a method that cannot be built
            theirs = check.model
        if theirs != check.model:
            return failed(
                f"{job.source}: worker {worker} loaded model {_model_label(theirs)}, this run uses "
                f"{_model_label(check.model)}; give every worker the same weights"
            )
    progress = _progress_sender(check.run) if check.run else None
    return run_clip(job, spec, opts, overwrite, progress)


def _model_label(info: dict[str, Any] | None) -> str:
    if not info:
        return "none"
    return f"{info.get('name')} (sha256 {str(info.get('sha256'))[:12]})"


def _probe(markers: list[tuple[str, str]], sources: list[str], files: list[tuple[str, str]]) -> dict[str, Any]:
    """Run on every worker before a batch: version, and which of this client's paths the worker cannot use."""
    problems: list[str] = []
    for path, token in markers:
        folder = Path(path).parent
        if _read_token(Path(path)) != token:
            problems.append(f"cannot see the output folder {folder}")
            continue
        probe = folder / f".colonlight-cluster-write-{uuid.uuid4().hex}"
        try:
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            problems.append(f"cannot write to the output folder {folder} ({exc.strerror or exc})")
    for what, path in files:
        if not Path(path).exists():
            problems.append(f"cannot see the {what} {path}")
    missing = [s for s in sources if not Path(s).exists()]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        problems.append(f"cannot see the input {missing[0]}{more}")
    return {"version": __version__, "problems": problems}


# ------------------------------------------------------------------------------------------ on the client


def absolute_job(job: ClipJob) -> ClipJob:
    """``job`` with absolute paths: a worker's working directory is not this process's."""
    source, out_dir = Path(job.source), Path(job.out_dir)
    if source.is_absolute() and out_dir.is_absolute():
        return job
    return dataclasses.replace(job, source=source.absolute(), out_dir=out_dir.absolute(), shown=job.label)


def absolute_spec(spec: MethodSpec) -> MethodSpec:
    """``spec`` with a relative weights path made absolute (for the same reason as :func:`absolute_job`)."""
    options = tuple(
        (k, str(Path(v).absolute())) if k == "weights" and isinstance(v, str) and not Path(v).is_absolute() else (k, v)
        for k, v in spec.options
    )
    return spec if options == spec.options else MethodSpec(spec.name, options)


def _out_root(job: ClipJob) -> Path:
    """The batch's output folder: ``job.out_dir`` less the clip's relative name."""
    depth = len(PurePosixPath(job.name).parts)
    out = Path(job.out_dir)
    return out.parents[depth - 1] if 0 < depth <= len(out.parents) else out.parent


class ClusterRunner:
    """A connection to a Dask scheduler that runs clips as tasks (used by the batch and by the service).

    ``submit`` returns the Dask future of one clip (``.result()`` gives its :class:`ClipOutcome`, which carries
    any per-clip failure); ``check`` runs the pre-flight checks of a batch; ``close`` disconnects.
    """

    def __init__(self, address: str, timeout: float | None = None) -> None:
        try:
            from distributed import Client
        except ImportError:
            raise MissingExtraError(
                f"running on a cluster needs Dask distributed: {install_command('cluster')}"
            ) from None
        self.address = address
        self.timeout = cluster_timeout() if timeout is None else timeout
        try:
            from distributed.comm.addressing import get_address_host_port, parse_address
            from distributed.comm.registry import get_backend

            scheme = parse_address(address)[0]
            get_backend(scheme)
            if scheme != "inproc":  # a network address needs its port: Client() half-made by a bad one hangs at exit
                get_address_host_port(address)
        except (ValueError, TypeError) as exc:
            raise ColonlightError(
                f"{address!r} is not a Dask scheduler address such as tcp://HOST:8786 ({_one_line(exc)})"
            ) from None
        try:
            if scheme != "inproc":
                _handshake(address, self.timeout)
            self.client = Client(address, timeout=self.timeout, set_as_default=False)
        except Exception as exc:  # noqa: BLE001 - whatever the other end does, it is not a scheduler we can use
            if isinstance(exc, TimeoutError):
                why = "it accepted the connection but sent no Dask handshake"
            elif isinstance(exc, MemoryError):  # e.g. an HTTP server's answer, read as a frame length
                why = "its answer is not Dask's protocol"
            else:  # refused, unreachable, a tls:// address without TLS settings
                why = _one_line(exc)
            raise ColonlightError(
                f"cannot reach the Dask scheduler at {address} within {self.timeout:g} s "
                f"({why}); is `dask scheduler` running there?"
            ) from None
        self._model_cache: dict[MethodSpec, dict[str, Any] | None] = {}

    # -- context manager
    def __enter__(self) -> ClusterRunner:  # noqa: PYI034 - Python 3.10 has no typing.Self
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with contextlib.suppress(Exception):  # closing a lost connection must not hide the real outcome
            self.client.close(timeout=self.timeout)

    def wait_for_workers(self, timeout: float | None = None) -> int:
        """Wait until at least one worker is connected; return how many are."""
        timeout = self.timeout if timeout is None else timeout
        try:
            self.client.wait_for_workers(1, timeout=timeout)
        except (TimeoutError, OSError):
            raise ColonlightError(
                f"no Dask worker is connected to the scheduler at {self.address} (waited {timeout:g} s); "
                f"start some with `dask worker {self.address}`"
            ) from None
        except Exception as exc:  # noqa: BLE001 - e.g. the scheduler went away meanwhile
            raise ColonlightError(f"lost the Dask scheduler at {self.address}: {_one_line(exc)}") from None
        count = self.connected_workers()
        if count is None:
            raise ColonlightError(f"lost the Dask scheduler at {self.address} after a worker connected")
        return count

    def connected_workers(self) -> int | None:
        """How many workers are connected now; ``None`` when the scheduler does not answer (its loss cancels the
        batch's futures, which then fail on their own)."""
        try:
            return len(self.client.scheduler_info(n_workers=-1).get("workers", {}))
        except Exception:  # noqa: BLE001 - a lost scheduler, a closing client
            return None

    def _expected_model(self, spec: MethodSpec) -> dict[str, Any] | None:
        """This machine's model_info() for ``spec`` (None when it cannot build the method: the workers then decide)."""
        if spec not in self._model_cache:
            try:
                self._model_cache[spec] = method_for(spec).model_info()
            except Exception:  # noqa: BLE001
                self._model_cache[spec] = None
        return self._model_cache[spec]

    def check(self, jobs: Sequence[ClipJob], spec: MethodSpec) -> None:
        """Pre-flight: every connected worker runs this colonlight version and sees our outputs, weights and inputs."""
        self.wait_for_workers()
        jobs, spec = [absolute_job(j) for j in jobs], absolute_spec(spec)
        token = uuid.uuid4().hex
        markers: list[tuple[str, str]] = []
        written: list[Path] = []
        try:
            for root in sorted({_out_root(j) for j in jobs}):
                path = root / f"{MARKER_NAME}-{token}"
                try:
                    root.mkdir(parents=True, exist_ok=True)
                    path.write_text(token, encoding="utf-8")
                except OSError:
                    continue  # this machine cannot write there either: the clips will say so
                written.append(path)
                markers.append((str(path), token))
            files = [("weights file", str(v)) for k, v in spec.options if k == "weights" and Path(str(v)).exists()]
            sources = [str(j.source) for j in jobs if Path(j.source).exists()][:PROBE_SOURCES]
            try:
                results = self.client.run(_probe, markers, sources, files, on_error="return")
            except Exception as exc:  # noqa: BLE001
                raise ColonlightError(f"cannot run the checks on the Dask workers: {_one_line(exc)}") from None
        finally:
            for path in written:
                path.unlink(missing_ok=True)
        problems = []
        for addr, res in sorted(results.items()):
            if isinstance(res, BaseException):
                problems.append(
                    f"worker {addr} cannot run colonlight ({_one_line(res)}); "
                    f"install colonlight {__version__} on every worker"
                )
            elif res.get("version") != __version__:
                problems.append(f"worker {addr} runs colonlight {res.get('version')}, this machine {__version__}")
            else:
                problems.extend(f"worker {addr} {p}" for p in res["problems"])
        if problems:
            hint = f"; {SHARED_FS_HINT}" if any("cannot see" in p or "cannot write" in p for p in problems) else ""
            more = f" (and {len(problems) - 1} more problem(s))" if len(problems) > 1 else ""
            raise ColonlightError(f"{problems[0]}{more}{hint}")

    def submit(
        self,
        job: ClipJob,
        spec: MethodSpec,
        opts: ClipOptions,
        overwrite: bool = False,
        *,
        run: str | None = None,
    ) -> Any:
        """Send one clip to the cluster; returns its ``distributed.Future`` (``.result()`` is a ClipOutcome).

        Relative paths are made absolute against this process's working directory (so the outcome's and
        gammas.json's ``source`` are absolute). ``run``: an id under which workers send progress events to
        :data:`PROGRESS_TOPIC` (None: no events).
        """
        job, spec = absolute_job(job), absolute_spec(spec)
        try:
            Path(job.out_dir).mkdir(parents=True, exist_ok=True)  # a local run creates it as well
            out_dir_seen = True
        except OSError:
            out_dir_seen = False  # cannot create it here: the worker's run will report why
        check = TaskCheck(out_dir_seen, Path(job.source).exists(), self._expected_model(spec), run)
        return self.client.submit(
            cluster_task,
            job,
            spec,
            opts,
            overwrite,
            check,
            key=f"colonlight-clip-{uuid.uuid4().hex}-{job.name}",
            pure=False,
        )

    def outcome(self, job: ClipJob, future: Any) -> ClipOutcome:
        """The outcome of a finished future, checked: a task that failed on the cluster, or a clip done on a worker
        whose outputs this machine cannot see, becomes a failed outcome."""
        try:
            result = future.result()
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt):
                raise
            name = type(exc).__name__
            if name == "KilledWorker":
                why = "its workers died too often while running it (see distributed.scheduler.allowed-failures)"
            elif name in ("CancelledError", "FutureCancelledError"):
                why = f"the task was cancelled (lost the Dask scheduler at {self.address}?)"
            else:
                why = f"{name}: {_one_line(exc)}"
            return ClipOutcome(job.name, str(job.source), "failed", error=f"{job.source}: cluster task failed: {why}")
        if not isinstance(result, ClipOutcome):  # pragma: no cover - a worker with another colonlight
            return ClipOutcome(
                job.name, str(job.source), "failed", error=f"{job.source}: unexpected task result {result!r}"
            )
        if result.status == "done" and not _visible_here(absolute_job(job), result.frames):
            return ClipOutcome(
                job.name,
                str(job.source),
                "failed",
                seconds=result.seconds,
                error=f"{job.out_dir}: the worker wrote this clip where this machine cannot see it; {SHARED_FS_HINT}",
            )
        return result


def _handshake(address: str, timeout: float) -> None:
    """Connect to ``address`` and exchange Dask's handshake within ``timeout`` seconds, or raise.

    Dask's ``Client`` bounds the connection by its timeout but not the handshake read after it: a server that
    accepts and stays silent held ``Client()`` (and the batch) forever, and one that answers something else (an
    HTTP server) made it read a frame length of exabytes (a MemoryError traceback). Run in a thread of its own: the
    caller may be inside an event loop (the service's start-up).
    """
    import asyncio
    import threading

    from distributed.comm.core import connect
    from distributed.security import Security

    async def shake() -> None:
        args = Security().get_connection_args("client")
        # connect() gives up on an address that refuses within ``timeout`` (an OSError); this bounds the handshake
        comm = await asyncio.wait_for(connect(address, timeout=timeout, **args), timeout + 1)
        await comm.close()

    failure: list[BaseException] = []

    def run() -> None:
        try:
            asyncio.run(shake())
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            failure.append(exc)

    thread = threading.Thread(target=run, name="colonlight-dask-handshake", daemon=True)
    thread.start()
    thread.join(timeout + 6)
    if thread.is_alive():
        raise TimeoutError(f"no Dask handshake from {address} within {timeout:g} s")
    if failure:
        raise failure[0]


def _visible_here(job: ClipJob, frames: int) -> bool:
    """True when this machine sees the clip's complete outputs (gammas.json with ``frames`` frames)."""
    from .atomic import read_json
    from .pipeline import GAMMAS_FILE

    deadline = time.monotonic() + VISIBLE_TIMEOUT
    while True:
        try:
            record = read_json(job.out_dir / GAMMAS_FILE)
            if record.get("frame_count") == frames:
                return True
        except (OSError, ValueError, AttributeError):
            pass
        if time.monotonic() > deadline:
            return False
        time.sleep(0.2)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def run_on_cluster(
    address: str,
    jobs: Sequence[ClipJob],
    spec: MethodSpec,
    opts: ClipOptions,
    overwrite: bool,
    done: Callable[[ClipOutcome], None],
    progress: ProgressFn | None,
) -> None:
    """Run ``jobs`` on the Dask cluster at ``address``, one task per clip; ``done(outcome)`` in completion order.

    Raises :class:`ColonlightError` (one line) when the scheduler is unreachable, no worker is connected, or the
    workers do not share this machine's files; per-clip problems are failed outcomes, as in a local run.
    """
    if not jobs:
        return
    with ClusterRunner(address) as runner:  # first: it says in one line when Dask is not installed
        from distributed import as_completed

        runner.check(jobs, spec)
        run = uuid.uuid4().hex if progress else None
        events: queue.SimpleQueue[ProgressEvent] = queue.SimpleQueue()
        if run:
            runner.client.subscribe_topic(
                PROGRESS_TOPIC, lambda ev: events.put(ev[1]) if ev[1].get("run") == run else None
            )
        running: set[str] = set()
        finished: set[str] = set()

        def drain() -> None:
            while progress is not None:
                try:
                    ev = events.get_nowait()
                except queue.Empty:
                    return
                clip, event = ev.get("clip"), ev.get("event")
                if clip in finished or clip is None:
                    continue  # late events of a finished clip
                if event == "start" and clip in running:
                    progress("end", clip, {})  # a retry after a worker died: close the old bar
                if event == "start":
                    running.add(clip)
                elif event == "end":
                    if clip not in running:
                        continue
                    running.discard(clip)
                elif clip not in running:
                    continue
                progress(event, clip, ev.get("data") or {})

        def settle(job: ClipJob, outcome: ClipOutcome) -> None:
            outcome.source = str(job.source)  # as given here (the task saw it made absolute)
            if progress is not None and job.name in running:
                running.discard(job.name)
                progress("end", job.name, {})
            finished.add(job.name)
            done(outcome)

        futures: dict[Any, ClipJob] = {}
        try:
            for job in jobs:
                futures[runner.submit(job, spec, opts, overwrite, run=run)] = job
            order = {f: i for i, f in enumerate(futures)}
            pending = set(futures)
            completed = as_completed(list(futures), loop=runner.client.loop)
            no_worker_since: float | None = None
            next_check = time.monotonic() + WORKER_CHECK_INTERVAL
            while pending:
                ready = completed.next_batch(block=False) if completed.has_ready() else []
                drain()
                if not ready:
                    # Dask holds a task with no worker to run it forever: every worker dead means a batch that
                    # never ends, so the clips not finished fail once none has been connected for the timeout.
                    now = time.monotonic()
                    if now >= next_check:
                        next_check = now + WORKER_CHECK_INTERVAL
                        no_worker_since = (no_worker_since or now) if runner.connected_workers() == 0 else None
                        if no_worker_since is not None and now - no_worker_since >= runner.timeout:
                            with contextlib.suppress(Exception):  # best effort: no worker runs them anyway
                                runner.client.cancel(list(pending), force=True)
                            for fut in sorted(pending, key=order.__getitem__):
                                settle(futures[fut], _no_worker_outcome(runner, futures[fut]))
                            return
                    time.sleep(0.1)
                    continue
                for fut in sorted(ready, key=order.__getitem__):  # a batch of results: in job order
                    pending.discard(fut)
                    settle(futures[fut], runner.outcome(futures[fut], fut))
        except BaseException:
            if futures:
                runner.client.cancel(list(futures), force=True)
            raise
        finally:
            if run:
                with contextlib.suppress(Exception):
                    runner.client.unsubscribe_topic(PROGRESS_TOPIC)


def _no_worker_outcome(runner: ClusterRunner, job: ClipJob) -> ClipOutcome:
    """A clip left when no worker has been connected for the timeout: failed, in one line."""
    why = (
        f"no Dask worker has been connected to the scheduler at {runner.address} for {runner.timeout:g} s "
        "(did they die?); the clip was not finished: start workers and rerun to resume"
    )
    return ClipOutcome(job.name, str(job.source), "failed", error=f"{job.source}: {why}")


__all__ = ["PROGRESS_TOPIC", "ClusterRunner", "cluster_task", "cluster_timeout", "run_on_cluster"]
