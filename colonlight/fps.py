"""The frame choice of FFmpeg's ``fps`` filter (``libavfilter/vf_fps.c``, its defaults: round=near,
eof_action=round, no start time), decided from presentation timestamps alone.

Pure integer arithmetic on timestamps: no PyAV, no frames. :func:`colonlight.decoding.iter_video_frames` feeds it
the timestamps the ``ffmpeg`` tool would feed the filter (:mod:`colonlight.timestamps`), and the live stream
(:mod:`colonlight.live`) the arrival times of its frames. Why exactly FFmpeg's choice: users compare our frames
with ``ffmpeg -vf fps=18`` extractions, so output frame ``k`` must be the very source frame FFmpeg outputs as ``k``.

A repeat costs nothing here: a source frame output ``n`` times in a row is one :class:`FpsRun` of a few integers,
however large ``n`` (a 60 s timestamp gap at 18 fps is one run of 1080), so a caller can stream the copies.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction


def as_fraction(rate: float | Fraction) -> Fraction:
    """A frame rate as an exact fraction; floats snap to the nearest ratio with denominator <= 1001 (NTSC)."""
    r = rate if isinstance(rate, Fraction) else Fraction(rate).limit_denominator(1001)
    if r <= 0:
        raise ValueError(f"frame rate must be positive, got {rate}")
    return r


def rescale_near(value: int, from_tb: Fraction, to_tb: Fraction) -> int:
    """``av_rescale_q_rnd(value, from_tb, to_tb, AV_ROUND_NEAR_INF)``: exact, halves away from zero."""
    x = Fraction(value) * from_tb / to_tb
    q, r = divmod(abs(x.numerator), x.denominator)
    if 2 * r >= x.denominator:
        q += 1
    return q if x >= 0 else -q


@dataclass(frozen=True)
class FpsDecision:
    """Source frame ``source_index`` is output frame ``index``, at output pts ``pts`` (units of 1/fps)."""

    index: int
    source_index: int
    pts: int


@dataclass(frozen=True)
class FpsRun:
    """Source frame ``source_index`` is output ``count`` times in a row: output frames ``index`` ..
    ``index + count - 1`` at output pts ``pts`` .. ``pts + count - 1``. A run is a few integers however long
    the repeat (a 60 s timestamp gap at 18 fps is one run of 1080), so a caller can stream the copies."""

    index: int
    source_index: int
    pts: int
    count: int

    def decisions(self) -> Iterator[FpsDecision]:
        for k in range(self.count):
            yield FpsDecision(self.index + k, self.source_index, self.pts + k)


class FpsSelector:
    """Which source frames FFmpeg's ``fps`` filter outputs, decided from presentation timestamps alone.

    Push every decoded frame's pts (``time_base`` units) in decoding order, then :meth:`close` with the
    end-of-stream pts; both return the decisions made so far (:meth:`push_runs` and :meth:`close_runs` return
    them as runs of repeats instead, in constant memory). Like the filter it holds at most two frames,
    so a caller keeps only the frames listed in :attr:`pending`. The rules, from ``vf_fps.c``:

    * each input pts is rescaled to the output time base 1/fps, to nearest, halves away from zero
      (``read_frame``: ``av_rescale_q_rnd(in_pts, ..., s->rounding)``, default ``AV_ROUND_NEAR_INF``);
    * the first output pts is the first frame's rescaled pts (``write_frame``: ``next_pts = frames[0]->pts``);
    * with two frames buffered the first is dropped if the second's pts <= the next output pts; otherwise the
      first is output at the next output pts, which advances by one. A frame thus repeats while the next one
      is still later: a source slower than fps gets duplicates (``write_frame``);
    * at end of stream the EOF pts (last pts + its duration) is rescaled the same way (``update_eof_pts``,
      eof_action=round) and the last frame is output until the next output pts reaches it.
    """

    def __init__(self, fps: float | Fraction, time_base: Fraction) -> None:
        self.fps = as_fraction(fps)
        self.time_base = Fraction(time_base)
        self._out_tb = 1 / self.fps
        self._buf: deque[tuple[int, int]] = deque()  # (source_index, pts in 1/fps units)
        self._next_pts: int | None = None
        self._pushed = 0
        self._emitted = 0
        self._closed = False

    @property
    def pending(self) -> tuple[int, ...]:
        """Source indices still held (at most two); no other source frame can be output any more."""
        return tuple(i for i, _ in self._buf)

    def push(self, pts: int) -> list[FpsDecision]:
        """Add the next decoded frame; return the output decisions it allows."""
        return [d for run in self.push_runs(pts) for d in run.decisions()]

    def close(self, eof_pts: int) -> list[FpsDecision]:
        """End of stream at ``eof_pts`` (``time_base`` units); return the remaining decisions."""
        return [d for run in self.close_runs(eof_pts) for d in run.decisions()]

    def push_runs(self, pts: int) -> list[FpsRun]:
        """:meth:`push`, with the decisions as runs (at most one)."""
        if self._closed:
            raise RuntimeError("FpsSelector.push after close")
        self._buf.append((self._pushed, rescale_near(pts, self.time_base, self._out_tb)))
        self._pushed += 1
        out: list[FpsRun] = []
        while len(self._buf) == 2:
            self._step(None, out)
        return out

    def close_runs(self, eof_pts: int) -> list[FpsRun]:
        """:meth:`close`, with the decisions as runs (at most two)."""
        self._closed = True
        eof = rescale_near(eof_pts, self.time_base, self._out_tb)
        out: list[FpsRun] = []
        while self._buf:
            self._step(eof, out)
        return out

    def _step(self, eof: int | None, out: list[FpsRun]) -> None:
        """Output the oldest frame until the next one (or EOF) is due, then drop it (one ``write_frame`` loop)."""
        if self._next_pts is None:
            self._next_pts = self._buf[0][1]
        limits = ([self._buf[1][1]] if len(self._buf) == 2 else []) + ([eof] if eof is not None else [])
        count = max(0, min(limits) - self._next_pts)
        if count:
            out.append(FpsRun(self._emitted, self._buf[0][0], self._next_pts, count))
            self._emitted += count
            self._next_pts += count
        self._buf.popleft()
