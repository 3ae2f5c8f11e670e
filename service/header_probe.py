"""The frame size an upload's stream header declares, read without decoding a frame (for the pixel cap).

The engine's probe decodes the first frame, which for a decompression bomb (a tiny file of 8000x8000 frames)
is already the damage. Here the container is opened with FFmpeg's own per-decoder pixel limit (``max_pixels``)
set to the cap, so that even ``avformat_find_stream_info``, which may decode a frame to learn the stream's
parameters, refuses to allocate a frame larger than the cap. The header's width and height are then read from
the stream, or, for decoders that clear the size they refused (PNG, MJPEG), from FFmpeg's refusal message.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Any

import av
import av.logging

# FFmpeg's libavutil/imgutils.c, av_image_check_size2()
_REFUSED = re.compile(r"Picture size (\d+)x(\d+) exceeds specified max pixel count")
# av.logging's settings are process-wide: one header probe at a time changes them (they take milliseconds).
_LOG_LEVEL_LOCK = threading.Lock()


def declared_frame_size(path: Path, max_pixels: int) -> tuple[int, int] | None:
    """``(width, height)`` of the largest video stream's header, or None if neither the header nor the decoder
    says (or FFmpeg cannot open the file: the engine's probe then says why, in its words)."""
    sizes = [wh for wh in _video_sizes(path, max_pixels) if wh[0] * wh[1] > 0]
    if sizes:  # the usual case (H.264, HEVC, VP9, ...): no need to listen to FFmpeg's log
        return max(sizes, key=lambda wh: wh[0] * wh[1])
    with _LOG_LEVEL_LOCK:
        level, skip = av.logging.get_level(), av.logging.get_skip_repeated()
        av.logging.set_level(av.logging.ERROR)
        av.logging.set_skip_repeated(False)  # the same refusal for the previous upload must not be swallowed
        try:
            with av.logging.Capture() as logs:  # this thread's messages only
                sizes = _video_sizes(path, max_pixels)
        finally:
            av.logging.set_level(level)
            av.logging.set_skip_repeated(skip)
    for _, _, message in logs:
        if m := _REFUSED.search(message):
            sizes.append((int(m.group(1)), int(m.group(2))))
    sizes = [wh for wh in sizes if wh[0] * wh[1] > 0]
    return max(sizes, key=lambda wh: wh[0] * wh[1], default=None)


def _video_sizes(path: Path, max_pixels: int) -> list[tuple[int, int]]:
    try:
        container: Any = av.open(
            str(path), mode="r", metadata_errors="replace", options={"max_pixels": str(max_pixels)}
        )
    except (av.error.FFmpegError, OSError, UnicodeError, ValueError):
        return []
    attached = av.stream.Disposition.attached_pic  # cover art, not frames of the clip
    with container:
        return [
            (int(s.codec_context.width or 0), int(s.codec_context.height or 0))
            for s in container.streams.video
            if s.codec_context is not None and not s.disposition & attached
        ]
