"""One clip, start to finish: frames are decoded once, enhanced once and written once, in a stream.

Layout of a clip's output folder (a stable interface, see the README)::

    frames/000000.png ...   enhanced frames (png or jpg), 6-digit index from 0
    gammas.json             what was done, with which model and settings, and every frame's gamma (written LAST:
                            its presence with matching settings means the clip is complete)
    enhanced.mp4            optional H.264 video at the extraction fps

Decoding runs in a thread ahead of the method, and image encoding in a small thread pool behind it (OpenCV and
PyAV release the GIL), with bounded queues so memory stays flat whatever the clip length. Frames are renamed into
place strictly in index order, so an interrupted run leaves a gap-free prefix ``000000 .. k`` (never a hole).

Memory is bounded by the frame size, never by the input (:func:`peak_rss_bound` states the bound): a source
frame that the fps conversion repeats (a timestamp gap, a slow source, a high fps) is handed out one copy at a
time, and the pixel cap (``ClipOptions.max_pixels``) is checked from the stream header before any frame is decoded.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .atomic import publish, read_json, remove_stale_temporaries, write_json_atomic, write_temporary
from .content import DEFAULT_CONTENT, content_setting, content_stream, parse_content
from .errors import InputError, OptionError
from .frames import encode_image
from .limits import (
    DEFAULT_FPS,
    DEFAULT_FRAME_FORMAT,
    DEFAULT_JPEG_QUALITY,
    MAX_FPS,
    MAX_JPEG_QUALITY,
    MAX_VIDEO_SIDE,
    MIN_JPEG_QUALITY,
    is_usable_fps,
    max_gap_frames_setting,
    max_pixels_setting,
)
from .methods.base import FrameResult, Method, integer_option, number_option
from .provenance import library_versions
from .slam_layout import CAMERA_FILES, TIMES_FILE, TUM_RGB_FILE, camera_setting, clip_camera, write_slam_layout
from .sources import clip_frames
from .streaming import enhance_frames
from .video import DecodedFrame, DecodeReport, VideoWriter

GAMMAS_FILE = "gammas.json"
FRAMES_DIR = "frames"
VIDEO_FILE = "enhanced.mp4"
MIN_FRAMES = 2
_QUEUE_DEPTH = 4
#: Encoder threads (JPEG/PNG encoding and fsync release the GIL): one more than a small machine's cores, so
#: that a thread waiting on fsync does not leave a core idle (measured on 2 cores: 3 beat 2, 4 no better).
_WRITERS = 3

#: Resident memory of one process that runs clips before any frame: Python, torch, the model, the codecs
#: (``colonlight enhance`` measured at 310-340 MiB on Linux x86-64 with the CPU build of torch).
PROCESS_BASE_BYTES = 450 << 20
#: What the libavcodec decoder may hold, in RGB-frame equivalents: an H.264 decoder keeps up to 16 reference
#: frames plus one per frame thread (at most 17) in YUV 4:2:0, half the bytes of an RGB frame each.
DECODER_FRAMES = 18
#: What the H.264 writer (x264, preset medium) may hold, in RGB-frame equivalents: its 40-frame look-ahead plus
#: B-frames and threads, each padded and with a half-size copy (measured: about 70 at 1280x720).
ENCODER_FRAMES = 80


def pipeline_frames(queue_depth: int = _QUEUE_DEPTH) -> int:
    """Full-size RGB frames one clip holds at most between decoder and writers, whatever the input: one being
    converted and ``queue_depth + 1`` decoded ahead; two held before writing starts and two in the method (its
    input and its result); ``2 * queue_depth`` at the image writers, plus their encoded bytes (at most one frame
    each, PNG level 1 of noise)."""
    return 1 + (queue_depth + 1) + 2 + 2 + 2 * (2 * queue_depth)


def peak_rss_bound(
    width: int, height: int, *, workers: int = 1, video: bool = False, queue_depth: int = _QUEUE_DEPTH
) -> int:
    """Upper bound, in bytes, of the resident memory of a run on clips of ``width x height`` frames.

    ``processes x PROCESS_BASE_BYTES + workers x 3wh x (pipeline_frames(queue_depth) + DECODER_FRAMES
    [+ ENCODER_FRAMES with video])``; ``processes`` is 1 in-process (``workers == 1``), else the parent plus
    ``workers`` pool processes. It does not depend on the clip's length, timestamps or fps: repeated frames stream
    one at a time. Per output frame only its ``gammas.json`` record (about 0.2 KB) is kept until the clip ends.
    The pixel cap bounds ``w x h`` itself, so with the default cap the bound holds whatever the input claims.
    """
    processes = 1 if workers <= 1 else workers + 1
    frames = pipeline_frames(queue_depth) + DECODER_FRAMES + (ENCODER_FRAMES if video else 0)
    return processes * PROCESS_BASE_BYTES + max(1, workers) * 3 * width * height * frames


@dataclass(frozen=True)
class ClipOptions:
    """Output settings of a clip; together with the method they decide every output byte."""

    fps: float | None = DEFAULT_FPS  # None or 0: keep every source frame
    frames: bool = True
    video: bool = False
    format: str = DEFAULT_FRAME_FORMAT  # png | jpg
    quality: int = DEFAULT_JPEG_QUALITY
    folder_fps: float = DEFAULT_FPS  # the rate assumed for a folder of frames
    camera: tuple[str, str] | None = None  # (file name, text) of a DSO/COLMAP camera file to copy (slam_layout)
    #: Largest frame (width x height) decoded; larger clips fail from their header. Default: limits.max_pixels_setting()
    max_pixels: int = field(default_factory=max_pixels_setting)
    #: Most copies of one frame a timestamp gap may add; past it the clip fails (limits.max_gap_frames_setting()).
    #: Not in the settings record: it decides whether a clip fails, never a byte of a clip that is done.
    max_gap_frames: int = field(default_factory=max_gap_frames_setting)
    #: auto: the method sees the field of view less fixed text; full: the whole frame; else a mask's path (content)
    content: str = DEFAULT_CONTENT

    def __post_init__(self) -> None:
        # Each value's type is checked with its range (methods.base's helpers): "18" or None compared with a
        # number was a TypeError of "<=", a NaN max_pixels a ValueError of int() once the clip ran, and a NaN,
        # negative or huge folder_fps wrote NaN, negative or all-zero times into times.txt and gammas.json.
        object.__setattr__(self, "content", parse_content(self.content))
        if self.format not in ("png", "jpg"):
            raise OptionError(f"format must be png or jpg, got {self.format!r}")
        quality = integer_option("quality", self.quality, f"within {MIN_JPEG_QUALITY}..{MAX_JPEG_QUALITY}")
        if not MIN_JPEG_QUALITY <= quality <= MAX_JPEG_QUALITY:
            raise OptionError(f"quality must be within {MIN_JPEG_QUALITY}..{MAX_JPEG_QUALITY}, got {self.quality}")
        rates = f"0 or within 1/1001..{MAX_FPS:g}"
        if self.fps is not None and not is_usable_fps(number_option("fps", self.fps, rates, text=False)):
            raise OptionError(f"fps must be {rates}, got {self.fps!r}")
        folder_fps = number_option("folder_fps", self.folder_fps, f"within 1/1001..{MAX_FPS:g}", text=False)
        if folder_fps == 0 or not is_usable_fps(folder_fps):
            raise OptionError(f"folder_fps must be within 1/1001..{MAX_FPS:g}, got {self.folder_fps!r}")
        max_pixels = integer_option("max_pixels", self.max_pixels, "a whole number >= 1")
        if max_pixels < 1:
            raise OptionError(f"max_pixels must be >= 1, got {self.max_pixels}")
        max_gap_frames = integer_option("max_gap_frames", self.max_gap_frames, "a whole number >= 1")
        if max_gap_frames < 1:
            raise OptionError(f"max_gap_frames must be >= 1, got {self.max_gap_frames}")
        if not (self.frames or self.video):
            raise OptionError("nothing to write: enable frames or video")
        # numpy numbers as Python's: the manifest and gammas.json are JSON ("Object of type float32 is not JSON
        # serializable" ended a batch, and an np.float32 fps failed the clip in Fraction())
        fps = self.fps.item() if isinstance(self.fps, np.generic) else self.fps
        checked = {"fps": fps, "folder_fps": folder_fps, "quality": quality, "max_pixels": max_pixels,
                   "max_gap_frames": max_gap_frames}  # fmt: skip
        for name, value in checked.items():
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class ClipResult:
    clip: str
    out_dir: Path
    frames: int
    seconds: float
    truncated: bool = False  # the source looks cut short: its frames that decode were used (see warnings)
    warnings: tuple[str, ...] = ()  # one line each, without the path (also in gammas.json)


def settings_record(method: Method, opts: ClipOptions) -> dict[str, Any]:
    """The settings that decide a clip's outputs; a complete clip made with other settings is redone."""
    return {
        "method": method.name,
        "model": method.model_info(),
        "parameters": method.parameters(),
        "fps": opts.fps or None,
        "content": content_setting(opts.content),
        "outputs": {"frames": opts.frames, "video": opts.video, "format": opts.format, "quality": opts.quality},
        **camera_setting(opts.camera),
    }


def complete_record(out_dir: Path, method: Method, opts: ClipOptions) -> dict[str, Any] | None:
    """The ``gammas.json`` of a finished clip in ``out_dir`` made with the same settings, else ``None``.

    A clip whose record is returned can be skipped; the record says how many frames it has.
    """
    try:
        record: dict[str, Any] = read_json(out_dir / GAMMAS_FILE)
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict):
        return None
    if record.get("settings") != json.loads(json.dumps(settings_record(method, opts))):
        return None
    if opts.video and not (out_dir / VIDEO_FILE).is_file():
        return None
    return record


def _prefetch(frames: Iterator[DecodedFrame], stop: threading.Event) -> Iterator[DecodedFrame]:
    """Decode in a background thread, a few frames ahead."""
    q: queue.Queue[Any] = queue.Queue(maxsize=_QUEUE_DEPTH)
    end = object()

    def produce() -> None:
        try:
            for f in frames:
                while not stop.is_set():
                    try:
                        q.put(f, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put(end)
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, which re-raises it
            q.put(exc)

    thread = threading.Thread(target=produce, name="colonlight-decode", daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is end:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        thread.join(timeout=5)


class _FrameSink:
    """Writes enhanced frames as images and/or to the H.264 writer.

    Images: a pool of ``_WRITERS`` threads encodes each frame and writes it to a temporary file (fsynced); the
    main thread renames the temporaries into place strictly in frame order, so the frames on disk are always a
    gap-free prefix of the clip. At most ``2 * _QUEUE_DEPTH`` frames are in flight. After a failure or an abort
    no later frame is published and no temporary is left behind.
    """

    def __init__(self, out_dir: Path, opts: ClipOptions, fps: float) -> None:
        self.opts = opts
        self.frames_dir = out_dir / FRAMES_DIR
        self.pool = (
            ThreadPoolExecutor(max_workers=_WRITERS, thread_name_prefix="colonlight-write") if opts.frames else None
        )
        self.pending: deque[tuple[Future[Path], Path]] = deque()  # (temporary being written, its destination)
        self.video = VideoWriter(out_dir / VIDEO_FILE, fps=fps) if opts.video else None
        self.count = 0

    def _write_temporary(self, dest: Path, frame: np.ndarray) -> Path:
        return write_temporary(dest, encode_image(frame, self.opts.format, self.opts.quality))

    def _publish_oldest(self) -> None:
        fut, dest = self.pending.popleft()
        publish(fut.result(), dest)  # re-raises a writer's error

    def write(self, index: int, frame: np.ndarray) -> None:
        if self.pool is not None:
            while self.pending and (self.pending[0][0].done() or len(self.pending) >= 2 * _QUEUE_DEPTH):
                self._publish_oldest()
            dest = self.frames_dir / f"{index:06d}.{self.opts.format}"
            self.pending.append((self.pool.submit(self._write_temporary, dest, frame), dest))
        if self.video is not None:
            self.video.write(frame)
        self.count += 1

    def finish(self) -> None:
        while self.pending:
            self._publish_oldest()
        if self.pool is not None:
            self.pool.shutdown()
        if self.video is not None:
            self.video.close()

    def abort(self) -> None:
        for fut, _ in self.pending:
            fut.cancel()
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
        for fut, _ in self.pending:  # written but never published: delete
            if fut.done() and not fut.cancelled() and fut.exception() is None:
                fut.result().unlink(missing_ok=True)
        self.pending.clear()
        if self.video is not None:
            self.video.abort()


def _remove_extra_frames(frames_dir: Path, count: int, fmt: str) -> None:
    """Delete frames a previous, different run left beyond this run's last index or in another format."""
    if not frames_dir.is_dir():
        return
    for p in frames_dir.iterdir():
        stem, _, suffix = p.name.partition(".")
        if stem.isdigit() and (int(stem) >= count or suffix != fmt):
            p.unlink(missing_ok=True)


def enhance_clip(
    source: Path,
    out_dir: Path,
    method: Method,
    opts: ClipOptions | None = None,
    *,
    clip_name: str | None = None,
    on_frame: Callable[[int], None] | None = None,
    source_name: str | None = None,
) -> ClipResult:
    """Enhance one clip (a video file or a folder of frames) into ``out_dir``; ``gammas.json`` is written last.

    ``source_name``: the source as ``gammas.json`` records it (default: ``source``), so that a clip a cluster
    worker reads from its absolute path records the path as the user gave it, as a local run does.

    Raises :class:`InputError` (one line naming the file and the cause) for unusable input. A clip that fails,
    at its first frame or part way (a frame size change, a write error, a bug), leaves nothing half-written: the
    frames and video it had published are removed (:func:`discard_partial_outputs`), with the folders it made.
    An interrupt (Ctrl-C, SIGTERM) keeps the frames already on disk, which are whole, and removes the video of a
    clip it stopped before its ``gammas.json``; a rerun redoes the clip.
    """
    created: list[Path] = []  # folders this call creates (out_dir, its missing parents): removed if left empty
    folder = Path(out_dir)
    while not os.path.lexists(folder) and folder != folder.parent:
        created.append(folder)
        folder = folder.parent
    try:
        return _enhance_clip(
            source, out_dir, method, opts, clip_name=clip_name, on_frame=on_frame, source_name=source_name
        )
    except Exception:
        discard_partial_outputs(Path(out_dir))
        if created:
            _remove_if_empty([Path(out_dir) / FRAMES_DIR, *created])
        raise
    except BaseException:
        remove_unfinished_video(Path(out_dir))
        if created:
            _remove_if_empty([Path(out_dir) / FRAMES_DIR, *created])
        raise


def remove_unfinished_video(out_dir: Path) -> None:
    """After an interrupt: remove the video of a clip without its ``gammas.json``. Its frames are kept (whole, a
    gap-free prefix), but the video is published just before ``gammas.json``, and an interrupt can land between
    the two; a video appears only with its complete clip."""
    if not (out_dir / GAMMAS_FILE).exists():
        with contextlib.suppress(OSError):
            (out_dir / VIDEO_FILE).unlink(missing_ok=True)


def discard_partial_outputs(out_dir: Path) -> None:
    """Remove what a clip that failed had published (numbered frames, video, SLAM listings, temporaries), so
    that a failed clip leaves nothing half-written and frees the room it took; its ``gammas.json`` is already
    gone (it is removed before the first write), and a rerun writes everything again. Other files are kept."""
    remove_stale_temporaries(out_dir)
    frames_dir = out_dir / FRAMES_DIR
    with contextlib.suppress(OSError):
        for p in frames_dir.iterdir():
            if p.name.partition(".")[0].isdigit():
                p.unlink(missing_ok=True)
    for name in (VIDEO_FILE, TIMES_FILE, TUM_RGB_FILE, *CAMERA_FILES):  # the frames' video and SLAM listings
        with contextlib.suppress(OSError):
            (out_dir / name).unlink(missing_ok=True)
    for folder in (frames_dir, out_dir):
        with contextlib.suppress(OSError):
            folder.rmdir()  # only if now empty


def _remove_if_empty(folders: list[Path]) -> None:
    """Remove each of ``folders`` (innermost first) that exists and is empty; stop at the first that is not."""
    for folder in folders:
        try:
            folder.rmdir()
        except FileNotFoundError:
            continue
        except OSError:
            return


def _enhance_clip(
    source: Path,
    out_dir: Path,
    method: Method,
    opts: ClipOptions | None,
    *,
    clip_name: str | None,
    on_frame: Callable[[int], None] | None,
    source_name: str | None = None,
) -> ClipResult:
    t0 = time.perf_counter()
    opts = ClipOptions() if opts is None else opts
    source, out_dir = Path(source), Path(out_dir)
    clip_name = clip_name or source.stem
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / GAMMAS_FILE).unlink(missing_ok=True)  # from here on the clip counts as incomplete
    remove_stale_temporaries(out_dir)
    fps_out = opts.fps or None

    stop = threading.Event()
    report = DecodeReport()
    frames = clip_frames(
        source,
        fps=fps_out,
        folder_fps=opts.folder_fps,
        min_frames=MIN_FRAMES,
        max_pixels=opts.max_pixels,
        report=report,
        max_gap_frames=opts.max_gap_frames,
    )
    decoded = _prefetch(frames, stop)
    # Hold two frames before writing anything, so that a clip too short to enhance leaves nothing behind.
    head: list[DecodedFrame] = []
    for f in decoded:
        head.append(f)
        if len(head) >= MIN_FRAMES:
            break
    if len(head) < MIN_FRAMES:
        stop.set()
        if fps_out and report.source_frames >= MIN_FRAMES:  # enough frames, too short a time for the rate
            raise InputError(
                f"{source}: its {report.source_frames} frames span too short a time for {fps_out:g} fps: only "
                f"{len(head)} frame(s) at that rate, at least {MIN_FRAMES} are needed (fps 0 keeps every frame)"
                f"{report.cut_note}"
            )
        raise InputError(f"{source}: only {len(head)} frame(s); at least {MIN_FRAMES} are needed{report.cut_note}")
    first_size = head[0].image.shape[:2]
    if opts.video and max(side + side % 2 for side in first_size) > MAX_VIDEO_SIDE:  # else x264 fails, cryptically
        stop.set()
        raise InputError(
            f"{source}: frames of {first_size[1]}x{first_size[0]} are too large for {VIDEO_FILE}: H.264 takes at "
            f"most {MAX_VIDEO_SIDE} pixels a side (without the video, --no-video, its frames can be written)"
        )
    video_fps = fps_out or _source_rate(head)
    sink = _FrameSink(out_dir, opts, video_fps)
    stream = content_stream(method, opts.content)
    waiting: deque[DecodedFrame] = deque()  # decoded frames whose result the method still holds back
    records: list[dict[str, Any]] = []

    def emit(results: list[FrameResult]) -> None:
        for res in results:
            meta = waiting.popleft()
            sink.write(meta.index, res.frame)
            rec: dict[str, Any] = {
                "index": meta.index,
                "time_s": round(meta.time_s, 6),
                "source_time_s": round(meta.source_time_s, 6),
                "gamma": res.gamma,
            }
            rec.update(res.info)
            records.append(rec)
            if on_frame:
                on_frame(len(records))

    def chain() -> Iterator[DecodedFrame]:
        yield from head
        yield from decoded

    try:
        try:  # a camera file for another size fails here, before any write
            camera = clip_camera(opts.camera, first_size)
        except InputError as exc:  # the camera's line names the camera file: name the clip too, as every line does
            raise InputError(f"{source}: {exc}") from None
        for f in chain():
            if f.image.shape[:2] != first_size:
                raise InputError(
                    f"{source}: frame {f.index} is {f.image.shape[1]}x{f.image.shape[0]}, "
                    f"the clip started at {first_size[1]}x{first_size[0]}"
                )
            waiting.append(f)
            emit(stream.push(f.image))
        emit(stream.flush())
        sink.finish()
    except BaseException:
        stop.set()
        sink.abort()
        raise
    if opts.frames:
        _remove_extra_frames(out_dir / FRAMES_DIR, len(records), opts.format)
    elif (out_dir / FRAMES_DIR).is_dir():
        _remove_extra_frames(out_dir / FRAMES_DIR, 0, opts.format)
    if not opts.video:
        (out_dir / VIDEO_FILE).unlink(missing_ok=True)

    write_slam_layout(out_dir, records, opts.format if opts.frames else None, camera)
    settings = settings_record(method, opts)
    gammas: dict[str, Any] = {
        "clip": clip_name,
        "source": source_name or str(source),
        "fps": fps_out,
        "method": method.name,
        "model": method.model_info(),
        "parameters": method.parameters(),
        "colonlight_version": __version__,
        "versions": library_versions(),
        "settings": settings,
        "frame_count": len(records),
    }
    warnings = tuple(report.warnings)
    if report.truncated:  # only then: a sound clip's gammas.json keeps its bytes
        gammas["truncated"] = True
    if warnings:
        gammas["warnings"] = list(warnings)
    gammas["frames"] = records
    write_json_atomic(out_dir / GAMMAS_FILE, gammas)
    return ClipResult(
        clip=clip_name,
        out_dir=out_dir,
        frames=len(records),
        seconds=time.perf_counter() - t0,
        truncated=report.truncated is not None,
        warnings=warnings,
    )


def _source_rate(head: list[DecodedFrame]) -> float:
    """The rate of a clip kept at its own frame rate, from its first two timestamps (fallback
    :data:`~colonlight.limits.DEFAULT_FPS`)."""
    dt = head[1].source_time_s - head[0].source_time_s
    return 1.0 / dt if dt > 0 else DEFAULT_FPS


def iter_enhanced(
    frames: Iterator[np.ndarray], method: Method, content: str = DEFAULT_CONTENT
) -> Iterator[FrameResult]:
    """Library convenience: enhance an iterable of RGB uint8 frames in order, yielding results as they are ready
    (:func:`colonlight.streaming.enhance_frames`, kept under this name)."""
    return enhance_frames(frames, method, content=content)


__all__ = [
    "ClipOptions",
    "ClipResult",
    "complete_record",
    "enhance_clip",
    "iter_enhanced",
    "peak_rss_bound",
    "settings_record",
]
