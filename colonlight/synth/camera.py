"""Intrinsics and the scope's path: where the tip is and where it looks, frame by frame.

The path is planned for the whole clip up front (it is tiny) so the lighting ground truth can look ahead.
Motion is forward (insertion) or backward (withdrawal) along the tube while looking down it, with wandering
speed (including pauses), lateral drift, look-around, hand jitter and roll. "Close occluder" events bring the
tip near the wall and turn it toward the wall (bright foreground filling much of the view, the lumen dark
behind). Poses are camera-to-world with OpenCV axes (x right, y down, z forward); lengths in millimetres here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import SynthConfig
from .geometry import Tube
from .noise import smooth_series

T_MAX_MM = 320.0  # rays longer than this see nothing (far lumen: dark anyway after inverse-square falloff)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; pixel centres at integer coordinates."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float) -> Intrinsics:
        """Square pixels; ``fov_deg`` is the field of view across the larger image side."""
        f = 0.5 * max(width, height) / np.tan(np.deg2rad(fov_deg) / 2)
        return cls(width, height, float(f), float(f), (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def half_fov_diag(self) -> float:
        """Angle (rad) from the optical axis to the image corner."""
        return float(np.arctan(np.hypot(self.cx / self.fx, self.cy / self.fy)))

    def rays(self) -> np.ndarray:
        """Unit ray directions (H*W, 3) in camera coordinates, row-major."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        d = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], axis=-1).reshape(-1, 3)
        unit: np.ndarray = d / np.linalg.norm(d, axis=1, keepdims=True)
        return unit

    def to_dict(self) -> dict[str, float | int | str]:
        return {
            "model": "pinhole",
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
        }


@dataclass
class Trajectory:
    """Per-frame tip positions (n,3) mm, camera-to-world rotations (n,3,3), close-occluder envelope (n,) in
    [0,1]."""

    positions: np.ndarray
    rotations: np.ndarray
    occluder: np.ndarray
    light_offset_cam: np.ndarray  # (3,) mm, light guide position in camera coordinates


def plan_depths(cfg: SynthConfig, rng: np.random.Generator) -> np.ndarray:
    """Tip height z (mm) per frame: a wandering speed that sometimes stops."""
    n = cfg.n_frames
    corr = cfg.motion_corr_s * cfg.fps
    s = smooth_series(rng, n, corr)
    speed = cfg.speed_mm_s * np.maximum(0.0, 1 + cfg.speed_var * s)
    return cfg.direction * np.concatenate([[0.0], np.cumsum(speed[:-1] / cfg.fps)])


@dataclass
class _Occluder:
    """Per-frame close-occluder state: envelope in [0,1] and the parameters of the event owning each frame."""

    env: np.ndarray
    direction: np.ndarray  # (n,2) unit vector toward the wall in the slice plane
    offset: np.ndarray  # fraction of the free radius
    turn: np.ndarray  # rad, view turned toward the wall
    fold_gap: np.ndarray  # mm in front of a fold crest (nan: "wall" event, no fold approach)


def _plan_occluders(cfg: SynthConfig, rng: np.random.Generator, half_fov: float) -> _Occluder:
    """Close-occluder events: "wall" (tip pushed to the wall and turned toward it) or "fold" (tip brought a
    few mm in front of a fold crest, near the wall). The turn stays within the field of view so some dark
    lumen usually remains in a corner: bright foreground, dark background."""
    n = cfg.n_frames
    if cfg.close_occluder == "forbid":
        k = 0
    elif cfg.close_occluder == "force":
        k = 1 + int(n > 60 and rng.random() < 0.3)
    else:
        k = (1 + int(n > 60 and rng.random() < 0.3)) if rng.random() < cfg.occluder_prob else 0
    idx = np.arange(n)
    best = np.zeros(n)
    occ = _Occluder(best, np.zeros((n, 2)), np.zeros(n), np.zeros(n), np.full(n, np.nan))
    for _ in range(k):
        centre = rng.uniform(0.15, 0.85) * (n - 1)
        plateau = rng.uniform(0.3, 1.5) * cfg.fps
        ramp = max(1.0, rng.uniform(0.15, 0.5) * cfg.fps)
        if cfg.close_occluder == "force":  # make sure the event is fully developed inside the clip
            plateau = max(plateau, 0.3 * n)
            ramp = min(ramp, max(1.0, 0.15 * n))
        dist = np.maximum(np.abs(idx - centre) - plateau / 2, 0)
        w = np.where(dist < ramp, 0.5 * (1 + np.cos(np.pi * np.minimum(dist / ramp, 1.0))), 0.0)
        ang = rng.uniform(0, 2 * np.pi)
        fold = rng.random() < 0.5
        offset = rng.uniform(0.35, 0.7) if fold else rng.uniform(0.5, 0.85)
        turn = half_fov * (rng.uniform(0.1, 0.45) if fold else rng.uniform(0.45, 0.95))
        gap = rng.uniform(3.0, 9.0) if fold else np.nan
        own = w > best
        best[own] = w[own]
        occ.direction[own] = [np.cos(ang), np.sin(ang)]
        occ.offset[own] = offset
        occ.turn[own] = turn
        occ.fold_gap[own] = gap
    return occ


def plan_trajectory(
    cfg: SynthConfig, rng: np.random.Generator, tube: Tube, z: np.ndarray, half_fov: float
) -> Trajectory:
    """Full pose sequence for the tip heights ``z`` inside ``tube`` (``half_fov``: rad, centre to corner)."""
    n = cfg.n_frames
    corr = cfg.motion_corr_s * cfg.fps
    lat = cfg.lateral * np.stack([smooth_series(rng, n, corr), smooth_series(rng, n, corr)], axis=1)
    mag = np.linalg.norm(lat, axis=1, keepdims=True)
    lat *= np.minimum(1.0, 0.55 / np.maximum(mag, 1e-9))
    yaw = np.deg2rad(cfg.look_var_deg * smooth_series(rng, n, corr) + cfg.jitter_deg * smooth_series(rng, n, 0.8))
    pitch = np.deg2rad(cfg.look_var_deg * smooth_series(rng, n, corr) + cfg.jitter_deg * smooth_series(rng, n, 0.8))
    t = np.arange(n) / cfg.fps
    roll = np.deg2rad(rng.uniform(0, 360) + cfg.roll_rate_deg_s * t + cfg.roll_var_deg * smooth_series(rng, n, corr))
    lookahead = rng.uniform(25, 70)
    occ = _plan_occluders(cfg, rng, half_fov)
    env = occ.env
    ang_l = rng.uniform(0, 2 * np.pi)
    light = np.array([np.cos(ang_l), np.sin(ang_l), 0.0]) * cfg.light_offset_mm

    # "fold" events: slide the tip to a few mm in front of the next clear fold crest
    z = z.astype(np.float64).copy()
    is_fold = np.isfinite(occ.fold_gap) & (env > 0)
    if is_fold.any() and len(tube.fold_z):
        for k in np.nonzero(is_fold)[0]:
            ahead = tube.fold_z[tube.fold_z > z[k] + occ.fold_gap[k]]
            if len(ahead):
                z[k] = (1 - env[k]) * z[k] + env[k] * (ahead[0] - occ.fold_gap[k])
        # keep the slide smooth between frames that target different crests
        z = np.convolve(np.pad(z, 1, mode="edge"), np.ones(3) / 3, mode="valid") if n > 2 else z

    # lateral offsets as fractions of the free radius (smoothed over +-10 mm so folds do not shove the tip)
    off = (1 - env)[:, None] * lat + (env * occ.offset)[:, None] * occ.direction
    zz = z[:, None] + np.linspace(-10, 10, 11)[None, :]
    rfree = tube.min_radius(zz.ravel()).reshape(zz.shape).min(axis=1)
    rfree = np.maximum(rfree, 0.3 * tube.radius_mm)
    centre = tube.centre(z).astype(np.float64)
    margin = np.minimum(2.5, 0.25 * tube.radius_mm)
    scale = np.ones(n)
    for _ in range(60):  # pull the tip toward the axis until it is safely inside
        pos = centre.copy()
        pos[:, :2] += off * (scale * rfree)[:, None]
        (F,) = tube.evaluate(pos.astype(np.float32))
        bad = margin > F
        if not bad.any():
            break
        scale[bad] *= 0.85

    # viewing direction: between the tangent and a point down the tube, + look-around, jitter, occluder turn
    tang = tube.tangent(z)
    ahead_pt = tube.centre(z + lookahead).astype(np.float64) - pos
    ahead_pt /= np.linalg.norm(ahead_pt, axis=1, keepdims=True)
    f0 = tang + ahead_pt
    f0 /= np.linalg.norm(f0, axis=1, keepdims=True)
    ex = np.array([1.0, 0.0, 0.0])
    u1 = ex - (f0 @ ex)[:, None] * f0
    u1 /= np.linalg.norm(u1, axis=1, keepdims=True)
    u2 = np.cross(f0, u1)
    fwd = f0 + np.tan(yaw)[:, None] * u1 + np.tan(pitch)[:, None] * u2
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    turn = env * occ.turn
    radial = np.concatenate([occ.direction, np.zeros((n, 1))], axis=1)
    rperp = radial - np.sum(radial * fwd, axis=1, keepdims=True) * fwd
    rn = np.linalg.norm(rperp, axis=1, keepdims=True)
    rperp = np.where(rn > 1e-9, rperp / np.maximum(rn, 1e-9), 0.0)
    fwd = np.cos(turn)[:, None] * fwd + np.sin(turn)[:, None] * rperp
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)

    # frames: parallel-transport a side vector (no flips), then roll about the view axis
    rots = np.zeros((n, 3, 3))
    x = u1[0] - (u1[0] @ fwd[0]) * fwd[0]
    for i in range(n):
        f = fwd[i]
        x = x - (x @ f) * f
        x /= np.linalg.norm(x)
        xr = np.cos(roll[i]) * x + np.sin(roll[i]) * np.cross(f, x)
        y = np.cross(f, xr)
        rots[i] = np.stack([xr, y, f], axis=1)
    return Trajectory(positions=pos, rotations=rots, occluder=env, light_offset_cam=light)
