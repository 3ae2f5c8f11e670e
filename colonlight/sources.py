"""One way in for every clip: a video file (decoded with timestamps) or a folder of frame images.

Callers ask :func:`clip_frames` for frames and never care which kind a clip is.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

from .errors import InputError, os_error_cause
from .frames import check_image_size, is_image_folder, iter_image_folder, list_image_frames
from .limits import DEFAULT_FPS, max_pixels_setting
from .video import DecodedFrame, DecodeReport, iter_video_frames, probe_frame_size


def clip_kind(path: Path) -> str:
    """``"video"`` for a file, ``"frames"`` for a folder of images; :class:`InputError` otherwise."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:  # a link loop or a dangling link is named as one: "no such file" sent users looking
        if not os.path.lexists(path):
            raise InputError(f"{path}: no such file or folder") from None
        raise InputError(f"{path}: {os_error_cause(exc)}") from None
    if stat.S_ISREG(mode):
        return "video"
    if stat.S_ISDIR(mode):
        if is_image_folder(path):
            return "frames"
        raise InputError(f"{path}: folder holds no frame images")
    raise InputError(f"{path}: not a regular file or folder")


def check_frame_size(path: Path, max_pixels: int | None = None) -> tuple[int, int] | None:
    """Refuse a clip whose frames exceed the pixel cap, from headers only (nothing is decoded).

    For a video file the stream header; for a folder of frames the header of its first image (each further image
    is checked as it is read). ``max_pixels`` None means the configured cap
    (:func:`colonlight.limits.max_pixels_setting`: ``COLONLIGHT_MAX_PIXELS`` or ``DEFAULT_MAX_PIXELS``).
    Raises :class:`~colonlight.errors.FrameTooLargeError` (``.width``, ``.height``, ``.max_pixels``) if too large,
    :class:`InputError` if the clip cannot be read at all. Returns the header's ``(width, height)`` (None for an
    image header Pillow cannot read). The service calls this at upload time.
    """
    cap = max_pixels_setting() if max_pixels is None else int(max_pixels)
    if clip_kind(path) == "video":
        return probe_frame_size(Path(path), cap)
    return check_image_size(list_image_frames(Path(path))[0], cap)


def clip_frames(
    path: Path,
    fps: float | None = DEFAULT_FPS,
    folder_fps: float = DEFAULT_FPS,
    min_frames: int = 0,
    max_pixels: int | None = None,
    report: DecodeReport | None = None,
    max_gap_frames: int | None = None,
) -> Iterator[DecodedFrame]:
    """Frames of a clip in order: a video resampled to ``fps`` (``None``/0 keeps all), or every image of a folder.

    A folder of frames has no timestamps; its frames are taken as already extracted, at ``folder_fps``.
    ``min_frames`` counts *source* frames (a single still shown for a second would otherwise give 18 outputs)
    and raises :class:`InputError` before anything is yielded when the clip has fewer. Frames of more than
    ``max_pixels`` pixels (None: the configured cap) are refused from their header, before they are decoded.
    A video's ``report`` learns what decoding found besides frames (a truncated file, damaged packets); a
    timestamp gap repeating a frame more than ``max_gap_frames`` times (None: the configured cap) fails it.
    """
    if clip_kind(path) == "video":
        return iter_video_frames(
            Path(path),
            fps=fps or None,
            min_frames=min_frames,
            max_pixels=max_pixels,
            max_gap_frames=max_gap_frames,
            report=report,
        )
    return iter_image_folder(Path(path), fps=folder_fps, min_frames=min_frames, max_pixels=max_pixels)
