"""Video I/O: decoding clips to upright RGB frames, picked as FFmpeg's ``fps`` filter picks them; the writer.

PyAV is used for both directions: it exposes presentation timestamps and rotation metadata, and its wheels
carry FFmpeg with libx264, so no system FFmpeg and no subprocess pipes are needed.

Why the frame choice copies FFmpeg exactly: users compare our frames with ``ffmpeg -vf fps=18`` extractions
(older pipelines made them that way), so output frame ``k`` must be the very source frame FFmpeg outputs as
frame ``k``. :class:`FpsSelector` models ``libavfilter/vf_fps.c``; :func:`iter_video_frames` feeds it the
timestamps the ``ffmpeg`` tool would feed it (``fftools/ffmpeg_demux.c``, ``ffmpeg_opt.c``, ``ffmpeg_dec.c``).

Container metadata (frame counts, durations) is never trusted: decoding alone decides how many frames exist.
It only warns: a file shorter than its container's own size field is reported as truncated (:class:`DecodeReport`).

Nothing the input claims can make memory grow: frames larger than the pixel cap are refused from the headers
before decoding, and a frame that the fps conversion repeats is handed out one copy at a time (:class:`FpsRun`).
"""

from __future__ import annotations

import logging
import math
import os
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any

import av
import cv2
import numpy as np
from av.video.reformatter import VideoReformatter

from .atomic import atomic_path
from .containers import declared_end, truncation_reason
from .errors import FrameTooLargeError, InputError
from .limits import DEFAULT_FPS, MAX_GAP_FRAMES_ENV, max_gap_frames_setting, max_pixels_setting

log = logging.getLogger(__name__)

#: Suffixes that usually name videos. Advisory only (e.g. to report a misnamed file): detection is by content.
VIDEO_SUFFIXES = frozenset(
    [
        ".mp4",
        ".m4v",
        ".mov",
        ".avi",
        ".mkv",
        ".mpg",
        ".mpeg",
        ".ts",
        ".mts",
        ".m2ts",
        ".webm",
        ".wmv",
        ".flv",
        ".3gp",
        ".ogv",
        ".vob",
        ".mxf",
        ".h264",
    ]
)

# Demuxers that open still images, animations or text as a "video" stream: such files are not clips.
_NOT_VIDEO_FORMATS = frozenset({"image2", "tty", "bin", "xbin", "idf", "adf", "apng", "gif"})
_AVFMT_NOTIMESTAMPS = 0x0080  # libavformat/avformat.h: the format has no timestamps (raw H.264, ...)
_AVFMT_TS_DISCONT = 0x0200  # libavformat/avformat.h: timestamps may jump (MPEG-TS, MPEG-PS)
_MICROSECONDS = Fraction(1, 1_000_000)  # AV_TIME_BASE_Q
_US = 1_000_000  # AV_TIME_BASE
_DTS_DELTA_THRESHOLD_US = 10 * _US  # fftools: dts_delta_threshold (10 s), for formats whose timestamps may jump
_DTS_ERROR_THRESHOLD_US = 3600 * 30 * _US  # fftools: dts_error_threshold (30 h), for the others
# libavformat's pts_wrap_bits of the demuxers that wrap (avpriv_set_pts_info); every other one uses 64: no wrap
_PTS_WRAP_BITS = {"mpegts": 33, "mpeg": 33, "mpegvideo": 33, "flv": 32}


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`probe_video` learnt. Sizes are upright (rotation applied); rates, durations advisory."""

    path: Path
    width: int
    height: int
    rotation: int  # clockwise degrees turned to make the picture upright (FFmpeg's autorotate angle)
    codec: str
    avg_fps: float | None
    time_base: Fraction | None
    has_audio: bool
    duration_s: float | None


@dataclass(frozen=True)
class DecodedFrame:
    """One output frame: ``image`` is ``(H, W, 3)`` uint8 RGB, upright."""

    image: np.ndarray
    index: int  # output index 0, 1, 2, ...
    source_index: int  # index of the decoded source frame it came from (repeats when FFmpeg duplicates)
    time_s: float  # output time: index / fps (the source time when every frame is kept)
    source_time_s: float  # the source frame's presentation time, relative to the stream's start time


@dataclass
class DecodeReport:
    """What decoding a clip found besides its frames; filled in as it decodes, complete after the last frame.

    Pass one to :func:`iter_video_frames` and read it once the iterator is exhausted. ``truncated`` is the reason
    the file looks cut short, from its container's own sizes and counts (metadata warns, it never counts frames:
    the frames are those that decode).
    """

    source_frames: int = 0  # decoded
    packets: int = 0  # video packets read (empty AVI "dropped frame" chunks included)
    damaged: int = 0  # packets flagged corrupt and frames decoded with errors concealed
    discontinuities: int = 0  # timestamp jumps corrected as ffmpeg corrects them (joined MPEG-TS, restarts)
    truncated: str | None = None

    @property
    def warnings(self) -> list[str]:
        """One line each for what a user should know about the clip (empty for a sound clip)."""
        out = []
        if self.truncated:
            out.append(f"truncated: {self.truncated}; the {self.source_frames} frames that decode were used")
        if self.damaged:
            out.append(
                f"{self.damaged} damaged packets/frames were skipped or decoded with errors concealed, as ffmpeg does"
            )
        if self.discontinuities:
            out.append(
                f"{self.discontinuities} timestamp discontinuities (joined or restarted recording) were "
                "bridged as ffmpeg bridges them"
            )
        return out


# ------------------------------------------------------------------------------------------------------------
# Frame choice: a model of libavfilter/vf_fps.c with its defaults (round=near, eof_action=round, no start)
# ------------------------------------------------------------------------------------------------------------


def _as_fraction(rate: float | Fraction) -> Fraction:
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
        self.fps = _as_fraction(fps)
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


class _FfmpegPacketTimestamps:
    """The ``ffmpeg`` tool's corrections of packet timestamps before decoding (``fftools/ffmpeg_demux.c``,
    ``ts_fixup``), applied to the packets of the one video stream in use, in demuxing order:

    * wrap correction at the start (``pts_wrap_bits`` < 64: MPEG-TS/PS, FLV): a first timestamp more than half
      the wrap range past the start is taken as not yet wrapped (libavformat unwraps the rest itself);
    * the shift by ``ts_offset = -start`` (see :class:`_FfmpegTimestamps`);
    * discontinuities (``ts_discontinuity_detect``): for formats whose timestamps may jump (MPEG-TS/PS), a dts
      more than 10 s away from the predicted next dts, or 0.1 s before the previous one (two recordings joined
      end to end, a restarted encoder), adds an offset that makes the stream continue where it was, for this
      and every later packet; for other formats a timestamp more than 30 h from the prediction is dropped;
    * the predicted next dts (``ist_dts_update``): this dts plus the packet's duration, else one frame at the
      codec's rate.

    Only the video stream is read, as ``ffmpeg -i clip -vf fps=18 ...`` reads only the streams it maps.
    """

    def __init__(self, container: Any, stream: Any, start_us: int | None, offset: int) -> None:
        self.tb = Fraction(stream.time_base)
        self.discont = bool(container.format.flags & _AVFMT_TS_DISCONT)
        self.wrap_bits = _PTS_WRAP_BITS.get(container.format.name.split(",")[0], 64)
        self.start_us = start_us
        self.offset = offset  # ts_offset in stream time base
        self.wrap_done = False
        self.discont_offset_us = 0  # ts_offset_discont
        self.saw_first = False
        self.next_dts_us: int | None = None
        self.dts_us = 0
        rate = stream.codec_context.framerate
        self.codec_rate = Fraction(rate) if rate else None
        avg = stream.average_rate
        delay = int(bool(stream.codec_context.has_b_frames))  # video_delay (PyAV tells only whether it is 0)
        self.first_dts_us = int(-delay * _US / float(avg)) if avg else 0
        #: number of timestamp discontinuities corrected (a join, a restart, a jump): worth a warning
        self.discontinuities = 0

    def _to_us(self, ts: int) -> int:
        return rescale_near(ts, self.tb, _MICROSECONDS)

    def _from_us(self, us: int) -> int:
        return rescale_near(us, _MICROSECONDS, self.tb)

    def fix(self, packet: Any) -> None:
        """Correct ``packet.pts``/``packet.dts`` in place, as ``ts_fixup`` does before the packet is decoded."""
        pts, dts = packet.pts, packet.dts
        if not self.wrap_done and self.start_us is not None and self.wrap_bits < 64:
            stime = self._from_us(self.start_us)
            half, full = 1 << (self.wrap_bits - 1), 1 << self.wrap_bits
            self.wrap_done = True
            if dts is not None and dts > stime + half:
                dts -= full
                self.wrap_done = False
            if pts is not None and pts > stime + half:
                pts -= full
                self.wrap_done = False
        if dts is not None:
            dts += self.offset
        if pts is not None:
            pts += self.offset
        shift = self._from_us(self.discont_offset_us)  # ts_discontinuity_process
        if dts is not None:
            dts += shift
        if pts is not None:
            pts += shift
        if dts is not None and self.next_dts_us is not None:  # ts_discontinuity_detect (one stream in use)
            pkt_dts_us = self._to_us(dts)
            delta = pkt_dts_us - self.next_dts_us
            if self.discont:
                if abs(delta) > _DTS_DELTA_THRESHOLD_US or pkt_dts_us + _US // 10 < self.dts_us:
                    self.discont_offset_us -= delta
                    self.discontinuities += 1
                    dts -= self._from_us(delta)
                    if pts is not None:
                        pts -= self._from_us(delta)
            else:
                if abs(delta) > _DTS_ERROR_THRESHOLD_US:
                    dts = None
                if pts is not None and abs(self._to_us(pts) - self.next_dts_us) > _DTS_ERROR_THRESHOLD_US:
                    pts = None
        self._update_next_dts(packet, pts, dts)
        packet.pts, packet.dts = pts, dts

    def _update_next_dts(self, packet: Any, pts: int | None, dts: int | None) -> None:
        """``ist_dts_update`` for a video stream (no ``-r`` input option)."""
        if not self.saw_first:
            self.dts_us = self.first_dts_us + (self._to_us(pts) if pts is not None else 0)
            self.saw_first = True
        if self.next_dts_us is None:
            self.next_dts_us = self.dts_us
        if dts is not None:
            self.next_dts_us = self.dts_us = self._to_us(dts)
        self.dts_us = self.next_dts_us
        if packet.duration:
            self.next_dts_us += self._to_us(packet.duration)
        elif self.codec_rate:
            self.next_dts_us += rescale_near(1, 1 / self.codec_rate, _MICROSECONDS)


class _FfmpegTimestamps:
    """The pts the ``ffmpeg`` tool hands to its filters, and its end-of-stream pts (stream time base).

    * ``ffmpeg_demux.c`` (``ts_fixup``) shifts each timestamp by ``ts_offset = -start`` (microseconds,
      rescaled with ``av_rescale_q``). ``start`` is the file's start (``ic->start_time``, earliest stream),
      except for formats whose timestamps may jump (MPEG-TS/PS), where ``correct_input_start_times``
      (``ffmpeg_opt.c``) takes the earliest stream in use: the video alone, as in
      ``ffmpeg -i clip -vf fps=18 frames/%06d.png``.
    * discontinuities and wraps are corrected on the packets, before decoding (:class:`_FfmpegPacketTimestamps`);
    * ``ffmpeg_dec.c`` (``video_frame_process``) takes ``best_effort_timestamp`` (pts, else dts here) and
      fills a missing one with the previous pts plus the previous frame's estimated duration; formats without
      timestamps (raw H.264) are timed that way throughout. EOF is signalled at last pts + that estimate
      (``decoder_thread``); the estimate follows ``video_duration_estimate``.
    """

    def __init__(self, container: Any, stream: Any) -> None:
        self.tb = Fraction(stream.time_base)
        flags = container.format.flags
        start = container.start_time
        if start is not None and flags & _AVFMT_TS_DISCONT and stream.start_time is not None:
            start = rescale_near(stream.start_time, self.tb, _MICROSECONDS)
        self.offset = -rescale_near(start, _MICROSECONDS, self.tb) if start is not None else 0
        #: the corrections made to packets before decoding: frames then carry shifted, continuous pts
        self.packets = _FfmpegPacketTimestamps(container, stream, start, self.offset)
        self.unreliable = bool(flags & _AVFMT_NOTIMESTAMPS)
        rate = stream.codec_context.framerate
        self.codec_rate = Fraction(rate) if rate else None
        guessed = stream.guessed_rate or stream.average_rate
        self.rate_in = Fraction(guessed) if guessed else None
        self.last_pts: int | None = None
        self.last_est = 0

    def frame_pts(self, frame: Any) -> int:
        """This frame's pts as FFmpeg's filters see it; updates the duration estimate."""
        pts = None if self.unreliable else (frame.pts if frame.pts is not None else frame.dts)
        if pts is None:
            pts = 0 if self.last_pts is None else self.last_pts + self.last_est
        self.last_est = self._duration(frame, pts)
        self.last_pts = pts
        return pts

    def eof_pts(self) -> int:
        return 0 if self.last_pts is None else self.last_pts + self.last_est

    def _duration(self, frame: Any, pts: int) -> int:
        dur = frame.duration or 0
        ts_diff = pts - self.last_pts if self.last_pts is not None else -1
        if dur > 0 and not self.unreliable and not (dur == 1 and ts_diff > 2):
            return dur
        codec_dur = rescale_near(1, 1 / self.codec_rate, self.tb) if self.codec_rate else 0
        if codec_dur > 0 and self.unreliable:
            return codec_dur
        if ts_diff > 0:
            return ts_diff
        if dur > 0:
            return dur
        if codec_dur > 0:
            return codec_dur
        if self.rate_in and (d := rescale_near(1, 1 / self.rate_in, self.tb)) > 0:
            return d
        return max(self.last_est, 1)


# ------------------------------------------------------------------------------------------------------------
# Rotation: FFmpeg's autorotate (fftools/ffmpeg_filter.c; the same rules as ffplay's configure_video_filters)
# ------------------------------------------------------------------------------------------------------------

Transform = Callable[[np.ndarray], np.ndarray]


def _display_matrix(frame: Any) -> np.ndarray | None:
    for sd in frame.side_data:
        if sd.type == av.sidedata.sidedata.Type.DISPLAYMATRIX:
            return np.frombuffer(bytes(sd), dtype=np.int32)[:9].copy()
    return None


def _rotation_tag(stream: Any) -> int | None:
    """A legacy ``rotate`` stream tag (clockwise degrees; mkv spells it ``ROTATE``), if any."""
    for key, value in stream.metadata.items():
        if key.lower() == "rotate":
            try:
                return int(float(value)) % 360
            except ValueError:
                return None
    return None


def _round_c(x: float) -> int:
    """C's ``round()``: halves away from zero (Python's ``round`` goes to even)."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def _contiguous(fn: Transform) -> Transform:
    return lambda img: np.ascontiguousarray(fn(img))


def _orientation(matrix: np.ndarray | None, tag: int | None) -> tuple[int, Transform]:
    """The clockwise angle and the transform that make a frame upright, as ``ffmpeg`` (autorotate) does.

    Without a display matrix a legacy ``rotate`` tag is honoured. FFmpeg >= 7 ignores a bare tag, but a file
    carrying one (old muxers, some recorders) means it, and the rule is otherwise the same.
    """
    m = None if matrix is None else matrix.astype(np.float64) / 65536.0
    if m is None:
        theta = float(tag or 0)
    else:
        s0, s1 = math.hypot(m[0], m[3]), math.hypot(m[1], m[4])
        if s0 == 0 or s1 == 0:
            return 0, lambda img: img
        # get_rotation(): theta = -round(av_display_rotation_get(matrix)), then normalised to [0, 360)
        theta = -_round_c(-math.degrees(math.atan2(m[1] / s1, m[0] / s0)))
    theta -= 360 * math.floor(theta / 360 + 0.9 / 360)
    if abs(theta - 90) < 1:  # transpose=clock; cclock_flip (a plain transpose) if matrix[3] > 0
        if m is not None and m[3] > 0:
            return 90, _contiguous(lambda img: img.transpose(1, 0, 2))
        return 90, _contiguous(lambda img: np.rot90(img, -1))
    if abs(theta - 180) < 1:  # hflip if matrix[0] < 0, vflip if matrix[4] < 0 (both for a tag)
        hflip = m is None or m[0] < 0
        vflip = m is None or m[4] < 0
        return 180, _contiguous(lambda img: img[:: -1 if vflip else 1, :: -1 if hflip else 1])
    if abs(theta - 270) < 1:  # transpose=cclock; clock_flip (an anti-transpose) if matrix[3] < 0
        if m is not None and m[3] < 0:
            return 270, _contiguous(lambda img: img.transpose(1, 0, 2)[::-1, ::-1])
        return 270, _contiguous(lambda img: np.rot90(img, 1))
    if abs(theta) > 1:  # rotate=theta*PI/180: clockwise, same canvas, black corners

        def rotate(img: np.ndarray) -> np.ndarray:
            h, w = img.shape[:2]
            rot = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), -theta, 1.0)
            return cv2.warpAffine(img, rot, (w, h), flags=cv2.INTER_LINEAR, borderValue=(0, 0, 0))

        return round(theta) % 360, rotate
    if m is not None and m[4] < 0:  # vflip
        return 0, _contiguous(lambda img: img[::-1])
    return 0, lambda img: img


# ------------------------------------------------------------------------------------------------------------
# Opening and errors: every expected failure becomes one InputError line naming the file
# ------------------------------------------------------------------------------------------------------------


def _error(path: Path, cause: str) -> InputError:
    return InputError(" ".join(f"{path}: {cause}".split()))


def _cause(exc: BaseException, opening: bool = False) -> str:
    """A short cause for an OS or FFmpeg error (without the path PyAV appends to its messages)."""
    if isinstance(exc, FileNotFoundError):
        return "file not found (moved or deleted?)"
    if isinstance(exc, PermissionError):
        return "permission denied"
    if isinstance(exc, IsADirectoryError):
        return "is a directory, not a video file"
    if isinstance(exc, av.error.InvalidDataError):
        return "not a video: the content is not a recognised video format" if opening else "invalid data"
    return str(getattr(exc, "strerror", None) or exc or type(exc).__name__)


def _check_file(path: Path) -> None:
    """Cheap checks with clear messages before FFmpeg sees the file."""
    try:
        st = path.stat()
    except OSError as exc:
        raise _error(path, _cause(exc)) from exc
    if not os.path.isfile(path):
        raise _error(path, "is a directory, not a video file" if path.is_dir() else "not a regular file")
    if st.st_size == 0:
        raise _error(path, "empty file (0 bytes)")


def _file_size(path: Path) -> int | None:
    try:
        return path.stat().st_size
    except OSError:
        return None


def _looks_like_mp4(path: Path) -> bool:
    """An ISO media file starts with an ``ftyp`` box; one that FFmpeg cannot open has lost its index."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8)[4:8] == b"ftyp"
    except OSError:
        return False


def _open_container(path: Path, options: dict[str, str]) -> tuple[Any, Any]:
    """``av.open`` with ``options`` for its stream probe, and the main video stream; InputError if no video."""
    try:
        container = av.open(str(path), mode="r", metadata_errors="replace", options=options)
    except (av.error.FFmpegError, OSError, UnicodeError, ValueError) as exc:
        if isinstance(exc, av.error.InvalidDataError) and _looks_like_mp4(path):
            raise _error(path, "truncated or unfinished MP4/MOV: its index ('moov') is missing") from exc
        end, size = declared_end(path), _file_size(path)
        if isinstance(exc, av.error.InvalidDataError) and end is not None and size is not None and end > size:
            raise _error(
                path,
                f"truncated video: the file ends at byte {size} but its container says it ends "
                f"at byte {end}, before any frame could be read",
            ) from exc
        raise _error(path, _cause(exc, opening=True)) from exc
    try:
        fmt = container.format.name
        if fmt in _NOT_VIDEO_FORMATS or fmt.endswith("_pipe"):
            raise _error(path, f"not a video: the content is a still image, animation or text ({fmt})")
        attached = av.stream.Disposition.attached_pic  # cover art of an audio file
        candidates = [s for s in container.streams.video if not s.disposition & attached]
        if not candidates:
            raise _error(path, "contains no video stream")
        best = container.streams.best("video")
        stream = best if best in candidates else candidates[0]
        if stream.codec_context is None:
            raise _error(path, "no decoder for its video codec")
    except BaseException:
        container.close()
        raise
    return container, stream


def _check_size(path: Path, stream: Any, cap: int) -> tuple[int, int]:
    width, height = int(stream.codec_context.width or 0), int(stream.codec_context.height or 0)
    if width * height > cap:
        raise FrameTooLargeError(path, width, height, cap)
    return width, height


def _header_size(path: Path, cap: int) -> tuple[int, int]:
    """The main video stream's size from the container and codec headers, decoding nothing: the stream probe
    (``avformat_find_stream_info``, which otherwise decodes a few frames) runs with ``skip_frame=all``.
    FrameTooLargeError past ``cap``; (0, 0) if the headers do not say."""
    container, stream = _open_container(path, {"skip_frame": "all"})
    with container:
        return _check_size(path, stream, cap)


def _open(path: Path, max_pixels: int | None = None) -> tuple[Any, Any]:
    """Open ``path`` for decoding and pick its main video stream; InputError if it is not a video.

    FrameTooLargeError if the headers give more than ``max_pixels`` (None: the configured cap) pixels, raised
    before any frame is decoded (:func:`_header_size`). libavcodec's own ``max_pixels`` is then set to the cap,
    for the stream probe and for the decoder, so that not even a frame whose header lied (or said nothing) about
    its size can be decoded past the cap.
    """
    _check_file(path)
    cap = max_pixels_setting() if max_pixels is None else int(max_pixels)
    _header_size(path, cap)
    container, stream = _open_container(path, {"max_pixels": str(cap)})
    try:
        _check_size(path, stream, cap)
        stream.codec_context.options = {"max_pixels": str(cap)}
        stream.codec_context.thread_type = "AUTO"  # frame + slice threads: ~1.5x faster on HD
    except BaseException:
        container.close()
        raise
    return container, stream


def _check_index(path: Path, stream: Any) -> None:
    """InputError if the container's own sample index points past the end of the file (a cut mp4/mov).

    libavformat reads such a file up to the cut and then reports a plain end of stream, so without this check
    a truncated recording would silently come out shorter.
    """
    try:
        size = path.stat().st_size
        end = max((e.pos + e.size for e in stream.index_entries if e.pos >= 0), default=0)
    except (OSError, AttributeError, ValueError):
        return
    if end > size:
        raise _error(
            path,
            f"truncated video: the file ends at byte {size} but its index refers to byte {end} "
            "(remux it, e.g. ffmpeg -i in.mp4 -c copy fixed.mp4, to keep the readable part)",
        )


def _frames(
    path: Path, container: Any, stream: Any, fix: Callable[[Any], None] | None, report: DecodeReport, cap: int
) -> Iterator[Any]:
    """Decoded frames of ``stream``; a demux or decode failure becomes InputError naming the frame reached.

    Packets the demuxer flags as corrupt and frames decoded with concealed errors are kept, as ``ffmpeg``
    keeps them (so that frame choice still matches it), and counted in ``report`` (one warning per clip). A
    packet the decoder rejects (damage part way through a clip) is skipped and counted, as ``ffmpeg`` skips it
    (``fftools/ffmpeg_dec.c``: "Error submitting packet to decoder", then the next packet): the frames after it
    still decode, from the next keyframe or with errors concealed, and are the frames ``ffmpeg`` outputs. A
    packet refused because its frames would exceed the pixel cap ``cap`` (libavcodec's ``max_pixels``: a stream
    that grows mid-clip) fails the clip instead (FrameTooLargeError): those frames are the clip, not damage.
    """
    packets = container.demux(stream)
    while True:
        try:
            packet = next(packets, None)
        except (av.error.FFmpegError, OSError, ValueError) as exc:
            cause = f"corrupt or truncated video: reading failed after {report.source_frames} frames ({_cause(exc)})"
            raise _error(path, cause) from exc
        if packet is None:
            return
        report.damaged += bool(packet.is_corrupt)
        if packet.size or packet.dts is not None:  # not the empty packet that flushes the decoder
            report.packets += 1
            if fix is not None:
                fix(packet)
        try:
            frames = packet.decode()
        except av.error.MemoryError:
            raise
        except av.error.FFmpegError as exc:  # ffmpeg goes on after any decoding error (without -xerror)
            _check_size(path, stream, cap)
            log.debug("%s: packet %d not decoded: %s", path, report.packets, exc)
            report.damaged += 1
            continue
        for frame in frames:
            report.source_frames += 1
            report.damaged += bool(frame.is_corrupt)
            yield frame


# ------------------------------------------------------------------------------------------------------------
# Public API
# ------------------------------------------------------------------------------------------------------------


def probe_frame_size(path: Path, max_pixels: int | None = None) -> tuple[int, int]:
    """``(width, height)`` of the clip's video stream as its header gives it (coded size, before rotation),
    without decoding a frame: the cheap check to make before accepting a clip.

    Raises :class:`~colonlight.errors.FrameTooLargeError` if ``width x height`` exceeds ``max_pixels`` (None: the
    configured cap, :func:`colonlight.limits.max_pixels_setting`), :class:`InputError` if it is no video.
    """
    path = Path(path)
    _check_file(path)
    return _header_size(path, max_pixels_setting() if max_pixels is None else int(max_pixels))


def probe_video(path: Path, max_pixels: int | None = None) -> VideoInfo:
    """Describe the clip at ``path``, decoding its first frame; InputError if it is no decodable video.

    FrameTooLargeError, before decoding, if its frames exceed ``max_pixels`` (None: the configured cap)."""
    path = Path(path)
    cap = max_pixels_setting() if max_pixels is None else int(max_pixels)
    container, stream = _open(path, cap)
    with container:
        first = next(iter(_frames(path, container, stream, None, DecodeReport(), cap)), None)
        if first is None:
            raise _error(path, "no decodable video frames (truncated or corrupt?)")
        rotation, _ = _orientation(_display_matrix(first), _rotation_tag(stream))
        width, height = (first.height, first.width) if rotation % 180 == 90 else (first.width, first.height)
        rate = stream.average_rate or stream.guessed_rate
        if container.duration is not None:
            duration: float | None = container.duration / 1_000_000
        elif stream.duration is not None:
            duration = float(stream.duration * stream.time_base)
        else:
            duration = None
        return VideoInfo(
            path=path,
            width=int(width),
            height=int(height),
            rotation=rotation,
            codec=stream.codec_context.name,
            avg_fps=float(rate) if rate else None,
            time_base=Fraction(stream.time_base) if stream.time_base else None,
            has_audio=len(container.streams.audio) > 0,
            duration_s=duration,
        )


def is_video(path: Path) -> bool:
    """True if ``path`` holds a decodable video, judged by content. Decodes a frame; never raises."""
    try:
        probe_video(Path(path))
        return True
    except FrameTooLargeError:  # a video, too large to decode: reported when it runs, not ignored
        return True
    except Exception:  # noqa: BLE001 - a yes/no sniff: any failure means "not a video we can use"
        return False


def iter_video_frames(
    path: Path,
    fps: float | Fraction | None = DEFAULT_FPS,
    *,
    min_frames: int = 0,
    max_pixels: int | None = None,
    max_gap_frames: int | None = None,
    report: DecodeReport | None = None,
) -> Iterator[DecodedFrame]:
    """Decode ``path`` into upright RGB frames at ``fps``, exactly the frames FFmpeg's ``fps`` filter picks.

    ``fps`` None or 0 keeps every decoded frame. With ``min_frames`` (2 for the recurrent model) a clip with
    fewer decoded source frames is an InputError, raised before any frame is yielded. A clip that fails
    part-way (corrupt data) yields what decoded, then raises InputError naming the file and the frame reached;
    an mp4/mov cut short (index past the end of file) is refused before the first frame. Memory is constant
    in clip length and in repeats: at most two source frames (plus ``min_frames``) are held, and a frame that
    the fps conversion repeats is copied as each repeat is taken. Frames of more than ``max_pixels`` pixels
    (None: the configured cap) are refused from the stream header (FrameTooLargeError) before any is decoded.
    A timestamp gap that would repeat one frame more than ``max_gap_frames`` times (None: the configured cap,
    :func:`colonlight.limits.max_gap_frames_setting`) is an InputError raised before the first repeat.
    ``report`` (a :class:`DecodeReport`) learns what else decoding found: a file cut short (``truncated``),
    damaged packets, timestamp discontinuities; without one, these are logged as warnings.
    """
    path = Path(path)
    warn = report is None
    report = DecodeReport() if report is None else report
    cap = max_pixels_setting() if max_pixels is None else int(max_pixels)
    container, stream = _open(path, cap)
    with container:
        _check_index(path, stream)
        selector = FpsSelector(fps, stream.time_base) if fps else None
        gap_cap = max_gap_frames_setting() if max_gap_frames is None else int(max_gap_frames)
        yield from _decode(path, container, stream, selector, min_frames, report, cap, gap_cap)
        report.truncated = truncation_reason(path, container.format.name)
        for line in report.warnings if warn else ():
            log.warning("%s: %s", path, line)


def _decode(
    path: Path,
    container: Any,
    stream: Any,
    selector: FpsSelector | None,
    min_frames: int,
    report: DecodeReport,
    cap: int,
    gap_cap: int,
) -> Iterator[DecodedFrame]:
    ts = _FfmpegTimestamps(container, stream)
    tag = _rotation_tag(stream)
    held: dict[int, tuple[Any, float]] = {}  # source index -> (av frame, source time), for selector.pending
    ready: deque[DecodedFrame] = deque()
    size: tuple[int, ...] | None = None
    start: int | None = None
    decoded = 0
    transform: Transform | None = None
    # One swscale context (and pool of scaler threads) for the whole clip: ``frame.to_ndarray(format="rgb24")``
    # makes a new context, and starts new scaler threads, for every frame (1350x1080: 1.2 ms of CPU and 3-4 ms of
    # wall time a frame, against 0.45 ms reused). Same conversion (bilinear chroma, the frame's own matrix and
    # range): identical pixels.
    reformatter = VideoReformatter()

    def convert(frame: Any, source_index: int) -> np.ndarray:
        nonlocal size, transform
        try:
            rgb = reformatter.reformat(frame, format="rgb24").to_ndarray()
        except (av.error.FFmpegError, ValueError) as exc:
            raise _error(path, f"cannot convert frame {source_index} to RGB ({_cause(exc)})") from exc
        if transform is None:
            # Once per clip, from the first frame, as FFmpeg's autorotate does. (Reading a frame's side data
            # makes a reference cycle that only the cyclic GC frees: doing it per frame let memory grow.)
            transform = _orientation(_display_matrix(frame), tag)[1]
        rgb = transform(rgb)
        if size is None:
            size = rgb.shape
        elif rgb.shape != size:
            raise _error(
                path,
                f"frame size changes mid-clip at source frame {source_index}: "
                f"{size[1]}x{size[0]} -> {rgb.shape[1]}x{rgb.shape[0]}",
            )
        return rgb

    def expand(runs: deque[FpsRun], rate: float) -> Iterator[DecodedFrame]:
        """The output frames of ``runs``, one at a time: a source frame repeated n times is converted once and
        handed out as n separate buffers made as they are asked for, so repeats never pile up in memory."""
        while runs:
            run = runs.popleft()
            frame, t_src = held[run.source_index]
            if run.count - 1 > gap_cap:
                raise _error(
                    path,
                    f"a timestamp gap after source frame {run.source_index} (at {t_src:.3f} s) would repeat it "
                    f"{run.count - 1} times ({run.count / rate:.1f} s at {rate:g} fps), more than the cap of "
                    f"{gap_cap} (--max-gap-frames or {MAX_GAP_FRAMES_ENV})",
                )
            image = convert(frame, run.source_index)
            for k in range(run.count):
                index = run.index + k
                # every repeat but the last gets its own copy of the pristine image: callers may change frames
                # in place, and the copies are made one by one as the consumer takes them
                out = image if k == run.count - 1 else image.copy()
                yield DecodedFrame(out, index, run.source_index, index / rate, t_src)

    runs: deque[FpsRun] = deque()  # decided, not yet handed out (only while fewer than min_frames decoded)
    for frame in _frames(path, container, stream, ts.packets.fix, report, cap):
        pts = ts.frame_pts(frame)
        if start is None:  # source times count from the stream start, in the same shifted pts domain
            start = pts if stream.start_time is None or ts.unreliable else stream.start_time + ts.offset
        t_src = float((pts - start) * ts.tb)
        index = decoded
        decoded += 1
        if selector is None:
            ready.append(DecodedFrame(convert(frame, index), index, index, t_src, t_src))
            if decoded >= min_frames:
                while ready:
                    yield ready.popleft()
            continue
        held[index] = (frame, t_src)
        runs.extend(selector.push_runs(pts))
        if decoded >= min_frames:
            yield from expand(runs, float(selector.fps))
            keep = set(selector.pending)
            for k in [k for k in held if k not in keep]:
                del held[k]
    if decoded == 0:
        raise _error(path, "no decodable video frames (truncated or corrupt?)")
    if decoded < min_frames:
        raise _error(path, f"too short: {decoded} frame(s) decoded, at least {min_frames} needed")
    report.discontinuities = ts.packets.discontinuities
    if selector is not None:
        runs.extend(selector.close_runs(ts.eof_pts()))
        yield from expand(runs, float(selector.fps))
    while ready:
        yield ready.popleft()


# ------------------------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------------------------


#: x264 threads (and so slices per frame) of :class:`VideoWriter`: fixed, so that ``enhanced.mp4`` is byte-identical
#: on any machine; 4 keeps a 1080p encode ahead of the enhancement on small machines.
ENCODER_THREADS = 4


class VideoWriter:
    """Write RGB uint8 frames to an H.264 (yuv420p, faststart) mp4 that browsers play.

    The file appears at ``path`` only when :meth:`close` succeeds (atomic rename); on error nothing is left.
    Odd widths/heights are padded by one pixel (yuv420p needs even sizes). Colours are converted as BT.601
    limited range and tagged so, so that players do not shift them. A writer that got no frame writes nothing.
    The same frames give the same bytes on any machine (fixed encoder threads, no muxer version or time).

    Example::

        with VideoWriter(Path("out.mp4"), fps=18) as w:
            for frame in frames:
                w.write(frame)
    """

    def __init__(self, path: Path, fps: float, crf: int = 18, preset: str = "medium") -> None:
        self.path = Path(path)
        self.fps = fps
        self.rate = _as_fraction(fps)
        self.crf = crf
        self.preset = preset
        self._ctx: Any = None
        self._tmp: Path | None = None
        self._container: Any = None
        self._stream: Any = None
        self._finished = False
        self.frames_written = 0

    def _open(self, width: int, height: int) -> None:
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        try:
            # bitexact: no muxer version string, so that the bytes depend on the frames and settings alone
            opts = {"movflags": "+faststart", "fflags": "+bitexact"}
            self._container = av.open(str(self._tmp), mode="w", format="mp4", options=opts)
            self._stream = self._container.add_stream("libx264", rate=self.rate)
            self._stream.width = width + (width % 2)
            self._stream.height = height + (height % 2)
            self._stream.pix_fmt = "yuv420p"
            cc = self._stream.codec_context
            cc.colorspace = cc.color_primaries = cc.color_trc = 6  # smpte170m: BT.601, as swscale converts
            cc.color_range = 1  # limited ("tv")
            self._stream.options = {"crf": str(self.crf), "preset": self.preset}
            # x264 cuts each frame into one slice per thread, and by default takes as many threads as the
            # process may use cores (sched_getaffinity): the bytes then depend on the machine and its load
            # limits. A fixed count makes them the same everywhere.
            cc.thread_type = "SLICE"
            cc.thread_count = ENCODER_THREADS
        except BaseException as exc:
            self._discard(exc)
            raise

    def write(self, frame: np.ndarray) -> None:
        """Append one HxWx3 RGB uint8 frame."""
        if self._finished:
            raise RuntimeError(f"{self.path}: write after close/abort")
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise InputError(f"{self.path}: frames must be HxWx3 uint8 RGB, got {frame.shape} {frame.dtype}")
        h, w = frame.shape[:2]
        if self._container is None:
            self._open(w, h)
        if (h + h % 2, w + w % 2) != (self._stream.height, self._stream.width):
            raise InputError(f"{self.path}: frame size {w}x{h} differs from the video's first frame")
        if h % 2 or w % 2:
            frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        vf.pts = self.frames_written
        vf.time_base = 1 / self.rate
        try:
            for packet in self._stream.encode(vf):
                self._container.mux(packet)
        except BaseException as exc:
            self._discard(exc)
            raise
        self.frames_written += 1

    def close(self) -> None:
        """Flush the encoder and move the finished file into place (nothing is written if no frame came)."""
        self._finished = True
        if self._container is None:
            return
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
            self._container.close()
        except BaseException as exc:
            self._discard(exc)
            raise
        self._container = None
        ctx, self._ctx = self._ctx, None
        ctx.__exit__(None, None, None)

    def abort(self) -> None:
        """Drop the partial file. Safe to call more than once."""
        self._discard(RuntimeError("aborted"))

    def _discard(self, exc: BaseException) -> None:
        self._finished = True
        if self._container is not None:
            try:
                self._container.close()
            except Exception:  # noqa: BLE001 - the file is being discarded anyway
                pass
            self._container = None
        if self._ctx is not None:
            ctx, self._ctx = self._ctx, None
            ctx.__exit__(type(exc), exc, None)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
