"""The timestamps the ``ffmpeg`` tool hands to its filters, modelled on the packets and frames PyAV gives us.

``ffmpeg -i clip -vf fps=18`` does not filter the demuxer's timestamps as they are: it shifts them to start at
zero, undoes the 33-bit wrap of MPEG-TS/PS, bridges jumps (two recordings joined end to end, ``cat a.ts b.ts``)
and fills in missing ones (``fftools/ffmpeg_demux.c``, ``ffmpeg_opt.c``, ``ffmpeg_dec.c``). The two classes here
repeat those steps, so that :class:`colonlight.fps.FpsSelector` sees what FFmpeg's filter sees. They read only
plain attributes of PyAV's container, stream, packet and frame objects (and import no PyAV), so they can be
driven by any object with those attributes.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Any

from .fps import rescale_near

_AVFMT_NOTIMESTAMPS = 0x0080  # libavformat/avformat.h: the format has no timestamps (raw H.264, ...)
_AVFMT_TS_DISCONT = 0x0200  # libavformat/avformat.h: timestamps may jump (MPEG-TS, MPEG-PS)
_MICROSECONDS = Fraction(1, 1_000_000)  # AV_TIME_BASE_Q
_US = 1_000_000  # AV_TIME_BASE
_DTS_DELTA_THRESHOLD_US = 10 * _US  # fftools: dts_delta_threshold (10 s), for formats whose timestamps may jump
_DTS_ERROR_THRESHOLD_US = 3600 * 30 * _US  # fftools: dts_error_threshold (30 h), for the others
# libavformat's pts_wrap_bits of the demuxers that wrap (avpriv_set_pts_info); every other one uses 64: no wrap
_PTS_WRAP_BITS = {"mpegts": 33, "mpeg": 33, "mpegvideo": 33, "flv": 32}


class FfmpegPacketTimestamps:
    """The ``ffmpeg`` tool's corrections of packet timestamps before decoding (``fftools/ffmpeg_demux.c``,
    ``ts_fixup``), applied to the packets of the one video stream in use, in demuxing order:

    * wrap correction at the start (``pts_wrap_bits`` < 64: MPEG-TS/PS, FLV): a first timestamp more than half
      the wrap range past the start is taken as not yet wrapped (libavformat unwraps the rest itself);
    * the shift by ``ts_offset = -start`` (see :class:`FfmpegTimestamps`);
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


class FfmpegTimestamps:
    """The pts the ``ffmpeg`` tool hands to its filters, and its end-of-stream pts (stream time base).

    * ``ffmpeg_demux.c`` (``ts_fixup``) shifts each timestamp by ``ts_offset = -start`` (microseconds,
      rescaled with ``av_rescale_q``). ``start`` is the file's start (``ic->start_time``, earliest stream),
      except for formats whose timestamps may jump (MPEG-TS/PS), where ``correct_input_start_times``
      (``ffmpeg_opt.c``) takes the earliest stream in use: the video alone, as in
      ``ffmpeg -i clip -vf fps=18 frames/%06d.png``.
    * discontinuities and wraps are corrected on the packets, before decoding (:class:`FfmpegPacketTimestamps`);
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
        self.packets = FfmpegPacketTimestamps(container, stream, start, self.offset)
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
