"""Video I/O in one import: decoding to upright RGB frames picked as FFmpeg's ``fps`` filter picks them, and the
H.264 writer. The parts live in their own modules; this one names them for callers (``from colonlight.video
import iter_video_frames, VideoWriter``):

* :mod:`colonlight.fps`: the model of ``libavfilter/vf_fps.c`` (pure timestamp arithmetic, no PyAV);
* :mod:`colonlight.timestamps`: the ``ffmpeg`` tool's timestamp corrections (start shift, wrap, joins);
* :mod:`colonlight.rotation`: FFmpeg's autorotate;
* :mod:`colonlight.containers`: whether a file is cut short, from its container's size fields;
* :mod:`colonlight.decoding`: opening, decoding and the public decoding API;
* :mod:`colonlight.video_writer`: :class:`VideoWriter`.
"""

from __future__ import annotations

from .decoding import (
    VIDEO_SUFFIXES,
    DecodedFrame,
    DecodeReport,
    VideoInfo,
    is_video,
    iter_video_frames,
    probe_frame_size,
    probe_video,
)
from .fps import FpsDecision, FpsRun, FpsSelector, as_fraction, rescale_near
from .video_writer import ENCODER_THREADS, VideoWriter

__all__ = [
    "ENCODER_THREADS",
    "VIDEO_SUFFIXES",
    "DecodeReport",
    "DecodedFrame",
    "FpsDecision",
    "FpsRun",
    "FpsSelector",
    "VideoInfo",
    "VideoWriter",
    "as_fraction",
    "is_video",
    "iter_video_frames",
    "probe_frame_size",
    "probe_video",
    "rescale_near",
]
