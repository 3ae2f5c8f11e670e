"""Lighting metrics on frame sequences (RGB uint8), shared by the quality gate and `colonlight evaluate`.

Pixels that count ("content"): not specular in the input (luma > 0.7, the training loss's mask) and not black
border (pixels that stay below 10/255 in every channel through the whole input clip: the scope's mask, not the
lumen, which moves). Luminance is Rec. 601 luma in [0, 1].
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

SPECULAR = 0.7
BORDER = 10 / 255
_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


def luma(frame: np.ndarray) -> np.ndarray:
    """``(H, W)`` float32 luma in [0, 1] of an RGB uint8 frame."""
    return (frame.astype(np.float32) @ _LUMA) / 255.0


def border_mask(frames: Sequence[np.ndarray]) -> np.ndarray:
    """True where every frame of the clip is black (below 10/255 in all channels)."""
    peak = np.zeros(frames[0].shape[:2], np.uint8)
    for f in frames:
        np.maximum(peak, f.max(axis=2), out=peak)
    return peak < BORDER * 255


def content_masks(inputs: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Per frame: pixels neither specular in that input frame nor border."""
    border = border_mask(inputs)
    return [(luma(f) <= SPECULAR) & ~border for f in inputs]


def mean_luma(frames: Sequence[np.ndarray], masks: Sequence[np.ndarray]) -> np.ndarray:
    """Mean luma over each frame's mask (NaN where a mask is empty)."""
    out = []
    for f, m in zip(frames, masks, strict=False):
        out.append(float(luma(f)[m].mean()) if m.any() else float("nan"))
    return np.array(out)


def flicker(frames: Sequence[np.ndarray], masks: Sequence[np.ndarray]) -> float:
    """Mean over consecutive frames of |change in mean luminance| over the pixels masked in both frames.

    Both means of a pair are taken over the same pixels: with each frame's own mask, a brighter input frame
    (more pixels above the specular threshold) would move the mean by changing which pixels count, and even
    a perfect restoration would appear to flicker.
    """
    if len(frames) < 2:
        return 0.0
    d = []
    prev = luma(frames[0])
    for t in range(1, len(frames)):
        cur = luma(frames[t])
        both = masks[t - 1] & masks[t]
        if both.any():
            d.append(abs(float(cur[both].mean()) - float(prev[both].mean())))
        prev = cur
    return float(np.mean(d)) if d else 0.0


def mse(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Mean squared error of two RGB uint8 frames over the masked pixels (NaN if the mask is empty)."""
    if not mask.any():
        return float("nan")
    diff = a.astype(np.float64)[mask] - b.astype(np.float64)[mask]
    return float((diff**2).mean())


def psnr_from_mse(value: float) -> float:
    """PSNR in dB for 8-bit data (inf for identical frames)."""
    return float("inf") if value == 0 else float(10.0 * np.log10(255.0**2 / value))


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB) of two RGB uint8 frames over the masked pixels."""
    return psnr_from_mse(mse(a, b, mask))


def dark_fraction(frame: np.ndarray, mask: np.ndarray, threshold: float = 0.1) -> float:
    """Fraction of masked pixels with luma below ``threshold`` (dark regions)."""
    return float((luma(frame)[mask] < threshold).mean()) if mask.any() else 0.0


def bright_fraction(frame: np.ndarray, mask: np.ndarray, threshold: float = 0.95) -> float:
    """Fraction of masked pixels with luma above ``threshold`` (over-exposure)."""
    return float((luma(frame)[mask] > threshold).mean()) if mask.any() else 0.0


@dataclass(frozen=True)
class ClipLighting:
    """Lighting summary of one enhanced clip against its input (and its clean frames when known)."""

    flicker_in: float
    flicker_out: float
    mean_luma_in: float
    mean_luma_out: float
    psnr_in: float | None = None  # input vs clean
    psnr_out: float | None = None  # enhanced vs clean

    @property
    def flicker_reduction(self) -> float:
        """1 - flicker_out / flicker_in (0.5 = halved)."""
        return 1.0 - self.flicker_out / self.flicker_in if self.flicker_in > 0 else 0.0


def _mean_of_defined(values: Sequence[float] | np.ndarray) -> float:
    """The mean of the values that are not NaN, or NaN when none is (a clip without content pixels, e.g. all
    black): ``np.nanmean`` gives the same, with a RuntimeWarning the user would see."""
    array = np.asarray(values, dtype=np.float64)
    return math.nan if np.isnan(array).all() else float(np.nanmean(array))


def clip_lighting(
    inputs: Sequence[np.ndarray],
    outputs: Sequence[np.ndarray],
    clean: Sequence[np.ndarray] | None = None,
    skip: int = 2,
    masks: Sequence[np.ndarray] | None = None,
) -> ClipLighting:
    """Flicker and brightness of ``outputs`` against ``inputs``; PSNR to ``clean`` from frame ``skip`` on.

    The clip's PSNR is that of its mean squared error over all compared frames (a per-frame mean of PSNR would
    be infinite as soon as one input frame equals its clean frame). ``masks``: ``content_masks(inputs)``, when
    the caller already has them (scoring several methods on one clip).
    """
    masks = content_masks(inputs) if masks is None else masks
    lin, lout = mean_luma(inputs, masks), mean_luma(outputs, masks)
    p_in = p_out = None
    if clean is not None:
        p_in = psnr_from_mse(
            _mean_of_defined([mse(i, c, m) for i, c, m in zip(inputs[skip:], clean[skip:], masks[skip:], strict=False)])
        )
        p_out = psnr_from_mse(
            _mean_of_defined(
                [mse(o, c, m) for o, c, m in zip(outputs[skip:], clean[skip:], masks[skip:], strict=False)]
            )
        )
    return ClipLighting(
        flicker_in=flicker(inputs, masks),
        flicker_out=flicker(outputs, masks),
        mean_luma_in=_mean_of_defined(lin),
        mean_luma_out=_mean_of_defined(lout),
        psnr_in=p_in,
        psnr_out=p_out,
    )
