"""Which decoded frames of a live stream become output frames: FFmpeg's ``fps`` rule, decided as frames arrive.

:class:`~colonlight.video.FpsSelector` (the model of ``vf_fps.c`` that ``enhance`` uses) decides about a frame only
when the next one is in: a frame is output for a slot unless a later frame also rounds into that slot. On a live
feed that wait is one source frame interval (33 ms at 30 fps) added to every frame's latency. So each frame is also
tried against a copy of the selector fed the *predicted* time of the next frame (this frame's time plus its
duration): if the prediction says it will be output, it is output at once. A constant-rate source (every camera
and encoder here) is predicted exactly, and the frames are the very ones ``enhance`` picks; when a frame arrives
earlier than predicted, the slot keeps the frame already sent (one slot of one frame differs from FFmpeg's choice).

Timestamps are per *segment*: a run of frames with increasing presentation times. A reconnect, a timestamp that
goes back, or a jump forward longer than :data:`MAX_GAP_S` starts a new segment with a fresh selector (so that a
3-second outage does not come back as 54 copies of the last frame); output indices go on across segments.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from fractions import Fraction

from ..video import FpsDecision, FpsSelector

#: A forward timestamp jump longer than this (seconds) is a discontinuity, not a slow stretch of the stream.
MAX_GAP_S = 2.0


@dataclass(frozen=True)
class Choice:
    """Output frame ``index`` (global, from 0) is the segment's source frame ``source_index``."""

    index: int
    source_index: int


class FrameChoice:
    """The output decisions of one stream, segment after segment; ``fps`` None keeps every frame."""

    def __init__(self, fps: float | Fraction | None) -> None:
        self.fps = Fraction(fps).limit_denominator(1001) if fps else None
        self._selector: FpsSelector | None = None
        self._base = 0  # output frames of the segments before this one
        self._claimed = 0  # output indices of this segment already decided (0 .. _claimed-1)
        self._pushed = 0  # source frames of this segment
        self._last_pts: int | None = None

    def start_segment(self, time_base: Fraction) -> None:
        """Begin a new segment (a new connection or a timestamp discontinuity); call :meth:`end_segment` first."""
        self._base += self._claimed
        self._claimed = self._pushed = 0
        self._last_pts = None
        self._selector = FpsSelector(self.fps, time_base) if self.fps else None

    def push(self, pts: int, next_pts_guess: int | None) -> list[Choice]:
        """Source frame at ``pts`` (segment time base, increasing): the output frames decided now.

        ``next_pts_guess`` is when the next frame is expected (None: no prediction, decide when it arrives).
        """
        index = self._pushed
        self._pushed += 1
        self._last_pts = pts
        if self._selector is None:
            return self._claim([FpsDecision(index, index, index)])
        out = self._claim(self._selector.push(pts))
        if next_pts_guess is not None and next_pts_guess > pts:
            trial = copy.deepcopy(self._selector)
            out += self._claim([d for d in trial.push(next_pts_guess) if d.source_index == index])
        return out

    def end_segment(self, eof_pts: int | None) -> list[Choice]:
        """End of the segment at ``eof_pts`` (last pts + its duration): the output frames still to decide."""
        if self._selector is None or self._pushed == 0:
            return []
        end = eof_pts if eof_pts is not None else (self._last_pts or 0) + 1
        out = self._claim(self._selector.close(end))
        self._selector = None
        return out

    @property
    def pending(self) -> tuple[int, ...]:
        """Source indices of this segment that a later decision may still name (keep their frames)."""
        if self._selector is None:
            return ()
        return self._selector.pending

    def _claim(self, decisions: list[FpsDecision]) -> list[Choice]:
        out = []
        for d in decisions:
            if d.index < self._claimed:  # this slot was already filled (by a prediction)
                continue
            self._claimed = d.index + 1
            out.append(Choice(self._base + d.index, d.source_index))
        return out
