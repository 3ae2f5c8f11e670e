"""``rnn``: the paper's recurrent gamma network, streamed frame by frame.

The network sees a small square copy of each frame (``model_size``; ``None`` feeds the full frame, as the release
does); its head predicts a handful of numbers per frame (the release's one gamma; the shipped model's monotone
tone curve), so the correction they give (``head_correction``) is applied to the full-resolution frame through a
256-entry lookup table. The first ``seeds`` frames (2, as in the release; the card's count for ours) only build
the recurrent state and are written unchanged with gamma 1.0.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from ..checkpoint import LoadedWeights, load_weights
from ..correction import CURVE_KNOTS, curve_values, gain_gamma_values
from ..curves import IDENTITY_LUT, apply_lut, curve_lut, gain_gamma_lut, gamma_lut
from ..device import resolve_device
from ..errors import OptionError
from ..limits import DEFAULT_MODEL_SIZE, MAX_MODEL_SIZE, MIN_MODEL_SIZE
from ..model import State
from ..scene_cut import SceneCutDetector, default_threshold
from ..tone_match import ToneMatcher, default_weight
from .base import FrameResult, Method, MethodStream, check_frame, integer_option, number_option
from .rnn_onnx import make_step

#: The applied gamma is kept inside this range; a value outside it is clamped and the clamp recorded.
GAMMA_MIN, GAMMA_MAX = 0.125, 4.0
#: The gain of the gain-gamma head is kept inside this range (its tanh bound is about 0.3 .. 3.3).
GAIN_MIN, GAIN_MAX = 0.25, 4.0
SEED_FRAMES = 2
#: A frame larger than this many times the network's input is first resampled bilinearly to that square
#: (``network_input``): cheap, and fine enough that the area average after it matches one of the whole frame.
PRESAMPLE = 8


def clamp_gamma(a: float) -> tuple[float, bool]:
    """Gamma ``1/a`` kept within ``[GAMMA_MIN, GAMMA_MAX]``; returns ``(gamma, clamped)``.

    A non-finite or non-positive ``a`` (the ReLU output can be exactly 0) means the network gave no usable
    answer: the frame is then left unchanged (gamma 1.0) rather than pushed to an extreme, and flagged.
    """
    if not math.isfinite(a) or a <= 0.0:
        return 1.0, True
    gamma = 1.0 / a
    if gamma < GAMMA_MIN:
        return GAMMA_MIN, True
    if gamma > GAMMA_MAX:
        return GAMMA_MAX, True
    return gamma, False


def clamp_gain_gamma(z0: float, z1: float) -> tuple[float, float, bool]:
    """``(gain, gamma, clamped)`` of the gain-gamma head's raw outputs; gamma kept in the same range as the
    gamma head's, gain within ``[GAIN_MIN, GAIN_MAX]``; non-finite outputs leave the frame unchanged, flagged."""
    if not (math.isfinite(z0) and math.isfinite(z1)):
        return 1.0, 1.0, True
    gain, gamma = gain_gamma_values(z0, z1)
    kept_gamma = min(max(gamma, GAMMA_MIN), GAMMA_MAX)
    kept_gain = min(max(gain, GAIN_MIN), GAIN_MAX)
    return kept_gain, kept_gamma, (kept_gamma != gamma or kept_gain != gain)


#: The curve head's summary gamma is the power law through its value here (the middle knot).
CURVE_SUMMARY_AT = CURVE_KNOTS[len(CURVE_KNOTS) // 2]


def table_gamma(lut: np.ndarray) -> float:
    """The summary gamma of an applied table, as the curve head's (the power law through its value at
    ``CURVE_SUMMARY_AT``, kept in the gamma range): what the records say of a table the tone match changed."""
    level = CURVE_SUMMARY_AT * 255.0
    at = float(np.interp(level, np.arange(256), lut.astype(np.float64))) / 255.0
    gamma = math.log(min(max(at, 1e-9), 1.0)) / math.log(CURVE_SUMMARY_AT)
    return min(max(gamma, GAMMA_MIN), GAMMA_MAX)


def curve_correction(z: list[float]) -> tuple[np.ndarray | None, list[float], float, bool]:
    """``(lut, values at the knots, summary gamma, clamped)`` of the curve head's raw outputs; non-finite outputs
    leave the frame unchanged (``lut`` None), flagged. The summary gamma (``log f(m) / log m`` at
    ``CURVE_SUMMARY_AT``, kept in the gamma range) is for records and plots; the curve is what is applied."""
    try:
        values, clamped = curve_values(z)
    except ValueError:
        return None, [], 1.0, True
    at = float(np.interp(CURVE_SUMMARY_AT, CURVE_KNOTS, values))
    gamma = math.log(min(max(at, 1e-9), 1.0)) / math.log(CURVE_SUMMARY_AT)
    gamma = min(max(gamma, GAMMA_MIN), GAMMA_MAX)
    return curve_lut(CURVE_KNOTS, values), [float(v) for v in values], gamma, clamped


@dataclasses.dataclass(frozen=True)
class Correction:
    """One frame's correction, from its head's raw outputs: the table applied and what the records say of it."""

    lut: np.ndarray | None  # the 256-entry table applied to the frame; None leaves the frame unchanged
    gamma: float  # the frame's gamma (the curve head's: its summary gamma)
    extra: dict[str, Any]  # recorded beside it: the curve head's values at the knots, the gain-gamma head's gain
    clamped: bool  # a raw output fell outside its range (or was not finite) and was kept inside it

    @property
    def table(self) -> np.ndarray:
        """The table as a whole: ``lut``, or the identity where the frame is left unchanged (for comparing
        corrections; the stream skips the lookup then)."""
        return IDENTITY_LUT if self.lut is None else self.lut


def head_correction(head: str, raw: list[float]) -> Correction:
    """The correction ``head`` (``gamma``, ``gain-gamma`` or ``curve``) gives for its raw outputs ``raw``: the one
    rule for the stream, the benchmarks and the tests, so a head's records and applied table cannot drift apart."""
    if head == "curve":
        lut, values, gamma, clamped = curve_correction(raw)
        return Correction(lut=lut, gamma=gamma, extra={"curve": values}, clamped=clamped)
    if head == "gain-gamma":
        gain, gamma, clamped = clamp_gain_gamma(*raw)
        return Correction(lut=gain_gamma_lut(gain, gamma), gamma=gamma, extra={"gain": gain}, clamped=clamped)
    gamma, clamped = clamp_gamma(raw[0])
    return Correction(lut=gamma_lut(gamma), gamma=gamma, extra={}, clamped=clamped)


def network_input(frame: np.ndarray, size: int | None) -> np.ndarray:
    """The copy of ``frame`` the network sees: ``size x size`` (area-averaged) or the frame itself.

    A frame whose shorter side exceeds ``PRESAMPLE x size`` is first resampled bilinearly to that square, then
    area-averaged to the target: from 1350x1080 that is about 0.4 ms against 1.6-2.6 ms for the Gaussian pyramid it
    replaced (session 15, ``python -m benchmarks model_cost``), and its gains and gammas are closer to one exact
    area average of the whole frame than the pyramid's were (README, cost).
    """
    if size is None or frame.shape[:2] == (size, size):
        return frame
    if min(frame.shape[:2]) > PRESAMPLE * size:
        frame = cv2.resize(frame, (PRESAMPLE * size, PRESAMPLE * size), interpolation=cv2.INTER_LINEAR)
    return cv2.resize(frame, (size, size), interpolation=cv2.INTER_AREA)


def _channels_last(net: torch.nn.Module) -> None:
    """Store the convolutions' weights channels-last: oneDNN runs the ConvLSTM's 64->128 convolution about 2x
    faster that way on a CPU (the whole step 10-15%; the head's outputs equal to float rounding, ~1e-7); README,
    cost. What ``Module.to(memory_format=...)`` does, in a form the type stubs accept."""
    for param in net.parameters():
        if param.ndim == 4:
            param.data = param.data.contiguous(memory_format=torch.channels_last)


def to_tensor(frame: np.ndarray, device: torch.device) -> torch.Tensor:
    """``(H, W, 3)`` uint8 -> ``(1, 3, H, W)`` float32 in [0, 1] on ``device``."""
    return torch.from_numpy(np.ascontiguousarray(frame)).to(device).permute(2, 0, 1)[None].float().div_(255.0)


class RecurrentGammaStream(MethodStream):
    """Per-clip state of :class:`RecurrentGammaMethod`: the ConvLSTM state and the frame count."""

    def __init__(self, method: RecurrentGammaMethod) -> None:
        self._method = method
        self._state: State | None = None
        self._index = 0
        self._matcher = ToneMatcher(method.tone_match) if method.tone_match > 0 else None
        self._cuts = SceneCutDetector(method.scene_cut) if method.scene_cut > 0 else None
        self._last: tuple[np.ndarray | None, float] = (None, 1.0)  # the last frame's applied table and gamma

    def predict(self, frame: np.ndarray) -> list[float]:
        """Advance the recurrent state by one frame and return the head's raw outputs (``[a]`` for the
        ``gamma`` head, ``[z0, z1]`` for ``gain-gamma``, ``CURVE_SEGMENTS`` slopes for ``curve``)."""
        m = self._method
        x = to_tensor(network_input(frame, m.model_size), m.device)
        with torch.inference_mode():
            out, self._state = m.step(x, self._state)
        return [float(v) for v in out.reshape(-1).tolist()]

    def predict_a(self, frame: np.ndarray) -> float:
        """Advance the recurrent state by one frame and return the ``gamma`` head's raw ``a``."""
        return self.predict(frame)[0]

    def restart(self) -> None:
        """Forget the clip so far (a scene cut): the next frame is treated as a clip's first."""
        self._state = None
        self._index = 0
        self._last = (None, 1.0)
        if self._matcher is not None:
            self._matcher = ToneMatcher(self._matcher.weight)

    def push(self, frame: np.ndarray) -> list[FrameResult]:
        check_frame(frame)
        verdict = self._cuts.judge(frame) if self._cuts is not None else "continues"
        if verdict == "featureless":  # nothing to judge or learn from (scene_cut): held, no state changes
            lut, gamma = self._last
            held = frame if lut is None else apply_lut(frame, lut)
            return [FrameResult(frame=held, gamma=gamma, info={"held": True})]
        cut = verdict == "cut"
        if cut:
            self.restart()
        raw = self.predict(frame)
        index, self._index = self._index, self._index + 1
        head = self._method.weights.head
        recorded = [v if math.isfinite(v) else None for v in raw]  # JSON has no NaN: a failed output reads null
        info: dict[str, Any] = {"z": recorded} if head != "gamma" else {"a": recorded[0]}
        if cut:
            info["scene_cut"] = True
        if index < self._method.seeds:
            if self._matcher is not None:
                self._matcher.keep(frame, IDENTITY_LUT)  # written unchanged: the next frame matches to it
            self._last = (None, 1.0)
            return [FrameResult(frame=frame, gamma=1.0, info={**info, "seed": True})]
        correction = head_correction(head, raw)
        info.update(correction.extra)
        if correction.clamped:
            info["clamped"] = True
        lut = correction.lut
        if self._matcher is not None:
            lut = self._matcher.table(frame, lut)
            info["applied_gamma"] = table_gamma(lut)
        corrected = frame if lut is None else apply_lut(frame, lut)
        self._last = (lut, correction.gamma)
        return [FrameResult(frame=corrected, gamma=correction.gamma, info=info)]


class RecurrentGammaMethod(Method):
    """The recurrent gamma model with loaded weights (ours by default, or the authors' ``.pth``).

    Args:
        weights: a ``.safetensors`` (ours) or ``.pth`` (the authors') file; ``None`` = the shipped default.
        model_size: the network's square input side; ``None`` or ``"full"`` feeds the full-resolution frame;
            ``"auto"`` (the default) is the size the weights were trained at, from their card, else
            ``DEFAULT_MODEL_SIZE`` (the authors' ``.pth`` has no card).
        device: ``auto | cpu | cuda | cuda:N``.
        seeds: leading frames passed through unchanged while the state builds; ``None``: the card's
            ``seed_frames`` (0 for the shipped default, trained to correct every frame), else 2 (the release).
        runtime: ``torch`` or ``onnxruntime`` (the step on ONNX Runtime, CPU only; ``methods/rnn_onnx``).
        tone_match: how much of each frame's tones to pull toward the previous output's (``tone_match``), 0..1;
            ``None``: ``DEFAULT_TONE_MATCH`` for colonlight's own heads, 0 for the paper's one-gamma head (the
            release has no such step, and the authors' checkpoint must stay exact to it).
        scene_cut: the rank correlation of consecutive frames' thumbnails below which a frame starts the stream
            afresh (``scene_cut``), 0..1, 0 = never; ``None``: ``DEFAULT_SCENE_CUT`` for colonlight's own heads,
            0 for the paper's one-gamma head.
    """

    name = "rnn"

    def __init__(
        self,
        weights: str | Path | LoadedWeights | None = None,
        model_size: int | str | None = "auto",
        device: str = "auto",
        seeds: int | None = None,
        runtime: str = "torch",
        tone_match: float | None = None,
        scene_cut: float | None = None,
    ) -> None:
        self.device = resolve_device(device)
        if isinstance(weights, LoadedWeights):  # a copy of the caller's net: moving and re-laying it is ours
            self.weights = dataclasses.replace(weights, net=copy.deepcopy(weights.net))
        else:
            self.weights = load_weights(weights)
        self.weights.net.to(self.device).eval()
        _channels_last(self.weights.net)
        self.model_size = parse_model_size(model_size, trained_at=self.weights.input_size)
        if seeds is None:  # what the weights were trained with (the card), else the release's 2
            seeds = self.weights.seed_frames if self.weights.seed_frames is not None else SEED_FRAMES
        seeds = integer_option("seeds", seeds, "a whole number >= 0")  # NaN and 1.5 were taken as they were
        if seeds < 0:
            raise OptionError(f"seeds must be a whole number >= 0, got {seeds}")
        self.seeds = seeds
        self.runtime = runtime
        if tone_match is None:
            tone_match = default_weight(self.weights.head)
        tone_match = number_option("tone_match", tone_match, "within 0..1")  # "0.5" was a TypeError of <=
        if not 0.0 <= tone_match <= 1.0:
            raise OptionError(f"tone_match must be within 0..1, got {tone_match}")
        self.tone_match = tone_match
        if scene_cut is None:
            scene_cut = default_threshold(self.weights.head)
        scene_cut = number_option("scene_cut", scene_cut, "within 0..1")
        if not 0.0 <= scene_cut <= 1.0:
            raise OptionError(f"scene_cut must be within 0..1, got {scene_cut}")
        self.scene_cut = scene_cut
        self.step = make_step(self.weights, self.model_size, self.device, runtime)  # net.step or ONNX Runtime's

    def stream(self) -> RecurrentGammaStream:
        return RecurrentGammaStream(self)

    def parameters(self) -> dict[str, Any]:
        params: dict[str, Any] = {
            "model_size": self.model_size if self.model_size is not None else "full",
            "seeds": self.seeds,
            "gamma_range": [GAMMA_MIN, GAMMA_MAX],
            "device": str(self.device),
            **({"runtime": self.runtime} if self.runtime != "torch" else {}),
            **({"tone_match": self.tone_match} if self.tone_match > 0 else {}),
            **({"scene_cut": self.scene_cut} if self.scene_cut > 0 else {}),
        }
        if self.weights.head != "gamma":  # older outputs' records stay as they were
            params["head"] = self.weights.head
        if self.weights.head == "gain-gamma":
            params["gain_range"] = [GAIN_MIN, GAIN_MAX]
        if self.weights.head == "curve":
            params["curve_knots"] = list(CURVE_KNOTS)
        if self.weights.net.inputs != "rgb":  # likewise: the paper's input goes unsaid
            params["inputs"] = self.weights.net.inputs
        return params

    def model_info(self) -> dict[str, Any]:
        return {"name": self.weights.name, "sha256": self.weights.sha256}


def parse_model_size(value: int | str | None, trained_at: int | None = None) -> int | None:
    """``"full"``/``None`` -> ``None``; ``"auto"`` -> ``trained_at`` (the weights' card) or ``DEFAULT_MODEL_SIZE``;
    a positive int (or its text) -> that int; anything else -> ValueError."""
    word = value.strip().lower() if isinstance(value, str) else None
    if value is None or word == "full":
        return None
    if word == "auto":
        return trained_at or DEFAULT_MODEL_SIZE
    accepted = "a positive integer, 'full' or 'auto'"
    if not isinstance(value, str):  # True was size 1 and 64.7 size 64, silently
        size = integer_option("model size", value, accepted)
    else:
        try:
            size = int(value)
        except ValueError:
            raise OptionError(f"model size must be {accepted}, got {value!r}") from None
    if not MIN_MODEL_SIZE <= size <= MAX_MODEL_SIZE:
        raise OptionError(f"model size must be {MIN_MODEL_SIZE}..{MAX_MODEL_SIZE} pixels, got {size}")
    return size
