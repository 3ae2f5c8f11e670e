"""The wall's appearance, painted once per clip on the unrolled tube (angle x length) and sampled with mip
levels.

Channels (all linear): albedo R, G, B; height slope along the angle and along the tube (per mm, for
bump-mapped normals that break specular glints into many small sparkles, as on wet mucosa); specular weight.
Content: a pink-red base colour chosen in display space (hue/saturation/value, converted to linear),
low-frequency mottling, fine granularity, branching submucosal vessels (sharp superficial ones, blurred deep
ones), optional debris.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass
from typing import Any, cast

import cv2
import numpy as np
import numpy.typing as npt

from .config import SynthConfig
from .noise import periodic_noise

TEXEL_MM = 0.35
N_LEVELS = 4


@dataclass
class WallTexture:
    """Mip pyramid of the (Nv, Nu, 6) atlas; ``v0`` is the tube arc coordinate (mm) of row 0."""

    levels: list[np.ndarray]
    v0: float

    @property
    def n_u(self) -> int:
        return int(self.levels[0].shape[1])

    @classmethod
    def paint(cls, cfg: SynthConfig, rng: np.random.Generator, arc_lo: float, arc_hi: float) -> WallTexture:
        """Paint the wall between tube arc coordinates ``arc_lo..arc_hi`` (mm)."""
        circ = 2 * np.pi * cfg.radius_mm
        nu = max(64, int(round(circ / TEXEL_MM)))
        nv = int(np.ceil((arc_hi - arc_lo) / TEXEL_MM)) + 2
        per_mm = 1.0 / TEXEL_MM

        # base colour, chosen in display space so hue/saturation mean what they look like
        h = (cfg.hue_deg % 360.0) / 360.0
        base_disp = np.array(colorsys.hsv_to_rgb(h, cfg.saturation, cfg.albedo))
        base = base_disp**2.2
        alb = np.empty((nv, nu, 3), np.float32)
        alb[:] = base.astype(np.float32)

        # mottling: brightness and a yellow/pale tint drift, large and medium scales
        m1 = periodic_noise(rng, (nv, nu), 18 * per_mm)
        m2 = periodic_noise(rng, (nv, nu), 5 * per_mm)
        m3 = periodic_noise(rng, (nv, nu), 25 * per_mm)
        lum = np.exp(cfg.mottle * (0.75 * m1 + 0.45 * m2))
        tint = 0.5 * cfg.mottle * m3
        alb *= lum[..., None]
        alb[..., 1] *= np.exp(tint)
        alb[..., 2] *= np.exp(0.6 * tint)
        # fine granularity (mucosal pits)
        fine = periodic_noise(rng, (nv, nu), 1.2)
        alb *= (1 + 0.05 * fine)[..., None]

        # vessels
        sharp, deep = _vessels(cfg, rng, nv, nu)
        vessel_tint = np.array([0.5, 0.82, 0.62], np.float32) * rng.uniform(0.85, 1.15, 3).astype(np.float32)
        v = cfg.vessel_contrast * np.clip(sharp + 0.6 * deep, 0, 1)
        alb *= np.clip(1 - v[..., None] * vessel_tint, 0.05, 1)

        # wetness: patchy, so glints gather in some places instead of sprinkling evenly
        wet = 0.6 * periodic_noise(rng, (nv, nu), 10 * per_mm) + 0.4 * periodic_noise(rng, (nv, nu), 3 * per_mm)
        spec = np.exp(0.9 * wet - 0.4).astype(np.float32)

        # debris: yellow-brown blobs, less glossy
        if cfg.debris > 0:
            mask: np.ndarray = np.zeros((nv, nu), np.float32)
            area_cm2 = nv * nu * TEXEL_MM**2 / 100.0
            for _ in range(int(rng.poisson(cfg.debris * 0.04 * area_cm2))):
                c = (int(rng.integers(0, nu)), int(rng.integers(0, nv)))
                ax = (max(1, int(rng.uniform(0.5, 4) * per_mm)), max(1, int(rng.uniform(0.5, 4) * per_mm)))
                cv2.ellipse(mask, c, ax, float(rng.uniform(0, 180)), 0, 360, float(rng.uniform(0.5, 1)), -1)
            mask = cv2.GaussianBlur(mask, (0, 0), 1.5)
            col = np.array(colorsys.hsv_to_rgb(rng.uniform(0.06, 0.11), rng.uniform(0.45, 0.8), rng.uniform(0.45, 0.8)))
            alb = alb * (1 - mask[..., None]) + (col**2.2).astype(np.float32) * mask[..., None]
            spec *= 1 - 0.6 * mask

        # height field -> slopes per mm
        hgt = cfg.bump * (
            0.05 * periodic_noise(rng, (nv, nu), 1.0 * per_mm) + 0.02 * periodic_noise(rng, (nv, nu), 2.5)
        )
        hgt += cfg.bump * 0.08 * sharp  # vessels slightly raised
        # gentle undulation of the mucosa (mm scale) so highlights on smooth stretches wander instead of
        # drawing the long straight streaks a perfect cylinder would give
        hgt += (0.3 + 0.7 * cfg.bump) * 0.6 * periodic_noise(rng, (nv, nu), 6 * per_mm)
        gu = (np.roll(hgt, -1, axis=1) - np.roll(hgt, 1, axis=1)) * (0.5 * per_mm)
        gv = np.gradient(hgt, axis=0) * per_mm

        atlas = np.concatenate([np.clip(alb, 0, 1), gu[..., None], gv[..., None], spec[..., None]], axis=2)
        atlas = np.ascontiguousarray(atlas, dtype=np.float32)
        levels = [atlas]
        for _ in range(N_LEVELS - 1):
            levels.append(cv2.pyrDown(levels[-1]))
        return cls(levels=levels, v0=float(arc_lo))

    def sample(self, theta: np.ndarray, arc: np.ndarray, footprint_mm: np.ndarray) -> np.ndarray:
        """Atlas channels at wall points given by angle ``theta`` (rad), arc coordinate (mm) and pixel
        footprint.

        The mip level follows the footprint (trilinear), so distant walls do not sparkle with aliasing. Inputs
        are 2-D (H, W) maps; returns (H, W, 6).
        """
        u = (theta * (self.n_u / (2 * np.pi))) % self.n_u
        v = (arc - self.v0) / TEXEL_MM
        lam = np.clip(np.log2(np.maximum(footprint_mm / TEXEL_MM, 1e-6)), 0, N_LEVELS - 1)
        out: np.ndarray | None = None
        for lv, img in enumerate(self.levels):
            w = np.clip(1 - np.abs(lam - lv), 0, 1).astype(np.float32)
            if not np.any(w > 0):
                continue
            sc = 0.5**lv
            mu = (u * sc - 0.5 * (1 - sc)).astype(np.float32)
            mv = np.clip(v * sc - 0.5 * (1 - sc), 0, img.shape[0] - 1).astype(np.float32)
            s = cv2.remap(img, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            out = s * w[..., None] if out is None else out + s * w[..., None]
        assert out is not None
        return out


def _vessels(cfg: SynthConfig, rng: np.random.Generator, nv: int, nu: int) -> tuple[np.ndarray, np.ndarray]:
    """Branching vessel trees as two coverage maps in [0,1]: superficial (sharp) and deep (blurred).

    Each tree is a gently curving trunk (smooth random curvature) that forks into thinner, shorter branches;
    widths below a texel are drawn fainter instead of thinner."""
    pad = min(int(40 / TEXEL_MM), nu)
    w_can = nu + 2 * pad
    layers = [np.zeros((nv, w_can), np.uint8), np.zeros((nv, w_can), np.uint8)]
    area_cm2 = nv * nu * TEXEL_MM**2 / 100.0
    n_trees = int(rng.poisson(cfg.vessel_density * area_cm2 / 3.0))
    seg_mm = 0.6
    shift = 3
    scale = (1 << shift) / TEXEL_MM

    stack: list[tuple[float, float, float, float, float, int, int]] = []
    for _ in range(n_trees):
        stack.append(
            (
                float(rng.uniform(pad, pad + nu)) * TEXEL_MM,
                float(rng.uniform(0, nv)) * TEXEL_MM,
                float(rng.uniform(0, 2 * np.pi)),
                float(np.exp(rng.normal(np.log(30.0), 0.5))),
                cfg.vessel_width_mm * float(np.exp(rng.normal(0.0, 0.3))),
                int(rng.random() < 0.4),
                0,
            )
        )
    while stack:
        x, y, ang, length, width, layer, depth = stack.pop()
        n_seg = max(3, int(length / seg_mm))
        # smooth random curvature (running sum of 8 normals) plus a little jitter
        w_n = rng.standard_normal(n_seg + 8)
        c8 = np.cumsum(w_n)
        curv = (0.07 / np.sqrt(8)) * (c8[8:] - c8[:-8])
        angs = ang + np.cumsum(curv + 0.03 * w_n[:n_seg])
        xs = x + np.concatenate([[0.0], np.cumsum(np.cos(angs) * seg_mm)])
        ys = y + np.concatenate([[0.0], np.cumsum(np.sin(angs) * seg_mm)])
        pts = np.stack([xs * scale, ys * scale], axis=1).round().astype(np.int32)
        thick = max(1, int(round(width / TEXEL_MM)))
        inten = int(255 * min(1.0, 0.35 + 0.65 * width / TEXEL_MM))
        cv2.polylines(layers[layer], [pts], False, inten, thickness=thick, lineType=cv2.LINE_AA, shift=shift)
        if depth < 3 and width > 0.06:
            for _ in range(int(rng.poisson(length / 12.0))):
                k = int(rng.integers(1, n_seg))
                side = 1 if rng.random() < 0.5 else -1
                stack.append(
                    (
                        xs[k],
                        ys[k],
                        float(angs[k - 1] + side * rng.uniform(0.35, 1.1)),
                        length * rng.uniform(0.3, 0.65),
                        width * rng.uniform(0.5, 0.75),
                        layer,
                        depth + 1,
                    )
                )
    out = []
    for i, lay in enumerate(layers):
        f = lay.astype(np.float32) / 255.0
        f = cast("npt.NDArray[np.floating[Any]]", cv2.GaussianBlur(f, (0, 0), 0.5 if i == 0 else 1.8))  # float in, out
        if i == 1:
            f *= 1.5
        core = f[:, pad : pad + nu].copy()
        core[:, :pad] = np.maximum(core[:, :pad], f[:, pad + nu :])
        core[:, nu - pad :] = np.maximum(core[:, nu - pad :], f[:, :pad])
        out.append(np.clip(core, 0, 1))
    return out[0], out[1]
