"""Where a live stream's enhanced frames go: a frame folder with rolling retention, a per-frame JSON-lines log,
and a pipe (YUV4MPEG2 or MPEG-TS) another program reads.

Every output here is bounded: the folder has at most ``2 * WRITERS`` frames in flight, the pipes write one frame
at a time and block while the reader is slow (the hand-off upstream then drops frames, counted), the log writes a
line per frame and flushes it.
"""

from __future__ import annotations

import contextlib
import errno
import json
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO, Protocol

import cv2
import numpy as np

from ..atomic import publish, remove_stale_temporaries, write_temporary
from ..errors import ColonlightError, InputError
from ..frames import encode_image
from ..limits import DEFAULT_JPEG_QUALITY

LOG_FILE = "gammas.jsonl"
SUMMARY_FILE = "stream.json"
PIPE_FORMATS = ("y4m", "mpegts")
#: Image encoder threads of a frame folder (OpenCV encodes without the GIL).
WRITERS = 2


class PipeClosed(ColonlightError):
    """The program reading ``--pipe`` closed its end: the stream ends (normally) here."""


class FrameOutput(Protocol):
    def write(self, index: int, frame: np.ndarray) -> None: ...
    def close(self) -> None: ...


def _even(frame: np.ndarray) -> np.ndarray:
    """Pad an odd width or height by one edge pixel (4:2:0 needs even sizes), as the H.264 writer does."""
    h, w = frame.shape[:2]
    if h % 2 or w % 2:
        return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    return frame


class Y4mPipe:
    """YUV4MPEG2 (4:2:0, BT.601 limited range) on a byte stream: what ``ffmpeg -i -`` and most SLAM front ends read.

    The header goes out with the first frame (its size fixes the stream's); a later frame of another size is an
    InputError, since a y4m stream cannot change size.
    """

    def __init__(self, fh: BinaryIO, fps: Fraction) -> None:
        self.fh = fh
        self.fps = fps
        self.size: tuple[int, int] | None = None

    def write(self, index: int, frame: np.ndarray) -> None:
        frame = _even(frame)
        h, w = frame.shape[:2]
        header = b""
        if self.size is None:
            self.size = (w, h)
            header = (
                f"YUV4MPEG2 W{w} H{h} F{self.fps.numerator}:{self.fps.denominator} Ip A1:1 C420jpeg "
                "XYSCSS=420JPEG XCOLORRANGE=LIMITED\n"
            ).encode("ascii")
        elif self.size != (w, h):
            raise InputError(
                f"the frame size changed to {w}x{h} at frame {index}, but the y4m stream started at "
                f"{self.size[0]}x{self.size[1]} and cannot change size"
            )
        yuv = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2YUV_I420)
        try:
            self.fh.write(header + b"FRAME\n")
            self.fh.write(yuv.data)
            self.fh.flush()
        except (BrokenPipeError, ConnectionResetError) as exc:
            raise PipeClosed("the program reading --pipe closed it") from exc

    def close(self) -> None:
        with contextlib.suppress(BrokenPipeError, ConnectionResetError, ValueError):
            self.fh.flush()


class MpegTsPipe:
    """H.264 in MPEG-TS on a byte stream, encoded for low delay (x264 ``zerolatency``: no lookahead, no B-frames,
    one packet out per frame in) and flushed after every frame; a keyframe every second so a reader can join."""

    def __init__(self, fh: BinaryIO, fps: Fraction, crf: int = 20) -> None:
        self.fh = fh
        self.fps = fps
        self.crf = crf
        self._container: Any = None
        self._stream: Any = None
        self.size: tuple[int, int] | None = None

    def _open(self, w: int, h: int) -> None:
        import av

        self._container = av.open(self.fh, mode="w", format="mpegts", container_options={"flush_packets": "1"})
        stream = self._container.add_stream("libx264", rate=self.fps)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        cc = stream.codec_context
        cc.colorspace = cc.color_primaries = cc.color_trc = 6  # BT.601, as the conversion below
        cc.color_range = 1
        keyint = max(1, round(float(self.fps)))
        stream.options = {"preset": "ultrafast", "tune": "zerolatency", "crf": str(self.crf), "g": str(keyint)}
        self._stream = stream
        self.size = (w, h)

    def write(self, index: int, frame: np.ndarray) -> None:
        import av

        frame = _even(frame)
        h, w = frame.shape[:2]
        if self._container is None:
            self._open(w, h)
        elif self.size is not None and self.size != (w, h):
            raise InputError(
                f"the frame size changed to {w}x{h} at frame {index}, but the MPEG-TS stream started at "
                f"{self.size[0]}x{self.size[1]} and cannot change size"
            )
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        vf.pts = index
        vf.time_base = 1 / self.fps
        try:
            for packet in self._stream.encode(vf):
                self._container.mux(packet)
            self.fh.flush()
        except (BrokenPipeError, ConnectionResetError) as exc:
            raise PipeClosed("the program reading --pipe closed it") from exc

    def close(self) -> None:
        if self._container is None:
            return
        import av

        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
            self._container.close()
            self.fh.flush()
        except (BrokenPipeError, ConnectionResetError, ValueError, OSError, av.error.FFmpegError):
            # every frame was flushed as it was written (a failure then was reported); what the writer still
            # holds fails here in PyAV's write callback (a full device, a reader gone): not reported twice
            pass
        self._container = None


def open_pipe(kind: str, fh: BinaryIO, fps: Fraction) -> FrameOutput:
    if kind == "y4m":
        return Y4mPipe(fh, fps)
    if kind == "mpegts":
        return MpegTsPipe(fh, fps)
    raise ValueError(f"pipe format must be one of {', '.join(PIPE_FORMATS)}, got {kind!r}")


class FrameFolder:
    """Enhanced frames as images in ``folder`` (``000000.jpg`` ...), each renamed into place complete, in order.

    ``keep`` > 0 keeps only the newest ``keep`` frames (a long procedure does not fill the disk); 0 keeps all.
    """

    def __init__(self, folder: Path, fmt: str = "jpg", quality: int = DEFAULT_JPEG_QUALITY, keep: int = 0) -> None:
        self.folder = Path(folder)
        self.fmt, self.quality, self.keep = fmt, quality, keep
        self.folder.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(self.folder)
        self._pool = ThreadPoolExecutor(max_workers=WRITERS, thread_name_prefix="colonlight-live-write")
        self._pending: deque[tuple[Future[Path], Path]] = deque()
        self._published: deque[Path] = deque()
        self._failed = False

    def _encode(self, dest: Path, frame: np.ndarray) -> Path:
        return write_temporary(dest, encode_image(frame, self.fmt, self.quality))

    def _publish_oldest(self) -> None:
        fut, dest = self._pending.popleft()
        try:
            publish(fut.result(), dest)
        except BaseException:
            self._failed = True  # the frames after a lost one are not published: no gap in the folder
            raise
        self._published.append(dest)
        while self.keep and len(self._published) > self.keep:
            self._published.popleft().unlink(missing_ok=True)

    def write(self, index: int, frame: np.ndarray) -> None:
        while self._pending and (self._pending[0][0].done() or len(self._pending) >= 2 * WRITERS):
            self._publish_oldest()
        dest = self.folder / f"{index:06d}.{self.fmt}"
        self._pending.append((self._pool.submit(self._encode, dest, frame), dest))

    def close(self) -> None:
        try:
            while self._pending and not self._failed:
                self._publish_oldest()
        finally:
            for fut, _ in self._pending:  # after a failure: nothing half-written stays behind
                fut.cancel()
            self._pool.shutdown(wait=True, cancel_futures=True)
            for fut, _ in self._pending:
                if fut.done() and not fut.cancelled() and fut.exception() is None:
                    fut.result().unlink(missing_ok=True)
            self._pending.clear()


class GammaLog:
    """``gammas.jsonl``: one JSON object per output frame, flushed as it is written (a reader can ``tail -f`` it)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # unbuffered: each line goes to the file as it is written (as a flush per line would), and a line that
        # cannot be written in full (a full disk) is cut off again, so that the log holds whole records only
        self._fh = open(self.path, "wb", buffering=0)  # noqa: SIM115 - held open for the stream's life
        self._size = 0

    def write(self, record: dict[str, Any]) -> None:
        text = json.dumps(record, ensure_ascii=False, separators=(",", ":")) + "\n"
        line = text.encode("utf-8", "backslashreplace")
        view = memoryview(line)
        try:
            while view:
                written = self._fh.write(view)
                if not written:
                    raise OSError(errno.EIO, "the file took no bytes")
                view = view[written:]
        except OSError:
            with contextlib.suppress(OSError):
                self._fh.truncate(self._size)
                self._fh.seek(self._size)
            raise
        self._size += len(line)

    def close(self) -> None:
        self._fh.close()
