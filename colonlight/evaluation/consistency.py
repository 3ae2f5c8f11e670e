"""Lighting consistency beyond the mean: consecutive-frame SSIM after motion compensation, and exposure extremes.

Consecutive frames of a scope differ by motion as well as by lighting. To score lighting alone, frame ``t`` is
warped into frame ``t-1``'s view before the two are compared:

- with ground truth (synthetic clips): each pixel of ``t-1`` is lifted with its depth, moved by the relative
  pose and projected into ``t`` (inverse warping). It is *invalid* where its depth is unknown, where it leaves
  frame ``t`` or lands behind the camera, and where frame ``t``'s own depth there disagrees by more than
  ``OCCLUSION_TOL`` (occluded);
- without (a user's clip): dense optical flow (OpenCV's DIS) from ``t-1`` to ``t``, made invalid where the
  backward flow does not bring the pixel back (forward-backward check). The flow is computed once, on the
  *input* frames after histogram equalisation (so a global gain or contrast change barely moves it), and the
  same correspondence scores every method.

SSIM (scikit-image's, with Wang et al.'s settings: Gaussian weights, sigma 1.5, population covariance; on luma
in [0, 1]) is averaged over the valid pixels that are
content (not specular, not border; :func:`colonlight.metrics.content_masks`) in both frames. Invalid pixels of
the warped frame are filled from frame ``t-1`` before filtering so that they add no structure of their own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from ..metrics import bright_fraction, dark_fraction, luma

SSIM_SIGMA = 1.5
#: Smallest side (pixels) DIS optical flow is given: OpenCV refuses frames under 12 pixels on both sides and
#: crashes the process (SIGSEGV, OpenCV 5.1) on some under 16 pixels high (64x8, 100x11, 256x12, 256x15).
MIN_FLOW_SIDE = 16
#: Relative depth disagreement beyond which a warped pixel is taken as occluded.
OCCLUSION_TOL = 0.05
DARK, BRIGHT = 0.1, 0.95


@dataclass(frozen=True)
class Correspondence:
    """Where each pixel of frame ``t-1`` is found in frame ``t``.

    ``map_x``/``map_y``: float32 ``(H, W)`` coordinates in frame ``t`` (for :func:`cv2.remap`); ``valid``: bool
    ``(H, W)``.
    """

    map_x: np.ndarray
    map_y: np.ndarray
    valid: np.ndarray


def _grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    return np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))


def depth_correspondence(
    depth_ref: np.ndarray, depth_src: np.ndarray, src_from_ref: np.ndarray, K: np.ndarray
) -> Correspondence:
    """Pixels of the reference view (depth ``depth_ref``) in the source view, moved by the 4x4 ``src_from_ref``.

    Depths are z-depths in metres with ``inf`` unknown; ``K`` has pixel centres at integer coordinates.
    """
    h, w = depth_ref.shape
    u, v = _grid(h, w)
    known = np.isfinite(depth_ref) & (depth_ref > 0)
    z = np.where(known, depth_ref, 1.0).astype(np.float64)
    pts = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    q = pts @ src_from_ref[:3, :3].T + src_from_ref[:3, 3]
    zs = q[..., 2]
    front = zs > 1e-6
    zsafe = np.where(front, zs, 1.0)
    mx = (K[0, 0] * q[..., 0] / zsafe + K[0, 2]).astype(np.float32)
    my = (K[1, 1] * q[..., 1] / zsafe + K[1, 2]).astype(np.float32)
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    valid = known & front & inside
    seen = cv2.remap(depth_src.astype(np.float32), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore"):
        valid &= np.isfinite(seen) & (np.abs(seen - zs) <= OCCLUSION_TOL * zs)
    return Correspondence(mx, my, valid)


def depth_correspondences(
    depths: Sequence[np.ndarray], poses: Sequence[np.ndarray], K: np.ndarray
) -> list[Correspondence]:
    """One :func:`depth_correspondence` per consecutive pair; ``poses`` are camera-to-world 4x4."""
    out = []
    for t in range(1, len(depths)):
        src_from_ref = np.linalg.inv(poses[t]) @ poses[t - 1]
        out.append(depth_correspondence(depths[t - 1], depths[t], src_from_ref, K))
    return out


def _flow_image(frame: np.ndarray) -> np.ndarray:
    return cv2.equalizeHist(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))


def flow_correspondences(frames: Sequence[np.ndarray]) -> list[Correspondence]:
    """DIS optical flow ``t-1 -> t`` per pair, with a forward-backward consistency check.

    InputError for frames with a side under :data:`MIN_FLOW_SIDE`, which OpenCV's DIS cannot take."""
    if frames and min(frames[0].shape[:2]) < MIN_FLOW_SIDE:
        h, w = frames[0].shape[:2]
        raise InputError(f"frames of {w}x{h} are too small for optical flow (at least {MIN_FLOW_SIDE} px a side)")
    # cv2's stubs have neither this factory nor calc()'s optional flow argument (None) used below
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)  # type: ignore[attr-defined]
    grey = [_flow_image(f) for f in frames]
    h, w = grey[0].shape
    u, v = _grid(h, w)
    out = []
    for t in range(1, len(grey)):
        fwd = dis.calc(grey[t - 1], grey[t], None)
        bwd = dis.calc(grey[t], grey[t - 1], None)
        mx, my = u + fwd[..., 0], v + fwd[..., 1]
        back = cv2.remap(bwd, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        err = np.sum((fwd + back) ** 2, axis=-1)
        tol = 0.01 * (np.sum(fwd**2, axis=-1) + np.sum(back**2, axis=-1)) + 0.5
        inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
        out.append(Correspondence(mx, my, inside & (err < tol)))
    return out


def warp(frame: np.ndarray, corr: Correspondence) -> np.ndarray:
    """Frame ``t`` seen from frame ``t-1``'s view (bilinear; invalid pixels hold arbitrary values)."""
    return cv2.remap(frame, corr.map_x, corr.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def warp_mask(mask: np.ndarray, corr: Correspondence) -> np.ndarray:
    """A boolean mask of frame ``t`` carried into frame ``t-1``'s view (nearest neighbour)."""
    m = cv2.remap(mask.astype(np.uint8), corr.map_x, corr.map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    return m.astype(bool)


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel SSIM of two luma images in [0, 1] (Wang et al. 2004: Gaussian window, sigma 1.5).

    scikit-image's separable filtering is about 8x faster on CPU than kornia's 2-D convolution, with the same
    map away from the border (checked to 3e-6); over a benchmark that is many minutes.
    """
    from skimage.metrics import structural_similarity

    full: np.ndarray
    _, full = structural_similarity(
        a, b, data_range=1.0, gaussian_weights=True, sigma=SSIM_SIGMA, use_sample_covariance=False, full=True
    )
    return full


def motion_compensated_ssim(
    frames: Sequence[np.ndarray], corrs: Sequence[Correspondence], masks: Sequence[np.ndarray]
) -> np.ndarray:
    """SSIM of each frame ``t-1`` with frame ``t`` warped into its view, over valid content pixels.

    Returns an array of ``len(frames) - 1`` values (NaN for a pair without a valid content pixel).
    """
    if len(corrs) != len(frames) - 1:
        raise ValueError(f"{len(frames)} frames need {len(frames) - 1} correspondences, got {len(corrs)}")
    out = np.full(len(corrs), np.nan)
    for t, c in enumerate(corrs, 1):
        keep = c.valid & masks[t - 1] & warp_mask(masks[t], c)
        if keep.any():
            ref = luma(frames[t - 1])
            moved = np.where(c.valid, luma(warp(frames[t], c)), ref)
            out[t - 1] = float(ssim_map(ref, moved)[keep].mean())
    return out


def exposure_fractions(frames: Sequence[np.ndarray], masks: Sequence[np.ndarray]) -> tuple[float, float]:
    """Mean over frames of the fraction of content pixels darker than 0.1 and brighter than 0.95 (luma)."""
    dark = [dark_fraction(f, m, DARK) for f, m in zip(frames, masks, strict=True)]
    bright = [bright_fraction(f, m, BRIGHT) for f, m in zip(frames, masks, strict=True)]
    return float(np.mean(dark)), float(np.mean(bright))


__all__ = [
    "MIN_FLOW_SIDE",
    "Correspondence",
    "depth_correspondence",
    "depth_correspondences",
    "exposure_fractions",
    "flow_correspondences",
    "motion_compensated_ssim",
    "ssim_map",
    "warp",
    "warp_mask",
]
