"""Scene cuts: a frame that does not continue the last one starts the stream afresh.

The recurrent network carries the lighting it has seen: its head changes the last correction, so after a cut
(a recording paused and resumed, an edited clip, the scope taken out and put back) it keeps correcting the new
scene toward the old one's level. Across a cut from a dark steady clip to a bright one, the shipped network held
the new scene at 0.28 in mean luminance where the input was 0.55, fifteen frames on (README, session 23), and the
tone matcher pulls the first frames toward the old scene's tones too. A cut is a new clip, so the stream resets.

A cut is told from a lighting change by what a lighting change keeps: the order of the pixels' brightness. Gain,
gamma, tone curves and exposure are monotone, so they leave ranks where they were; a new scene does not. The test
is the rank correlation (Spearman's, ties given their mean rank) of the two frames' grey thumbnails. On 15104
consecutive frame pairs of 256 validation clips (gain jumps, tone-curve changes, close occluders, fast motion) it
never fell below 0.28; between frames of different clips its median was 0.03, but colonoscopy views look alike
(a dark lumen in a pink tube), so a third of those pairs correlate above ``DEFAULT_SCENE_CUT``: the threshold keeps
a margin against false cuts, which cost more than missed ones, and catches about two cuts in three.

A frame whose thumbnail is one level throughout (a black dropout, a white flash, a blank screen) has no order
to keep, so it tells neither a cut nor a lighting change: it is *featureless*, and the stream holds for it (it
passes through the last frame's table and changes no state; ``methods/rnn``). Judged as a cut, one black frame
restarted the stream and left the rest of the clip at another level (by 14-21 of 255 in mean on three of five
validation clips, session 25); fed to the network, it threw the correction off for ten frames.

Ranks come from integer counts and every sum is of half-integers below 2**53, so a host computes the same
correlation exactly from the same thumbnail. Memory: one thumbnail's ranks.
"""

from __future__ import annotations

import math
from typing import Literal

import cv2
import numpy as np

from .tone_match import subsample

#: Rank correlation below which a frame starts a new scene, for colonlight's own models when none is given
#: (chosen on validation clips, session 23; README, the default model). The paper's one-gamma head defaults to 0:
#: the release has no such step.
DEFAULT_SCENE_CUT = 0.15
#: The thumbnail's side in pixels.
THUMB_SIDE = 32
#: What the test finds of a frame: it continues the last frame's scene, starts another, or has no order to judge.
Verdict = Literal["continues", "cut", "featureless"]


def default_threshold(head: str) -> float:
    """The threshold a model with ``head`` runs with when none is given: ``DEFAULT_SCENE_CUT`` for colonlight's
    own heads, 0 (off) for the paper's one-gamma head (the authors' checkpoint stays exact to its release)."""
    return 0.0 if head == "gamma" else DEFAULT_SCENE_CUT


def host_rule(threshold: float) -> dict[str, object]:
    """The test in a host's terms (the ONNX sidecar's ``scene_cut`` entry), as numbers and one text."""
    return {
        "threshold": threshold,
        "thumb_side": THUMB_SIDE,
        "rule": "skipped when threshold is 0. Per frame, before the network's step: thumb = cv::cvtColor("
        "cv::resize(sample, (thumb_side, thumb_side), INTER_AREA), RGB2GRAY), where sample is the tone match's "
        "subsample of the frame; rank of each pixel = (number of thumb pixels darker) + (number equal + 1) / 2; "
        "with r and s the two frames' ranks less their means, corr = sum(r * s) / sqrt(sum(r * r) * sum(s * s)), "
        "0 when the denominator is 0. A frame whose thumb is one level throughout is featureless: it is held "
        "(written through the last frame's applied table, identity if none; the network does not run, and the "
        "recurrent state, the tone match's memory, the frame count and the kept thumbnail stay as they were). "
        "Otherwise, after the first frame that is not featureless, corr below threshold makes this frame a new "
        "clip: the recurrent state, the tone match's memory and the frame count "
        "start again, as at the first frame. The thumbnail is kept for the next frame.",
    }


def thumbnail(frame: np.ndarray) -> np.ndarray:
    """The frame's grey ``THUMB_SIDE``-square thumbnail (uint8), area-averaged from the tone match's subsample."""
    small = cv2.resize(subsample(frame), (THUMB_SIDE, THUMB_SIDE), interpolation=cv2.INTER_AREA)
    grey: np.ndarray = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
    return grey


def mean_ranks(thumb: np.ndarray) -> np.ndarray:
    """Each pixel's rank among the thumbnail's pixels, 1-based, ties given their mean rank (float64)."""
    levels = thumb.reshape(-1)
    counts = np.bincount(levels, minlength=256).astype(np.float64)
    darker = np.cumsum(counts) - counts
    ranks: np.ndarray = (darker + (counts + 1.0) / 2.0)[levels]
    return ranks


def centred_ranks(thumb: np.ndarray) -> np.ndarray:
    """``mean_ranks`` less their mean. The ranks sum to n (n + 1) / 2 whatever the ties, so the mean is
    (n + 1) / 2 and the centred ranks stay multiples of 1/2: every sum ``correlation`` takes is exact in float64."""
    centred: np.ndarray = mean_ranks(thumb) - (thumb.size + 1) / 2.0
    return centred


def correlation(r: np.ndarray, s: np.ndarray) -> float:
    """Pearson's correlation of two centred rank vectors of one length (Spearman's of their thumbnails); 0 when
    either is flat (one level throughout)."""
    denominator = float(r @ r) * float(s @ s)
    return float(r @ s) / math.sqrt(denominator) if denominator > 0 else 0.0


def rank_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's correlation of two thumbnails of one shape; 0 when either is flat."""
    return correlation(centred_ranks(a), centred_ranks(b))


class SceneCutDetector:
    """Per-clip state: the last judged frame's thumbnail, as its centred ranks (each frame's are computed once).

    Args:
        threshold: rank correlation below which a frame starts a new scene, 0 .. 1 (0 never does).
    """

    def __init__(self, threshold: float) -> None:
        if not 0.0 <= threshold <= 1.0:
            raise ValueError(f"scene cut threshold must be within 0..1, got {threshold}")
        self.threshold = threshold
        self._previous: np.ndarray | None = None

    def judge(self, frame: np.ndarray) -> Verdict:
        """Whether ``frame`` continues the last frame judged, starts a new scene (never the first), or is
        featureless (its thumbnail one level: neither, and not remembered, so the frame after a flash is judged
        against the frame before it).

        A frame of another size is judged by its thumbnail like any other: ``--content auto`` can move the
        content box within one scene, and its thumbnail still follows the last one."""
        ranks = centred_ranks(thumbnail(frame))
        if not ranks.any():  # one level: every rank is the mean rank
            return "featureless"
        previous, self._previous = self._previous, ranks
        if previous is None or self.threshold <= 0:
            return "continues"
        return "cut" if correlation(previous, ranks) < self.threshold else "continues"
