"""One way in for every clip: a video file (decoded with timestamps) or a folder of frame images.

Callers ask :func:`clip_frames` for frames and never care which kind a clip is.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from .errors import InputError
from .frames import is_image_folder, iter_image_folder
from .video import DecodedFrame, iter_video_frames


def clip_kind(path: Path) -> str:
    """``"video"`` for a file, ``"frames"`` for a folder of images; :class:`InputError` otherwise."""
    path = Path(path)
    if path.is_file():
        return "video"
    if path.is_dir():
        if is_image_folder(path):
            return "frames"
        raise InputError(f"{path}: folder holds no frame images")
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    raise InputError(f"{path}: not a regular file or folder")


def clip_frames(
    path: Path, fps: float | None = 18.0, folder_fps: float = 18.0, min_frames: int = 0
) -> Iterator[DecodedFrame]:
    """Frames of a clip in order: a video resampled to ``fps`` (``None``/0 keeps all), or every image of a folder.

    A folder of frames has no timestamps; its frames are taken as already extracted, at ``folder_fps``.
    ``min_frames`` counts *source* frames (a single still shown for a second would otherwise give 18 outputs)
    and raises :class:`InputError` before anything is yielded when the clip has fewer.
    """
    if clip_kind(path) == "video":
        return iter_video_frames(Path(path), fps=fps or None, min_frames=min_frames)
    return iter_image_folder(Path(path), fps=folder_fps, min_frames=min_frames)
