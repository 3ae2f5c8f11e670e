"""``colonlight.sources``: the one way in for every clip (a video file or a folder of frames), on real files."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from colonlight.errors import FrameTooLargeError, InputError
from colonlight.sources import check_frame_size, clip_frames, clip_kind
from tests.media import make_clip, make_image_folder, needs_ffmpeg, read_index


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clip(tmp_path_factory.mktemp("src") / "clip.mp4", n_frames=10, fps=10)


def test_kind_of_each_path(tmp_path: Path) -> None:
    make_image_folder(tmp_path / "frames", n=3)
    (tmp_path / "empty").mkdir()
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "file.bin").write_bytes(b"x")
    assert clip_kind(tmp_path / "file.bin") == "video"  # a file is a video until decoding says otherwise
    assert clip_kind(tmp_path / "frames") == "frames"
    for name, cause in (
        ("empty", "folder holds no frame images"),
        ("missing", "no such file or folder"),
        ("fifo", "not a regular file or folder"),
    ):
        with pytest.raises(InputError) as err:
            clip_kind(tmp_path / name)
        assert str(err.value) == f"{tmp_path / name}: {cause}"


@needs_ffmpeg
def test_video_frames_in_order_and_its_header_size(video: Path) -> None:
    frames = list(clip_frames(video, fps=None))
    assert [read_index(f.image) for f in frames] == list(range(10))
    assert [f.index for f in frames] == list(range(10))
    assert check_frame_size(video) == (128, 96)
    with pytest.raises(FrameTooLargeError) as err:
        check_frame_size(video, max_pixels=128 * 96 - 1)
    assert (err.value.width, err.value.height) == (128, 96)


@needs_ffmpeg
def test_video_resampled_to_fps(video: Path) -> None:
    # 10 frames at 10 fps resampled to 5 fps: FFmpeg's fps filter keeps every second frame
    assert [read_index(f.image) for f in clip_frames(video, fps=5)] == [0, 2, 4, 6, 8]


def test_folder_frames_at_the_folder_rate_and_min_frames(tmp_path: Path) -> None:
    make_image_folder(tmp_path / "f", n=4, size=(64, 48))
    frames = list(clip_frames(tmp_path / "f", fps=None, folder_fps=2.0))
    assert [read_index(f.image) for f in frames] == [0, 1, 2, 3]
    assert [f.time_s for f in frames] == [0.0, 0.5, 1.0, 1.5]
    assert check_frame_size(tmp_path / "f") == (64, 48)
    with pytest.raises(InputError):
        next(clip_frames(tmp_path / "f", min_frames=5))
    with pytest.raises(FrameTooLargeError):
        list(clip_frames(tmp_path / "f", max_pixels=64 * 48 - 1))
