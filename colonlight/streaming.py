"""Enhance a sequence of frames in one call that cannot lose any: ``for out in enhance_frames(frames, method)``.

A :class:`~colonlight.methods.MethodStream` may hold frames back (``deflicker`` looks ahead and returns its last
frames only from ``flush()``); a caller's loop over ``push`` that forgets ``flush`` drops them. This iterator
pushes every frame and flushes at the end, so it yields exactly one result per frame given, in order, whatever
the method. Frames are pulled one at a time: memory stays constant for a clip of any length.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from .content import DEFAULT_CONTENT, content_stream
from .errors import FrameShapeError
from .limits import DEFAULT_METHOD
from .methods import FrameResult, Method, create_method
from .methods.base import check_frame


def enhance_frames(
    frames: Iterable[np.ndarray],
    method: Method | str = DEFAULT_METHOD,
    *,
    content: str = DEFAULT_CONTENT,
    **options: Any,
) -> Iterator[FrameResult]:
    """Yield one :class:`FrameResult` per frame of ``frames`` (``(H, W, 3)`` uint8 RGB, in clip order), in order.

    ``method``: a :class:`Method` (built once, reused across clips), or a method's name, built here with
    ``options`` (``create_method(name, **options)``). Each call is one clip: a fresh stream, state from zero.
    ``content``: ``auto`` (the default, as ``colonlight enhance``'s) shows the method only the field of view
    inside a black border, less fixed text, and returns those pixels unchanged (:mod:`colonlight.content`; the
    first frames wait for the area to be found); ``full``: the whole frame. Seen whole, a scope's round border
    drove the shipped network to its brightest (session 26).
    """
    if isinstance(method, str):
        method = create_method(method, **options)
    elif not callable(getattr(method, "stream", None)):  # None or 5 failed later as "has no attribute 'stream'"
        raise TypeError(f"method must be a Method or a method's name, got {method!r}")
    elif options:
        raise TypeError("options go with a method's name; a built Method already has its own")
    stream = content_stream(method, content)
    size: tuple[int, ...] | None = None  # the clip's frame size (its first frame's)
    for index, frame in enumerate(frames):
        _check(frame, index, size)
        size = size or frame.shape[:2]
        yield from stream.push(frame)
    yield from stream.flush()


def _check(frame: np.ndarray, index: int, size: tuple[int, ...] | None) -> None:
    """``check_frame``, and the clip's frame ``size`` (one call is one clip, whatever ``content``: with ``full`` a
    frame of another size went on through the clip's state), the error naming frame ``index``."""
    try:
        check_frame(frame)
    except FrameShapeError as exc:
        raise FrameShapeError(f"frame {index}: {exc}") from None
    if size is not None and frame.shape[:2] != size:
        (h, w), (h0, w0) = frame.shape[:2], size
        raise FrameShapeError(
            f"frame {index}: frame is {w}x{h}, the clip started at {w0}x{h0}: one call is one clip of one frame size"
        )


__all__ = ["enhance_frames"]
