"""The reader thread's work: decode the source, time its frames, choose them at the output rate, convert the chosen
ones to RGB and hand them over; reopen a lost network source with backoff.

Runs beside the processing loop (FFmpeg decodes and converts without holding the GIL), so decoding a 1080p frame
overlaps the network and the writers. Memory is constant: at most the two frames the frame choice may still name,
plus the one being decoded.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import av
import numpy as np
from av.video.reformatter import VideoReformatter

from ..errors import InputError
from .choice import MAX_GAP_S, Choice, FrameChoice
from .handoff import FrameHandoff
from .source import SourceSpec, open_source, source_error
from .stats import StreamSummary

log = logging.getLogger(__name__)

#: Reconnect delays: the first retry after BACKOFF_START_S, doubling up to BACKOFF_MAX_S; back to the start once a
#: connection has delivered frames.
BACKOFF_START_S = 0.5
BACKOFF_MAX_S = 8.0
#: The rate assumed for a source that states none (raw H.264 without timing information).
FALLBACK_RATE = Fraction(25)
#: How far past its deadline a connection's waits may run: the processing loop, which looks at the clock every
#: tenth of a second, must see the duration end before the reader reports a source that never answered.
DEADLINE_GRACE_S = 0.5
#: The shortest wait for a source: FFmpeg needs a moment even to fail.
MIN_WAIT_S = 0.05


@dataclass(frozen=True)
class LiveFrame:
    """A chosen frame on its way to processing."""

    image: np.ndarray  # (H, W, 3) uint8 RGB
    index: int  # output index, from 0, across reconnects
    source_time_s: float  # the source frame's time on the stream's timeline (continues across reconnects)
    arrival_wall: float  # time.time() when the frame left the decoder (or was released by --realtime pacing)
    arrival: float  # time.perf_counter() at the same moment: latency is measured from here
    connection: int  # 1 for the first connection, 2 after the first reconnect, ...


@dataclass
class _Held:
    frame: Any  # av.VideoFrame
    time_s: float
    arrival_wall: float
    arrival: float
    rgb: np.ndarray | None = None


class StreamReader:
    """Reads ``spec`` until it ends (or forever with ``reconnect``), putting chosen frames into ``handoff``."""

    def __init__(
        self,
        spec: SourceSpec,
        handoff: FrameHandoff[LiveFrame],
        summary: StreamSummary,
        stop: threading.Event,
        *,
        fps: float | None,
        realtime: bool,
        reconnect: bool,
        timeout_s: float,
        notify: Callable[[str], None] | None = None,
    ) -> None:
        self.spec = spec
        self.handoff = handoff
        self.summary = summary
        self.stop = stop
        self.realtime = realtime
        self.reconnect = reconnect
        self.timeout_s = timeout_s
        self.notify = notify or (lambda message: log.info("%s", message))
        self.choice = FrameChoice(fps)
        self.source_rate: Fraction | None = None  # the first connection's frame rate (for pipes at --fps 0)
        self.error: BaseException | None = None
        self.ended = ""  # why reading stopped
        self._timeline_end = 0.0  # where the last segment ended on the stream's timeline (seconds)
        self._last_arrival: float | None = None  # perf_counter of the last decoded frame
        self._pace_origin: float | None = None  # perf_counter at timeline 0, for --realtime
        self._ahead_max: float | None = None  # max over frames of (timeline time - arrival time): see _track_lag
        self.deadline: float | None = None  # perf_counter when the run ends (its duration); None: no end

    def _wait_limit(self) -> float:
        """The timeout of the next connection's open and reads: ``timeout_s``, but never past the run's deadline, so
        that a source that never answers does not hold a run with a duration for a whole timeout beyond it."""
        if self.deadline is None:
            return self.timeout_s
        left = self.deadline + DEADLINE_GRACE_S - time.perf_counter()
        return max(MIN_WAIT_S, min(self.timeout_s, left))

    # ------------------------------------------------------------------------------------------ thread body

    def run(self) -> None:
        try:
            self._connections()
        except BaseException as exc:  # noqa: BLE001 - handed to the processing loop, which reports it
            self.error = exc
        finally:
            self.handoff.close()

    def _connections(self) -> None:
        backoff = BACKOFF_START_S
        self.notify(f"{self.spec.text}: waiting for frames")
        while not self.stop.is_set():
            try:
                container, stream = open_source(self.spec, self._wait_limit(), self.stop)
            except InputError as exc:
                if not self.reconnect or self.stop.is_set():  # a run that has ended hears of no more retries
                    raise
                self.notify(f"{exc}; retrying in {backoff:g} s")
                self.stop.wait(backoff)
                backoff = min(2 * backoff, BACKOFF_MAX_S)
                continue
            self.summary.connections += 1
            if self.summary.connections > 1 and not self.stop.is_set():
                self.notify(f"{self.spec.text}: reconnected (connection {self.summary.connections})")
            decoded_before = self.summary.frames_decoded
            try:
                self._read(container, stream)
                what = f"{self.spec.text}: source ended"
            except InputError as exc:
                if not self.reconnect and self.summary.frames_decoded == decoded_before:
                    raise  # never delivered a frame: an error, not the end of a stream
                what = str(exc)
                if not self.reconnect:  # a live source that stops sending has ended (UDP has no other end)
                    self.ended = f"source lost: {exc}"
                    return
            finally:
                container.close()
            if not self.reconnect or self.stop.is_set():
                self.ended = "source ended"
                return
            if self.summary.frames_decoded > decoded_before:
                backoff = BACKOFF_START_S
            self.notify(f"{what}; reconnecting in {backoff:g} s (recurrent state kept)")
            self.stop.wait(backoff)
            backoff = min(2 * backoff, BACKOFF_MAX_S)
        self.ended = "stopped"

    # ------------------------------------------------------------------------------------------ one connection

    def _read(self, container: Any, stream: Any) -> None:
        tb = Fraction(stream.time_base) if stream.time_base else Fraction(1, 90000)
        rate = stream.codec_context.framerate or stream.guessed_rate or stream.average_rate
        rate = Fraction(rate) if rate else FALLBACK_RATE
        if self.source_rate is None:
            self.source_rate = rate
        frame_ticks = max(1, round(1 / (rate * tb)))  # one frame's duration in time-base units
        reformatter = VideoReformatter()  # one swscale context per connection (see colonlight.video)
        held: dict[int, _Held] = {}
        gap = 0.0 if self._last_arrival is None else time.perf_counter() - self._last_arrival
        seg_start: int | None = None
        seg_offset = self._timeline_end + gap
        last_rel: int | None = None
        last_dur = frame_ticks
        count = 0  # source frames of this segment
        previous: float | None = None  # perf_counter of this connection's last decoded frame
        ending = False  # the source went silent for the timeout: what still comes out is its tail, not a lag

        def hand_over(choices: list[Choice]) -> None:
            for c in choices:
                h = held[c.source_index]
                if h.rgb is None:
                    h.rgb = reformatter.reformat(h.frame, format="rgb24").to_ndarray()
                    image = h.rgb
                else:  # the same source frame again (a slower source): its own buffer
                    image = h.rgb.copy()
                self.summary.frames_in += 1
                self.handoff.put(
                    LiveFrame(image, c.index, h.time_s, h.arrival_wall, h.arrival, self.summary.connections)
                )

        def release() -> None:
            keep = set(self.choice.pending)
            for k in [k for k in held if k not in keep]:
                del held[k]

        def end_segment() -> None:
            if last_rel is not None:
                hand_over(self.choice.end_segment(last_rel + last_dur))
                self._timeline_end = seg_offset + float((last_rel + last_dur) * tb)
            held.clear()

        self.choice.start_segment(tb)
        try:
            for frame in self._decoded(container, stream):
                if self.stop.is_set():
                    return
                pts = frame.pts if frame.pts is not None else frame.dts
                if pts is None:  # no timestamps (raw H.264): one frame duration after the previous frame
                    pts = (seg_start or 0) + (last_rel + last_dur if last_rel is not None else 0)
                dur = frame.duration if frame.duration and frame.duration > 0 else last_dur
                if seg_start is None:
                    seg_start = pts
                rel = pts - seg_start
                if last_rel is not None and (rel < last_rel or float((rel - last_rel) * tb) > MAX_GAP_S):
                    end_segment()  # timestamps went back or jumped: a new segment, output indices go on
                    seg_offset, seg_start, rel, last_rel, count = self._timeline_end, pts, 0, None, 0
                    self.choice.start_segment(tb)
                elif last_rel is not None and rel > last_rel and not frame.duration:
                    dur = rel - last_rel
                time_s = seg_offset + float(rel * tb)
                if self.realtime:
                    self._pace(time_s)
                now = time.perf_counter()
                # After --timeout s of silence the demuxer gives up, and only then releases the frames it and the
                # decoder still held (MPEG-TS completes a packet when the next one starts): late because the
                # source stopped, not because the machine fell behind.
                ending = ending or (previous is not None and now - previous >= self.timeout_s)
                previous = self._last_arrival = now
                if not ending:
                    self._track_lag(time_s, now)
                held[count] = _Held(frame, time_s, time.time(), now)
                count += 1
                self.summary.frames_decoded += 1
                hand_over(self.choice.push(rel, rel + dur))
                last_rel, last_dur = rel, dur
                release()
        finally:
            if not self.stop.is_set():
                end_segment()
            else:
                held.clear()

    def _decoded(self, container: Any, stream: Any) -> Any:
        """Decoded frames; a packet the decoder refuses (joined mid-GOP, UDP loss) is counted and skipped."""
        try:
            for packet in container.demux(stream):
                try:
                    frames = packet.decode()
                except (av.error.InvalidDataError, av.error.UndefinedError) as exc:
                    self.summary.frames_damaged += 1
                    log.debug("undecodable packet: %s", exc)
                    continue
                yield from frames
        except (av.error.FFmpegError, OSError) as exc:
            raise source_error(self.spec, exc, self.summary.frames_decoded) from exc

    def _track_lag(self, time_s: float, now: float) -> None:
        """How far decoding has fallen behind the source's clock: a backlog waiting in the socket or pipe, which
        arrival-to-output latency cannot see. Frames that keep up arrive at a steady offset from their timestamps;
        the reference is the largest offset seen (so the burst FFmpeg's probing releases at the start is not a lag)."""
        if not self.spec.is_live and not self.realtime:
            return
        ahead = time_s - now
        if self._ahead_max is None or ahead > self._ahead_max:
            self._ahead_max = ahead
        self.summary.behind_max_s = round(max(self.summary.behind_max_s, self._ahead_max - ahead), 3)

    def _pace(self, time_s: float) -> None:
        """--realtime: release a frame when its time comes, as if a camera were producing the file now."""
        now = time.perf_counter()
        if self._pace_origin is None:
            self._pace_origin = now - time_s
        delay = self._pace_origin + time_s - now
        if delay > 0:
            self.stop.wait(delay)
