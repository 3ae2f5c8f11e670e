"""The H.264 writer: RGB frames to an mp4 (yuv420p, faststart) that browsers play, byte-identical on any machine.

PyAV's wheels carry FFmpeg with libx264, so no system FFmpeg and no subprocess pipes are needed.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from types import TracebackType
from typing import Any

import av
import numpy as np

from .atomic import atomic_path
from .errors import InputError
from .fps import as_fraction

#: x264 threads (and so slices per frame) of :class:`VideoWriter`: fixed, so that ``enhanced.mp4`` is byte-identical
#: on any machine; 4 keeps a 1080p encode ahead of the enhancement on small machines.
ENCODER_THREADS = 4
#: x264 options of :class:`VideoWriter` beyond CRF and preset. mbtree=0: x264's macroblock-tree pass gives
#: different bytes from run to run in one process (even on one thread: 7 different videos of the same 26 frames in
#: 40 encodes at 96x80, 2 in 40 at 320x240); without it the bytes are the same every time. Its cost in bytes is
#: measured by ``python -m benchmarks video_encoding`` (README, reproducible videos).
X264_PARAMS = "mbtree=0"


class VideoWriter:
    """Write RGB uint8 frames to an H.264 (yuv420p, faststart) mp4 that browsers play.

    The file appears at ``path`` only when :meth:`close` succeeds (atomic rename); on error nothing is left.
    Odd widths/heights are padded by one pixel (yuv420p needs even sizes). Colours are converted as BT.601
    limited range and tagged so, so that players do not shift them. A writer that got no frame writes nothing.
    The same frames give the same bytes on any machine (fixed encoder threads, no muxer version or time, no
    macroblock-tree pass: ``X264_PARAMS``); ``x264_params`` overrides that for measurements of what it costs.

    Example::

        with VideoWriter(Path("out.mp4"), fps=18) as w:
            for frame in frames:
                w.write(frame)
    """

    def __init__(
        self, path: Path, fps: float, crf: int = 18, preset: str = "medium", x264_params: str = X264_PARAMS
    ) -> None:
        self.path = Path(path)
        self.fps = fps
        self.rate = as_fraction(fps)
        self.crf = crf
        self.preset = preset
        self.x264_params = x264_params
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
            options = {"crf": str(self.crf), "preset": self.preset}
            if self.x264_params:
                options["x264-params"] = self.x264_params
            self._stream.options = options
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
            with contextlib.suppress(Exception):  # the file is being discarded anyway
                self._container.close()
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
