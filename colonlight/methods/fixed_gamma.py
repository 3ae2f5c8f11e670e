"""``gamma``: one fixed power curve for every frame, the simplest global brightening baseline.

It has no state and no data dependence, so it isolates how much of an enhancement's effect a single
well-chosen global exponent already buys.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..curves import apply_lut, gamma_lut
from ..errors import OptionError
from .base import FrameResult, Method, MethodStream, check_frame, number_option


class _FixedGammaStream(MethodStream):
    def __init__(self, gamma: float, lut: np.ndarray) -> None:
        self._gamma = gamma
        self._lut = lut

    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        return [FrameResult(frame=apply_lut(frame, self._lut), gamma=self._gamma)]


class FixedGammaMethod(Method):
    """``out = round(255 * (in / 255) ** gamma)`` on every RGB sample of every frame.

    Args:
        gamma: the exponent, finite and > 0; below 1 brightens (default 0.7). It is reported as
            :attr:`FrameResult.gamma` of every frame.
    """

    name = "gamma"

    def __init__(self, gamma: float = 0.7) -> None:
        gamma = number_option("gamma", gamma, "finite and > 0")
        if gamma <= 0:
            raise OptionError(f"gamma must be finite and > 0, got {gamma!r}")
        self.gamma = gamma
        self._lut = gamma_lut(gamma)

    def stream(self) -> MethodStream:
        return _FixedGammaStream(self.gamma, self._lut)

    def parameters(self) -> dict[str, Any]:
        return {"gamma": self.gamma}
