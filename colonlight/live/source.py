"""Where a live stream comes from: a capture device, a network URL, a file, or a container on standard input.

Every kind is opened through PyAV (FFmpeg's demuxers and protocols), so MPEG-TS over UDP, HTTP or TCP, RTSP,
Matroska or raw H.264 on a pipe and V4L2 devices all arrive as the same decoded frames. Opening failures become one
:class:`~colonlight.errors.InputError` line naming the source and the cause.
"""

from __future__ import annotations

import math
import os
import select
import stat
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import av

from ..decoding import is_still_format
from ..errors import InputError
from ..stream_choice import main_video_stream

#: URL schemes read as network streams (FFmpeg protocols).
NETWORK_SCHEMES = frozenset({"rtsp", "rtsps", "rtmp", "rtmps", "udp", "rtp", "tcp", "http", "https"})
#: The SRC that means "a container stream on standard input".
STDIN = "-"
_V4L2_SYSFS = Path("/sys/class/video4linux")
#: Options for network streams unless the user gives them: RTSP over TCP (no lost UDP packets, works through NAT);
#: a UDP receive buffer that overflows is survivable (frames are dropped downstream, not the connection).
_NETWORK_DEFAULTS: dict[str, dict[str, str]] = {
    "rtsp": {"rtsp_transport": "tcp"},
    "rtsps": {"rtsp_transport": "tcp"},
    "udp": {"overrun_nonfatal": "1"},
}


@dataclass(frozen=True)
class SourceSpec:
    """A parsed SRC: what it is and what :func:`open_source` hands to PyAV."""

    text: str  # as the user wrote it
    kind: str  # device | network | file | stdin
    url: str  # what av.open opens
    format: str | None = None  # a forced demuxer (v4l2 for devices, or the user's --input-format)
    options: Mapping[str, str] = field(default_factory=dict)

    @property
    def is_live(self) -> bool:
        """True when frames arrive at the source's pace (everything but a file read as fast as possible)."""
        return self.kind != "file"

    @property
    def can_reconnect(self) -> bool:
        """Network streams and devices can be opened again after they end; a file or a pipe cannot."""
        return self.kind in ("network", "device")


def _scheme(text: str) -> str | None:
    head, sep, _ = text.partition("://")
    return head.lower() if sep and head.isalnum() else None


def parse_source(text: str, input_format: str | None = None, options: Mapping[str, str] | None = None) -> SourceSpec:
    """Classify SRC; InputError for an unknown URL scheme, a missing file, or an absent capture device."""
    opts = dict(options or {})
    if text == STDIN:
        return SourceSpec(text, "stdin", "pipe:0", input_format, opts)
    scheme = _scheme(text)
    if scheme is not None:
        if scheme not in NETWORK_SCHEMES:
            raise InputError(
                f"{text}: unknown stream scheme {scheme!r} (use one of {', '.join(sorted(NETWORK_SCHEMES))})"
            )
        return SourceSpec(text, "network", text, input_format, {**_NETWORK_DEFAULTS.get(scheme, {}), **opts})
    if text.startswith("/dev/video") or input_format in ("v4l2", "video4linux2"):
        probe_device(Path(text))
        return SourceSpec(text, "device", text, input_format or "v4l2", opts)
    path = Path(text)
    try:
        exists = path.exists()
    except OSError as exc:  # a name past NAME_MAX (ENAMETOOLONG): Path.exists raises it, a traceback before
        raise InputError(f"{text}: cannot open: {exc.strerror or exc}") from None
    if not exists:
        if os.path.lexists(path):
            raise InputError(f"{text}: a dangling symbolic link (or a link loop)")
        raise InputError(f"{text}: no such file (a stream URL needs a scheme such as udp:// or http://)")
    if path.is_dir():
        raise InputError(f"{text}: is a folder; `colonlight stream` reads one video, device or URL")
    return SourceSpec(text, "file", str(path), input_format, opts)


@dataclass(frozen=True)
class CaptureDevice:
    path: Path
    name: str


def list_devices() -> list[CaptureDevice]:
    """The V4L2 capture devices of this machine (``/dev/videoN`` with their driver's name), sorted by number."""
    found = []
    for dev in sorted(Path("/dev").glob("video*"), key=lambda p: (len(p.name), p.name)):
        name_file = _V4L2_SYSFS / dev.name / "name"
        try:
            name = name_file.read_text(encoding="utf-8", errors="replace").strip()
        except OSError:
            name = "?"
        found.append(CaptureDevice(dev, name))
    return found


def probe_device(path: Path) -> None:
    """InputError unless ``path`` is a capture device this process may open (checked before FFmpeg tries)."""
    try:
        st = path.stat()
    except FileNotFoundError:
        present = ", ".join(str(d.path) for d in list_devices())
        hint = f"devices present: {present}" if present else "this machine has no /dev/video* capture device"
        raise InputError(f"{path}: no such capture device ({hint})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot inspect the device ({exc.strerror or exc})") from None
    if not stat.S_ISCHR(st.st_mode):
        raise InputError(f"{path}: not a capture device (not a character device)")
    if not os.access(path, os.R_OK | os.W_OK):
        raise InputError(f"{path}: permission denied (add the user to the device's group, usually 'video')")


def _cause(exc: BaseException) -> str:
    if isinstance(exc, av.error.ExitError):
        return "no data before the timeout"
    if isinstance(exc, av.error.InvalidDataError):
        return "not a video stream FFmpeg recognises (invalid data)"
    if isinstance(exc, av.error.EOFError):
        return "the source ends before its first video frame"
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return " ".join(str(text).split())


#: How long one wait for an RTSP publisher lasts; between waits a stop (Ctrl-C) is seen.
LISTEN_SLICE_S = 1


def is_rtsp_listen(spec: SourceSpec) -> bool:
    """True when colonlight is the RTSP server an encoder publishes to (``--input-option rtsp_flags=listen``:
    the encoder pushes its stream with ANNOUNCE/RECORD)."""
    return _scheme(spec.url) in ("rtsp", "rtsps") and "listen" in spec.options.get("rtsp_flags", "").split("+")


#: How often a read of standard input that waits for data looks at the run's stop flag.
STDIN_POLL_S = 0.1
#: The most one read of standard input takes (PyAV's buffer): a 1080p raw frame arrives in a dozen reads.
STDIN_BUFFER = 1 << 18


class StdinInput:
    """Standard input as PyAV reads a file object: its bytes as they come, and the end of the stream once ``stop``
    is set. FFmpeg's own pipe read waits in the kernel, where neither a stop nor FFmpeg's interrupt callback reaches
    it: a run stopped on a silent pipe left its reader thread blocked for as long as the pipe stayed silent. As
    FFmpeg's pipe, it waits for its producer for good (a pipe that pauses is not lost) and cannot seek."""

    def __init__(self, fd: int, stop: threading.Event | None) -> None:
        self.fd = fd
        self.stop = stop

    def read(self, size: int) -> bytes:
        """Up to ``size`` bytes once some are there; b"" (the end) at the end of input or once stopped."""
        while self.stop is None or not self.stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], STDIN_POLL_S)
            if ready:
                try:
                    return os.read(self.fd, size)
                except BlockingIOError:  # a non-blocking pipe (its writer's choice) that was not ready after all
                    continue
        return b""


def _open_container(
    spec: SourceSpec, timeout_s: float, options: dict[str, str], stop: threading.Event | None = None
) -> Any:
    kwargs: dict[str, Any] = {"mode": "r", "metadata_errors": "replace", "options": options}
    if spec.format:
        kwargs["format"] = spec.format
    if spec.kind == "stdin":  # no timeout: its reads wait for the producer, and end on a stop
        return av.open(StdinInput(0, stop), buffer_size=STDIN_BUFFER, **kwargs)
    if spec.kind != "file":
        kwargs["timeout"] = (timeout_s, timeout_s)
    return av.open(spec.url, **kwargs)


def _listen(spec: SourceSpec, timeout_s: float, stop: threading.Event | None) -> Any:
    """Wait for an RTSP publisher for ``timeout_s`` seconds, in slices so that ``stop`` ends the wait at once.

    FFmpeg's own default (wait forever, ``listen_timeout`` -1) fails at once in FFmpeg 8 ("Numerical result out
    of range") and could not be interrupted; a ``listen_timeout`` the user gives is kept as one wait.
    """
    if "listen_timeout" in spec.options:
        return _open_container(spec, timeout_s + float(spec.options["listen_timeout"]), dict(spec.options))
    deadline = time.monotonic() + timeout_s
    while True:
        wait = max(1, min(LISTEN_SLICE_S, math.ceil(deadline - time.monotonic())))
        try:
            return _open_container(spec, timeout_s + wait, {**spec.options, "listen_timeout": str(wait)})
        except (av.error.ExitError, TimeoutError):  # no publisher in this slice
            if (stop is not None and stop.is_set()) or time.monotonic() >= deadline:
                raise


def open_source(spec: SourceSpec, timeout_s: float, stop: threading.Event | None = None) -> tuple[Any, Any]:
    """Open ``spec`` and pick its video stream; one InputError line on failure.

    ``timeout_s`` bounds opening and every later read of a network source or device: a silent one raises instead
    of blocking. A listening RTSP source waits ``timeout_s`` for its publisher, ended early by ``stop``. Standard
    input waits for its producer for good; ``stop`` ends its open or read as the end of the input.
    """
    try:
        if is_rtsp_listen(spec):
            container = _listen(spec, timeout_s, stop)
        else:
            container = _open_container(spec, timeout_s, dict(spec.options), stop)
    except (av.error.FFmpegError, OSError, ValueError, UnicodeError) as exc:
        raise InputError(f"{spec.text}: cannot open ({_cause(exc)})") from exc
    try:
        fmt = container.format.name
        if spec.kind == "file" and is_still_format(fmt):
            # a still image (or a text file FFmpeg renders) would be a "stream" of one frame that ends at once: as
            # `enhance` and the service, refused by name. Images piped on standard input (image2pipe) or served at
            # a URL (a camera's snapshot, re-read with --reconnect) are frames arriving over time, and are read.
            raise InputError(
                f"{spec.text}: not a video: the content is a still image, animation or text ({fmt}); "
                "`colonlight stream` reads a video file, a capture device, a stream URL or -"
            )
        stream = main_video_stream(container.streams.video)  # as `enhance` and `ffmpeg -i` choose it
        if stream is None:
            raise InputError(f"{spec.text}: holds no video stream")
        if stream.codec_context is None:
            raise InputError(f"{spec.text}: no decoder for its video codec")
        # A live frame must leave the decoder as soon as its packet is in: slice threads only (frame threads hold
        # back one frame per thread). A file read as fast as possible takes every thread.
        stream.codec_context.thread_type = "AUTO" if spec.kind == "file" else "SLICE"
    except BaseException:
        container.close()
        raise
    return container, stream


def source_error(spec: SourceSpec, exc: BaseException, frames: int) -> InputError:
    """The one-line error for a source that failed after ``frames`` decoded frames."""
    return InputError(f"{spec.text}: stream lost after {frames} frames ({_cause(exc)})")
