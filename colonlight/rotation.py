"""Upright frames as FFmpeg's autorotate makes them (``fftools/ffmpeg_filter.c``; the same rules as ffplay's
``configure_video_filters``): from a frame's display matrix, else a legacy ``rotate`` stream tag."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
from av.sidedata.sidedata import Type as SideDataType

Transform = Callable[[np.ndarray], np.ndarray]


def display_matrix(frame: Any) -> np.ndarray | None:
    """The frame's display matrix (9 int32, 16.16 and 2.30 fixed point), if it has one.

    Looked up by type, not by iterating: PyAV 18.1.1 made iterating the side data yield their types (a mapping's
    keys), where 18.1.0 yielded the side data themselves; ``get`` by type means the same in both."""
    sd = frame.side_data.get(SideDataType.DISPLAYMATRIX)
    return None if sd is None else np.frombuffer(bytes(sd), dtype=np.int32)[:9].copy()


def rotation_tag(stream: Any) -> int | None:
    """A legacy ``rotate`` stream tag (clockwise degrees; mkv spells it ``ROTATE``), if any."""
    for key, value in stream.metadata.items():
        if key.lower() == "rotate":
            try:
                return int(float(value)) % 360
            except ValueError:
                return None
    return None


def _round_c(x: float) -> int:
    """C's ``round()``: halves away from zero (Python's ``round`` goes to even)."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def _contiguous(fn: Transform) -> Transform:
    return lambda img: np.ascontiguousarray(fn(img))


def orientation(matrix: np.ndarray | None, tag: int | None) -> tuple[int, Transform]:
    """The clockwise angle and the transform that make a frame upright, as ``ffmpeg`` (autorotate) does.

    Without a display matrix a legacy ``rotate`` tag is honoured. FFmpeg >= 7 ignores a bare tag, but a file
    carrying one (old muxers, some recorders) means it, and the rule is otherwise the same.
    """
    m = None if matrix is None else matrix.astype(np.float64) / 65536.0
    if m is None:
        theta = float(tag or 0)
    else:
        s0, s1 = math.hypot(m[0], m[3]), math.hypot(m[1], m[4])
        if s0 == 0 or s1 == 0:
            return 0, lambda img: img
        # get_rotation(): theta = -round(av_display_rotation_get(matrix)), then normalised to [0, 360)
        theta = -_round_c(-math.degrees(math.atan2(m[1] / s1, m[0] / s0)))
    theta -= 360 * math.floor(theta / 360 + 0.9 / 360)
    if abs(theta - 90) < 1:  # transpose=clock; cclock_flip (a plain transpose) if matrix[3] > 0
        if m is not None and m[3] > 0:
            return 90, _contiguous(lambda img: img.transpose(1, 0, 2))
        return 90, _contiguous(lambda img: np.rot90(img, -1))
    if abs(theta - 180) < 1:  # hflip if matrix[0] < 0, vflip if matrix[4] < 0 (both for a tag)
        hflip = m is None or m[0] < 0
        vflip = m is None or m[4] < 0
        return 180, _contiguous(lambda img: img[:: -1 if vflip else 1, :: -1 if hflip else 1])
    if abs(theta - 270) < 1:  # transpose=cclock; clock_flip (an anti-transpose) if matrix[3] < 0
        if m is not None and m[3] < 0:
            return 270, _contiguous(lambda img: img.transpose(1, 0, 2)[::-1, ::-1])
        return 270, _contiguous(lambda img: np.rot90(img, 1))
    if abs(theta) > 1:  # rotate=theta*PI/180: clockwise, same canvas, black corners

        def rotate(img: np.ndarray) -> np.ndarray:
            h, w = img.shape[:2]
            rot = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), -theta, 1.0)
            return cv2.warpAffine(img, rot, (w, h), flags=cv2.INTER_LINEAR, borderValue=(0, 0, 0))

        return round(theta) % 360, rotate
    if m is not None and m[4] < 0:  # vflip
        return 0, _contiguous(lambda img: img[::-1])
    return 0, lambda img: img
