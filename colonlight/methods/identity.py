"""``none``: frames pass through unchanged (the control every comparison needs)."""

from __future__ import annotations

import numpy as np

from .base import FrameResult, Method, MethodStream, check_frame


class _IdentityStream(MethodStream):
    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        return [FrameResult(frame=frame, gamma=1.0)]


class IdentityMethod(Method):
    """Leave every frame unchanged; the reported gamma is 1.0."""

    name = "none"

    def stream(self) -> MethodStream:
        return _IdentityStream()
