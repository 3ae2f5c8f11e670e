"""Temporal tone matching: each output frame's tones pulled toward the previous output frame's.

A per-frame correction estimated from one frame carries that frame's error, and independent errors flicker: the
shipped network's output flickered 1.38x as much as the clean frames on validation clips (README, session 22).
Two consecutive frames show nearly the same surface, so their tone distributions over the pixels usable in both
(not specular in either input) should agree unless the scene's own lighting moved. The matcher
takes the table that maps this frame's corrected tones onto the previous output's (quantile matching of the
pooled R, G and B samples) and applies ``weight`` of it on top of the method's table: a complementary filter,
where the frame-to-frame change comes mostly from the previous output and the level from the network, which
keeps pulling toward its own estimate (a change the network holds for several frames passes: ``weight ** n`` of
it is left after ``n`` frames). Unlike smoothing the correction over time, which lags behind a camera's gain jump
and leaves it in (session 19), this cancels the jump in the frame where it happens.

Histograms come from a nearest-neighbour subsample of at most about ``SAMPLE_PIXELS`` pixels, counted by
OpenCV: about a millisecond a frame at 1350x1080. Memory: one subsample of the last input frame, its mask and its
table, whatever the clip's length.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .curves import IDENTITY_LUT
from .metrics import SPECULAR

#: The weight of the match for colonlight's own models when none is given (chosen on validation clips, session
#: 22; README, the default model). The paper's one-gamma models default to 0: the release has no such step.
DEFAULT_TONE_MATCH = 0.7
#: Histograms are taken over a subsample of at most about this many pixels.
SAMPLE_PIXELS = 65_536
#: Fewer usable pixels in both frames than this and the frame keeps the method's table unchanged.
MIN_SHARED = 256
#: ``usable``'s bound on OpenCV's 8-bit Rec. 601 luma: the lighting metrics' ``SPECULAR``, in levels.
SPECULAR_LEVEL = math.floor(SPECULAR * 255)

_LEVELS = np.arange(256, dtype=np.float64)


def default_weight(head: str) -> float:
    """The weight a model with ``head`` runs with when none is given: ``DEFAULT_TONE_MATCH`` for colonlight's own
    heads, 0 for the paper's one-gamma head (the authors' checkpoint stays exact to its release)."""
    return 0.0 if head == "gamma" else DEFAULT_TONE_MATCH


def host_rule(weight: float) -> dict[str, object]:
    """The matcher in a host's terms (the ONNX sidecar's ``tone_match`` entry), as numbers and one text."""
    return {
        "weight": weight,
        "sample_pixels": SAMPLE_PIXELS,
        "specular_level": SPECULAR_LEVEL,
        "min_shared": MIN_SHARED,
        "rule": "skipped when weight is 0. Per frame (seed frames are only kept, with the identity table): "
        "step = max(1, ceil(sqrt(H * W / sample_pixels))); sample = the frame, or cv::resize to (ceil(W / step), "
        "ceil(H / step)) with INTER_NEAREST; usable = cv::cvtColor(sample, RGB2GRAY) <= specular_level. From the "
        "second frame on, if the previous sample has the same shape and at least min_shared pixels are usable in "
        "both: counts = the pooled R, G, B histograms (cv::calcHist, mask usable in both) of this sample moved "
        "through the head's table, and ref = the same of the previous sample moved through the table applied to "
        "it; for the levels present in each, q = (cumsum(counts) - counts / 2) / sum(counts); each present source "
        "level maps to the linear interpolation (numpy.interp) of the reference levels at its q; levels between "
        "present ones are interpolated, levels outside keep their distance to the nearest, clipped to 0..255; "
        "pulled[v] = (1 - weight) * v + weight * match[v], made non-decreasing (running maximum), rounded half to "
        "even to uint8; the applied table is pulled[head_table[v]]. Otherwise the head's table. The applied table "
        "and the sample are kept for the next frame.",
    }


def sample_step(height: int, width: int) -> int:
    """The subsample's stride: 1 up to ``SAMPLE_PIXELS`` pixels, then the least that stays under it."""
    return max(1, math.ceil(math.sqrt(height * width / SAMPLE_PIXELS)))


def subsample(frame: np.ndarray) -> np.ndarray:
    """Every ``sample_step``-th pixel each way (nearest neighbour), or the frame itself when it is small."""
    height, width = frame.shape[:2]
    step = sample_step(height, width)
    if step == 1:
        return frame
    size = (math.ceil(width / step), math.ceil(height / step))
    return cv2.resize(frame, size, interpolation=cv2.INTER_NEAREST)


def usable(frame: np.ndarray) -> np.ndarray:
    """Pixels whose tones follow the lighting, as a 0/1 uint8 mask: not specular (OpenCV's 8-bit Rec. 601 luma
    above ``SPECULAR_LEVEL``, the lighting metrics' threshold). A clipped highlight says nothing of the exposure,
    and one frame's highlights are not the next one's. A black border stays black in both frames and matches
    itself (``--content`` leaves it out altogether)."""
    return (cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) <= SPECULAR_LEVEL).astype(np.uint8)


def tone_histogram(frame: np.ndarray, mask: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Counts (float, 256) of the R, G and B samples of ``table[frame]`` over ``mask``, pooled: the histogram of
    each channel of ``frame``, moved through the table."""
    counts = sum(cv2.calcHist([frame], [c], mask, [256], [0, 256]).reshape(-1) for c in range(3))
    return np.bincount(table, weights=np.asarray(counts, dtype=np.float64), minlength=256)


def _quantiles(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The levels with counts and the mid-bin quantile of each (strictly increasing)."""
    present = np.flatnonzero(counts)
    mid = (np.cumsum(counts) - counts / 2) / counts.sum()
    return present.astype(np.float64), mid[present]


def matching_table(source: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The non-decreasing table (float, 256 entries) that maps tones counted as ``source`` onto tones counted as
    ``reference`` (histograms of 256 counts, neither empty): each level present in ``source`` goes to the reference
    level at its mid-bin quantile; levels between them are interpolated, and levels beyond them keep their
    distance to the nearest one (a subsample may miss levels the full frame has). Equal histograms give the
    identity."""
    levels_s, q_s = _quantiles(source)
    levels_r, q_r = _quantiles(reference)
    mapped = np.interp(q_s, q_r, levels_r)
    table = np.interp(_LEVELS, levels_s, mapped)
    below, above = levels_s[0] > _LEVELS, levels_s[-1] < _LEVELS
    table[below] = mapped[0] - (levels_s[0] - _LEVELS[below])
    table[above] = mapped[-1] + (_LEVELS[above] - levels_s[-1])
    clipped: np.ndarray = np.clip(table, 0.0, 255.0)
    return clipped


class ToneMatcher:
    """Per-clip state: the last input frame's subsample, its usable pixels and the table applied to it.

    Args:
        weight: how much of the match to apply, 0 (off: the method's table as it is) .. 1 (the previous
            output's tones exactly, but for what the network's own table changes).
    """

    def __init__(self, weight: float) -> None:
        if not 0.0 <= weight <= 1.0:
            raise ValueError(f"tone match weight must be within 0..1, got {weight}")
        self.weight = weight
        self._previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (subsample, usable, table)

    def table(self, frame: np.ndarray, lut: np.ndarray | None) -> np.ndarray:
        """The uint8 table to apply to ``frame`` (the input): the method's ``lut`` (``None``: identity) followed
        by ``weight`` of the match of its result to the previous output. Remembers the result for the next."""
        base = IDENTITY_LUT if lut is None else lut
        sample = subsample(frame)
        ok = usable(sample)
        out = base
        previous = self._previous
        if self.weight > 0 and previous is not None and previous[0].shape == sample.shape:
            shared = cv2.bitwise_and(ok, previous[1])
            if cv2.countNonZero(shared) >= MIN_SHARED:
                match = matching_table(
                    tone_histogram(sample, shared, base), tone_histogram(previous[0], shared, previous[2])
                )
                pulled = np.maximum.accumulate((1.0 - self.weight) * _LEVELS + self.weight * match)
                out = np.clip(np.rint(pulled), 0, 255).astype(np.uint8)[base]
        self._previous = (sample.copy() if sample is frame else sample, ok, out)
        return out

    def keep(self, frame: np.ndarray, table: np.ndarray) -> None:
        """Remember ``frame`` as written through ``table`` without matching it (a seed frame, written as it is)."""
        sample = subsample(frame)
        self._previous = (sample.copy() if sample is frame else sample, usable(sample), table)
