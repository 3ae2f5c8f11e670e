"""Decoding clips to upright RGB frames, picked exactly as FFmpeg's ``fps`` filter picks them.

PyAV exposes presentation timestamps and rotation metadata. :func:`iter_video_frames` corrects the timestamps as
the ``ffmpeg`` tool does (:mod:`colonlight.timestamps`), lets the model of ``vf_fps.c`` choose the frames
(:mod:`colonlight.fps`) and turns them upright (:mod:`colonlight.rotation`).

Container metadata (frame counts, durations) is never trusted: decoding alone decides how many frames exist.
It only warns: a file shorter than its container's own size fields is reported as truncated
(:class:`DecodeReport`, :mod:`colonlight.containers`). Damage part way through is decoded past, as ffmpeg does.

Nothing the input claims can make memory grow: frames larger than the pixel cap are refused from the headers
before decoding, and a frame that the fps conversion repeats is handed out one copy at a time (:class:`FpsRun`),
up to the gap cap (:func:`colonlight.limits.max_gap_frames_setting`).
"""

from __future__ import annotations

import errno
import logging
import os
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np
from av.video.reformatter import VideoReformatter

from .containers import declared_end, index_cut, truncation_reason
from .errors import FrameTooLargeError, InputError
from .fps import FpsRun, FpsSelector
from .limits import DEFAULT_FPS, MAX_GAP_FRAMES_ENV, max_gap_frames_setting, max_pixels_setting
from .rotation import Transform, display_matrix, orientation, rotation_tag
from .stream_choice import main_video_stream
from .timestamps import FfmpegTimestamps

log = logging.getLogger(__name__)

#: Suffixes that name videos (raw H.264 streams too: ``colonlight enhance file.h264`` decodes one). A batch takes a
#: file with one as a clip before probing, so that a broken one is reported, not ignored; a file with any other
#: suffix is a clip only if its content decodes (:func:`is_video`).
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

# Demuxers that open still images, animations or text as a "video" stream: such files are not clips. CD+G
# ("cdg", karaoke graphics from a CD's subcode) too: its probe asks only that a few bytes have certain low bits,
# and takes about one small file of random bytes in 700 (16-320 bytes), so a folder of data files had "clips".
_NOT_VIDEO_FORMATS = frozenset({"image2", "tty", "bin", "xbin", "idf", "adf", "apng", "gif", "cdg"})


def is_still_format(fmt: str) -> bool:
    """Whether FFmpeg's demuxer ``fmt`` reads a still image, an animation or text, not a video (a file of it is
    refused by name, by ``enhance``, the service and ``stream`` alike)."""
    return fmt in _NOT_VIDEO_FORMATS or fmt.endswith("_pipe")


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
    decoder_error: str | None = None  # why the decoder refused the first packet it refused

    @property
    def nothing_decoded(self) -> str:
        """The cause said for a clip none of whose frames decode: the decoder's own reason when it refused every
        packet (a valid stream this FFmpeg build cannot decode is not "truncated or corrupt"), else the guess."""
        if self.packets and self.decoder_error:
            return f"no decodable video frames: the decoder refused all {self.packets} packets ({self.decoder_error})"
        return "no decodable video frames (truncated or corrupt?)"

    @property
    def cut_note(self) -> str:
        """``"; the file is truncated: REASON"`` if the file looks cut short, else ``""``: what the one-line error
        of a clip too short to use adds, as a finished clip's :attr:`warnings` say it."""
        return f"; the file is truncated: {self.truncated}" if self.truncated else ""

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


def _error(path: Path, cause: str) -> InputError:
    return InputError(" ".join(f"{path}: {cause}".split()))


#: errno codes FFmpeg's demuxers return for a header they refuse (not the OS's, for a file already stat()ed)
_HEADER_ERRNOS = frozenset({errno.EBUSY, errno.EINVAL, errno.ERANGE, errno.EDOM, errno.ENOSYS, errno.EOVERFLOW})


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
    if opening and isinstance(exc, av.error.EOFError):  # a container header, then nothing (or a cut)
        return "no video frames: the file ends before its first frame (an empty or unfinished recording?)"
    if opening and isinstance(exc, av.error.FFmpegError) and exc.errno == errno.EIO:  # FFmpeg's word for a cut
        return "its container cannot be read (Input/output error): truncated or corrupt?"
    if opening and isinstance(exc, av.error.FFmpegError) and exc.errno in _HEADER_ERRNOS:
        # a demuxer's refusal of the header it read, in errno's words: said bare ("Device or resource busy" for a
        # .y4m of size 0x0 or past FFmpeg's limit), it read as trouble with the disk rather than with the file
        return f"not a video FFmpeg can open: it refuses the file's header ({exc.strerror or exc})"
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


def _index_cut_error(path: Path) -> InputError | None:
    """The error for an MP4/MOV cut inside its index ('moov'), if it is one. FFmpeg reads such a file as having
    no video stream, a stream of no known codec or no frame at all, depending on where the cut falls: each of
    those said alone sends the user looking for the wrong cause."""
    cut = index_cut(path)
    if cut is None:
        return None
    size, end = cut
    return _error(
        path,
        f"truncated MP4/MOV: the file ends at byte {size}, inside its index (the 'moov' box, which ends at "
        f"byte {end}); no frame can be read",
    )


def _open_container(path: Path, options: dict[str, str]) -> tuple[Any, Any]:
    """``av.open`` with ``options`` for its stream probe, and the main video stream; InputError if no video."""
    try:
        container = av.open(str(path), mode="r", metadata_errors="replace", options=options)
    except (av.error.FFmpegError, OSError, UnicodeError, ValueError) as exc:
        if isinstance(exc, av.error.FFmpegError) and (cut := _index_cut_error(path)) is not None:
            raise cut from exc
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
        if is_still_format(fmt):
            raise _error(path, f"not a video: the content is a still image, animation or text ({fmt})")
        stream = main_video_stream(container.streams.video)  # the one `ffmpeg -i` takes; never cover art
        if stream is None or stream.codec_context is None:
            raise _index_cut_error(path) or _error(
                path, "contains no video stream" if stream is None else "no decoder for its video codec"
            )
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


#: The largest ``max_pixels`` libavcodec takes (INT_MAX); a frame of more pixels cannot be decoded at all.
_LIBAV_MAX_PIXELS = 2**31 - 1


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
    # libavcodec's max_pixels is an int option of 0..INT_MAX: a larger value is refused, and every frame with it
    libav_cap = str(min(cap, _LIBAV_MAX_PIXELS))
    container, stream = _open_container(path, {"max_pixels": libav_cap})
    try:
        _check_size(path, stream, cap)
        stream.codec_context.options = {"max_pixels": libav_cap}
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
            if report.source_frames == 0:
                cause = f"corrupt or truncated video: reading failed before its first frame ({_cause(exc)})"
                raise _error(path, cause) from exc
            # ffmpeg says "Error during demuxing" and ends the input there, keeping what it decoded (a frame size
            # field damaged in an IVF, a y4m FRAME marker): the frames so far are the clip, marked truncated
            report.truncated = f"reading stopped after {report.packets} packets ({_cause(exc)})"
            yield from _drained(path, stream, report)
            return
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
            if report.decoder_error is None:
                report.decoder_error = _decoder_cause(exc, stream)
            continue
        for frame in frames:
            report.source_frames += 1
            report.damaged += bool(frame.is_corrupt)
            yield frame


def _decoder_cause(exc: BaseException, stream: Any) -> str:
    """Why a packet did not decode, in words: a decoder that would not even open for the stream (libavcodec
    refuses some valid streams, a 17x9 Theora clip) is said as that, not as PyAV's errno text ("Operation not
    permitted" reads as a file permission problem)."""
    codec = getattr(stream.codec_context, "name", None) or "video"
    if "avcodec_open2" in str(exc):
        return f"FFmpeg's {codec} decoder cannot be opened for this {stream.width}x{stream.height} stream"
    return f"{codec}: {_cause(exc)}"


def _drained(path: Path, stream: Any, report: DecodeReport) -> Iterator[Any]:
    """The frames the decoder still holds once reading has stopped early (what ffmpeg flushes at its input's end)."""
    try:
        frames = stream.codec_context.decode(None)
    except av.error.FFmpegError as exc:  # nothing more to take from a decoder that fails on the flush
        log.debug("%s: flushing the decoder failed: %s", path, exc)
        return
    for frame in frames:
        report.source_frames += 1
        report.damaged += bool(frame.is_corrupt)
        yield frame


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
        report = DecodeReport()
        first = next(iter(_frames(path, container, stream, None, report, cap)), None)
        if first is None:
            raise _index_cut_error(path) or _error(path, report.nothing_decoded)
        rotation, _ = orientation(display_matrix(first), rotation_tag(stream))
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
        report.truncated = truncation_reason(path, container.format.name) or report.truncated
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
    ts = FfmpegTimestamps(container, stream)
    tag = rotation_tag(stream)
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
            transform = orientation(display_matrix(frame), tag)[1]
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
        raise _index_cut_error(path) or _error(path, report.nothing_decoded)
    if decoded < min_frames:
        # the container's sizes are read now, not after the last frame: a clip cut short fails here, and said
        # alone "too short" sends the user to a recording that was long enough rather than to the cut copy
        report.truncated = truncation_reason(path, container.format.name) or report.truncated
        raise _error(path, f"too short: {decoded} frame(s) decoded, at least {min_frames} needed{report.cut_note}")
    report.discontinuities = ts.packets.discontinuities
    if selector is not None:
        runs.extend(selector.close_runs(ts.eof_pts()))
        yield from expand(runs, float(selector.fps))
    while ready:
        yield ready.popleft()
