"""One live stream, start to end: a reader thread feeds a bounded hand-off, the processing loop enhances each frame
with one recurrent state for the whole stream and writes it to the outputs; a summary at the end.

The state is kept across reconnects: a reconnect is the same procedure seen again after a gap, and restarting
would send the next two frames through unchanged (the model's seeds), a visible jump in brightness. A stream can
be stopped at any moment from another thread or a signal handler (:meth:`LiveStream.stop`): the frame in hand is
finished, the outputs are closed complete, and the summary is made.
"""

from __future__ import annotations

import atexit
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO

from .. import __version__
from ..atomic import write_json_atomic
from ..content import DEFAULT_CONTENT, content_setting, live_content_stream, parse_content
from ..errors import ColonlightError, InputError, OptionError
from ..limits import DEFAULT_FPS, DEFAULT_JPEG_QUALITY
from ..methods.base import FrameResult, Method
from ..pipeline import FRAMES_DIR
from ..provenance import library_versions
from .handoff import DROP_POLICIES, FrameHandoff, HandoffClosed
from .outputs import LOG_FILE, SUMMARY_FILE, FrameFolder, FrameOutput, GammaLog, PipeClosed, open_pipe
from .reader import DEADLINE_GRACE_S, LiveFrame, StreamReader
from .source import SourceSpec
from .stats import LatencyStats, StreamSummary

#: Frames that may wait between the reader and the processing loop (each a full RGB frame: 6 MB at 1080p).
DEFAULT_BUFFER = 2
#: Seconds without data after which a network source or device counts as lost.
DEFAULT_TIMEOUT_S = 5.0
#: The longest --timeout: PyAV turns it into FFmpeg's microseconds, and Python's thread waits refuse more than
#: ``threading.TIMEOUT_MAX`` (~292 years on Linux) with an OverflowError.
MAX_TIMEOUT_S = 1e9
#: How long the end of a run waits for its reader thread (longer for an open the duration bounds: see
#: :meth:`LiveStream._reader_wait_s`). A reader blocked in a read of a network source gone silent (its timeout is
#: fixed when the connection opens) is left to end by itself: a stop or the duration ends the run now, not up to a
#: --timeout later. (Standard input's reads see the stop: see :class:`~colonlight.live.source.StdinInput`.)
READER_JOIN_S = 0.5
_POLL_S = 0.1  # how often the processing loop looks at the stop flag while waiting for a frame

#: Readers that a run left in a read, each with the perf_counter time by which its own timeout ends it.
_left_readers: list[tuple[threading.Thread, float]] = []
_left_readers_lock = threading.Lock()


def _leave_reader(thread: threading.Thread, until: float) -> None:
    with _left_readers_lock:
        _left_readers[:] = [(t, u) for t, u in _left_readers if t.is_alive()]  # constant memory in a long process
        _left_readers.append((thread, until))


@atexit.register
def _join_left_readers() -> None:
    """At exit, wait for every reader still in a read (each for at most its timeout + 1 s, as a run once did):
    the interpreter must not be torn down under a thread inside FFmpeg, whose interrupt callback takes the GIL.
    (Measured: a script that froze its objects with ``gc.freeze()``, as the CLI does, and ended while an RTSP
    listener waited for its next publisher died of SIGSEGV in 2 runs of 3.)"""
    with _left_readers_lock:
        left = list(_left_readers)
    for thread, until in left:
        thread.join(max(0.0, until - time.perf_counter()))


@dataclass(frozen=True)
class StreamOptions:
    """How a stream is read and processed."""

    fps: float | None = DEFAULT_FPS  # None or 0: every source frame
    realtime: bool = False  # pace a file at its own rate
    drop: str = "auto"  # oldest | newest | never | auto (never for a file read as fast as possible, else oldest)
    buffer: int = DEFAULT_BUFFER
    reconnect: bool = False
    timeout_s: float = DEFAULT_TIMEOUT_S
    duration_s: float | None = None  # stop after this many seconds
    content: str = DEFAULT_CONTENT  # auto, full or a mask's path (colonlight.content.parse_content)

    def drop_policy(self, spec: SourceSpec) -> str:
        if self.drop != "auto":
            return self.drop
        return "oldest" if spec.is_live or self.realtime else "never"

    def __post_init__(self) -> None:
        if self.drop != "auto" and self.drop not in DROP_POLICIES:
            raise OptionError(f"drop must be auto or one of {', '.join(DROP_POLICIES)}, got {self.drop!r}")
        if self.buffer < 1:
            raise OptionError(f"buffer must be >= 1, got {self.buffer}")
        # not `<= 0` alone: NaN passes it, and infinity (or 1e308) then crashed the end of the run (OverflowError
        # from the reader thread's join) after the frames were out, with a traceback and no stream.json
        if not 0 < self.timeout_s <= MAX_TIMEOUT_S:
            raise OptionError(
                f"timeout must be a number of seconds above 0 and at most {MAX_TIMEOUT_S:.0f}, got {self.timeout_s}"
            )
        # `not > 0`, so that NaN is refused too: a 0 s duration read nothing and failed as a stream that "gave no
        # frame"; NaN never ended; a negative one ended at once (infinity is no limit, and allowed)
        if self.duration_s is not None and not self.duration_s > 0:
            raise OptionError(f"duration must be a number of seconds above 0, got {self.duration_s}")
        # stored parsed, as ClipOptions stores it: "AUTO" kept as given was taken for a mask's path when the record
        # was written, and stream.json was lost to "No such file or directory"
        object.__setattr__(self, "content", parse_content(self.content))


@dataclass(frozen=True)
class OutputPlan:
    """Which outputs a stream writes; each is opened at the first enhanced frame, so a source that never delivers
    leaves nothing behind."""

    out_dir: Path | None = None  # OUT/gammas.jsonl, OUT/stream.json and (with frames) OUT/frames/
    frames: bool = True
    format: str = "jpg"
    quality: int = DEFAULT_JPEG_QUALITY
    keep: int = 0  # newest frames kept in OUT/frames (0: all)
    pipe: str | None = None  # y4m | mpegts
    pipe_file: BinaryIO | None = None  # where the pipe goes (the CLI: standard output)


def prepare_output_dir(out_dir: Path, overwrite: bool) -> None:
    """Refuse to mix two streams in one folder: InputError if OUT holds a stream's outputs, unless ``overwrite``
    (then the old log, summary and frames go)."""
    out_dir = Path(out_dir)
    existing = next((p for p in (out_dir, *out_dir.parents) if os.path.lexists(p)), None)
    if existing is not None and not existing.is_dir():  # found now, not as a traceback at the first frame
        what = "is" if existing == out_dir else f"lies under {existing}, which is"
        raise InputError(f"{out_dir}: {what} a file, not a folder (--output names a folder)")
    frames = out_dir / FRAMES_DIR
    try:
        old = [p for p in (out_dir / LOG_FILE, out_dir / SUMMARY_FILE) if p.exists()]
        old_frames = [p for p in frames.iterdir() if p.name.partition(".")[0].isdigit()] if frames.is_dir() else []
    except OSError as exc:  # a name past NAME_MAX (ENAMETOOLONG): Path.exists raises it, a traceback before
        raise InputError(f"{out_dir}: cannot use the output folder: {exc.strerror or exc}") from None
    if not (old or old_frames):
        return
    if not overwrite:
        raise InputError(f"{out_dir}: already holds a stream's outputs (use --overwrite or another --output)")
    for p in old + old_frames:
        p.unlink(missing_ok=True)


class LiveStream:
    """Enhance ``spec`` with ``method`` into the outputs of ``plan``; :meth:`run` returns the summary."""

    def __init__(
        self,
        spec: SourceSpec,
        method: Method,
        opts: StreamOptions = StreamOptions(),
        plan: OutputPlan = OutputPlan(),
        *,
        notify: Callable[[str], None] | None = None,
        on_frame: Callable[[StreamSummary], None] | None = None,
    ) -> None:
        if spec.kind == "file" and opts.reconnect:
            raise InputError(f"{spec.text}: --reconnect applies to network streams and devices, not to a file")
        if spec.kind == "stdin" and opts.reconnect:
            raise InputError("-: --reconnect applies to network streams and devices, not to standard input")
        self.spec, self.method, self.opts, self.plan = spec, method, opts, plan
        self.summary = StreamSummary(source=spec.text)
        self.latency = LatencyStats()
        self._stop = threading.Event()
        self._stop_reason = "stopped"
        self.handoff: FrameHandoff[LiveFrame] = FrameHandoff(opts.buffer, opts.drop_policy(spec))
        self.reader = StreamReader(
            spec,
            self.handoff,
            self.summary,
            self._stop,
            fps=opts.fps or None,
            realtime=opts.realtime,
            reconnect=opts.reconnect,
            timeout_s=opts.timeout_s,
            notify=notify,
        )
        self.on_frame = on_frame
        self._outputs: list[FrameOutput] = []
        self._names: dict[int, str] = {}  # id(output) -> how an error line names it
        self._where = ""  # the output being opened (for an error line)
        self._log: GammaLog | None = None
        self._opened = False
        self._thread: threading.Thread | None = None  # the reader's, once run() has started it

    def stop(self, reason: str = "stopped") -> None:
        """End the stream soon (thread- and signal-safe): the frame in hand is finished, the rest is dropped."""
        self._stop_reason = reason
        self._stop.set()

    # ------------------------------------------------------------------------------------------ outputs

    def _open_outputs(self) -> None:
        self._opened = True
        plan = self.plan
        # The pipe goes first: it is the output that may refuse a frame (a y4m or H.264 stream cannot change
        # size), and a refused frame must not reach the frame folder either (no frame without its log line).
        if plan.pipe is not None and plan.pipe_file is not None:
            rate = Fraction(self.opts.fps).limit_denominator(1001) if self.opts.fps else (self.reader.source_rate or 30)
            pipe = open_pipe(plan.pipe, plan.pipe_file, Fraction(rate))
            self._outputs.append(pipe)
            self._names[id(pipe)] = f"standard output (--pipe {plan.pipe})"
        if plan.out_dir is not None:
            self._where = str(plan.out_dir)
            plan.out_dir.mkdir(parents=True, exist_ok=True)
            if plan.frames:
                folder = FrameFolder(plan.out_dir / FRAMES_DIR, plan.format, plan.quality, plan.keep)
                self._outputs.append(folder)
                self._names[id(folder)] = str(plan.out_dir / FRAMES_DIR)
            self._where = str(plan.out_dir / LOG_FILE)
            self._log = GammaLog(plan.out_dir / LOG_FILE)
        self._where = ""

    def _write_error(self, where: str, exc: OSError) -> ColonlightError:
        """One line for an output that cannot be written (a full disk, a folder gone, a closed descriptor)."""
        cause = exc.strerror or str(exc) or type(exc).__name__
        return ColonlightError(f"{where}: cannot write ({cause}); what was written before is complete")

    def _close_outputs(self) -> None:
        first_error: BaseException | None = None
        for out in self._outputs:
            try:
                out.close()
            except OSError as exc:
                first_error = first_error or self._write_error(self._names.get(id(out), "an output"), exc)
            except Exception as exc:  # noqa: BLE001 - close the others, report the first
                first_error = first_error or exc
        if self._log is not None:
            self._log.close()
        if first_error is not None:
            raise first_error

    # ------------------------------------------------------------------------------------------ the loop

    def run(self) -> StreamSummary:
        """Read, enhance and write until the source ends, :meth:`stop` is called or the duration is reached."""
        t0 = time.perf_counter()
        if self.opts.duration_s is not None:
            self.reader.deadline = t0 + self.opts.duration_s
        thread = self._thread = threading.Thread(target=self.reader.run, name="colonlight-live-read", daemon=True)
        # one recurrent state for the whole stream, reconnects included; the content area found on the first frame
        stream = live_content_stream(self.method, self.opts.content)
        waiting: deque[LiveFrame] = deque()
        last_progress = 0.0
        ended_by_source = False
        thread.start()
        try:
            while True:
                if self._stop.is_set():
                    self.summary.end = self._stop_reason
                    break
                if self.opts.duration_s is not None and time.perf_counter() - t0 >= self.opts.duration_s:
                    self.summary.end = "duration reached"
                    break
                try:
                    item = self.handoff.get(_POLL_S)
                except HandoffClosed:
                    ended_by_source = True
                    break
                if item is None:
                    continue
                waiting.append(item)
                self._emit(stream.push(item.image), waiting)
                if self.on_frame is not None and time.perf_counter() - last_progress > 0.25:
                    last_progress = time.perf_counter()
                    self._count_drops()
                    self.on_frame(self.summary)
            if ended_by_source:
                self._emit(stream.flush(), waiting)
                if self.reader.error is not None:
                    raise self.reader.error
                self.summary.end = self._stop_reason if self._stop.is_set() else (self.reader.ended or "source ended")
        except PipeClosed as exc:
            self.summary.end = str(exc)
        except ColonlightError as exc:
            self.summary.end = "error"
            self.summary.error = str(exc)
        finally:
            self._stop.set()
            self.handoff.cancel()
            ended = time.perf_counter()
            thread.join(timeout=self._reader_wait_s())
            if thread.is_alive():  # still in a read: what it counts from now on goes to a summary no one reads
                self.summary = replace(self.summary)
                _leave_reader(thread, ended + self.opts.timeout_s + 1.0)
            try:
                self._close_outputs()
            except PipeClosed:
                pass
            except (ColonlightError, OSError) as exc:
                self.summary.error = self.summary.error or f"closing the outputs failed: {exc}"
            self.summary.seconds = round(time.perf_counter() - t0, 3)
            # every chosen frame that was not output was dropped: by the hand-off, or in hand when the stream stopped
            self.summary.frames_dropped = max(self.handoff.dropped, self.summary.frames_in - self.summary.frames_out)
            self.summary.take_latency(self.latency)
            self._fail_if_nothing_came()
            if self.plan.out_dir is not None and self._opened:
                try:
                    write_json_atomic(self.plan.out_dir / SUMMARY_FILE, self.record())  # whole or not at all
                except OSError as exc:
                    error = self._write_error(str(self.plan.out_dir / SUMMARY_FILE), exc)
                    self.summary.error = self.summary.error or str(error)
        return self.summary

    def _reader_wait_s(self) -> float:
        """How long the end of the run waits for the reader: READER_JOIN_S; when the duration ended the run, until an
        open it bounds has given up (DEADLINE_GRACE_S after the deadline), so that a listener's port is free again
        when :meth:`run` returns in that common case. Never longer than the reader's own timeout + 1 s."""
        wait = READER_JOIN_S
        deadline, now = self.reader.deadline, time.perf_counter()
        if deadline is not None and now >= deadline:  # not for a stop long before it (a Ctrl-C 1 h into 2 h)
            wait = max(wait, deadline + DEADLINE_GRACE_S + READER_JOIN_S - now)
        return min(self.opts.timeout_s + 1.0, wait)

    def wait_source_closed(self, timeout_s: float | None = None) -> bool:
        """Wait up to ``timeout_s`` (None: for good) for the source to be closed after :meth:`run`; True once it is.
        A read the run left to time out by itself holds the source, a UDP or RTSP listener's port for one, for up
        to the stream's timeout."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
        return thread is None or not thread.is_alive()

    def _fail_if_nothing_came(self) -> None:
        """A stream that ended by itself or by its duration without one decoded frame failed: to a script it is not
        a recording that went well (nothing was written). A stop by the caller is not a failure."""
        if self.summary.error or self.summary.frames_decoded:
            return
        if self.summary.end == "duration reached":
            self.summary.error = f"{self.spec.text}: no video frame arrived in the {self.opts.duration_s:g} s duration"
        elif self.summary.end == "source ended":
            self.summary.error = f"{self.spec.text}: the source ended before any video frame arrived"

    def _count_drops(self) -> None:
        self.summary.frames_dropped = self.handoff.dropped

    def _emit(self, results: list[FrameResult], waiting: deque[LiveFrame]) -> None:
        for res in results:
            f = waiting.popleft()
            if not self._opened:
                try:
                    self._open_outputs()
                except OSError as exc:  # e.g. a read-only or full file system
                    raise self._write_error(self._where or "an output", exc) from exc
            for out in self._outputs:
                try:
                    out.write(f.index, res.frame)
                except InputError as exc:  # a pipe that cannot take this frame (its size changed)
                    raise InputError(f"{self.spec.text}: {exc}") from exc
                except OSError as exc:
                    raise self._write_error(self._names.get(id(out), "an output"), exc) from exc
            done = time.perf_counter()
            latency = done - f.arrival
            self.latency.add(latency)
            self.summary.frames_out += 1
            if self._log is not None:
                record: dict[str, Any] = {
                    "index": f.index,
                    "source_time_s": round(f.source_time_s, 6),
                    "arrival": round(f.arrival_wall, 6),
                    "output": round(f.arrival_wall + latency, 6),
                    "latency_ms": round(latency * 1000.0, 3),
                    "gamma": res.gamma,
                }
                if f.connection > 1:
                    record["connection"] = f.connection
                record.update(res.info)
                try:
                    self._log.write(record)
                except OSError as exc:
                    raise self._write_error(str(self._log.path), exc) from exc

    def record(self) -> dict[str, Any]:
        """``stream.json``: the source, the settings and the summary."""
        options = {**asdict(self.opts), "content": content_setting(self.opts.content), "drop": self.handoff.policy}
        return {
            "source": self.spec.text,
            "kind": self.spec.kind,
            "method": self.method.name,
            "model": self.method.model_info(),
            "parameters": self.method.parameters(),
            "options": options,
            "colonlight_version": __version__,
            "versions": library_versions(),
            "summary": asdict(self.summary),
        }
