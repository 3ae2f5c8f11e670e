"""Seeded random fields: smooth 1-D series (motion, drifts) and 2-D noise images (texture), all deterministic.

Each consumer gets its own generator from :func:`stream` so that adding draws in one part of the generator
does not change the random numbers of another (a clip stays reproducible part by part).
"""

from __future__ import annotations

import zlib

import cv2
import numpy as np


def stream(seed: int, name: str, *extra: int) -> np.random.Generator:
    """An independent generator for (seed, part name, extra indices)."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(name.encode()), *extra])


def smooth_series(rng: np.random.Generator, n: int, corr: float) -> np.ndarray:
    """A length-``n`` Gaussian-smoothed white-noise series with unit standard deviation and ~``corr`` samples
    of correlation, so motions wander smoothly instead of jumping frame to frame."""
    sigma = max(float(corr), 0.3)
    half = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    k /= np.sqrt(np.sum(k**2))
    w = rng.standard_normal(n + 2 * half)
    return np.convolve(w, k, mode="valid")[:n]


def periodic_noise(rng: np.random.Generator, shape: tuple[int, int], cell: float) -> np.ndarray:
    """Smooth value noise of unit std, periodic along axis 1 (the tube's angle), with features ~``cell``
    pixels.

    A coarse random grid is tiled three times across, upsampled bicubically and the middle third kept, so the
    left and right edges meet without a seam.
    """
    h, w = shape
    gh = max(2, int(np.ceil(h / cell)) + 3)
    gw = max(3, int(round(w / cell)))
    g = rng.standard_normal((gh, gw)).astype(np.float32)
    tiled = np.concatenate([g, g, g], axis=1)
    big_w = 3 * w
    big_h = int(round(gh * big_w / (3 * gw)))
    up = cv2.resize(tiled, (big_w, max(big_h, h)), interpolation=cv2.INTER_CUBIC)
    out = up[:h, w : 2 * w]
    sd = float(out.std())
    return (out - float(out.mean())) / (sd if sd > 1e-8 else 1.0)
