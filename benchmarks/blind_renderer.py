"""A second colonoscopy-like clip renderer (numpy + OpenCV only), written blind to colonlight's own generator.

Written in session 32 by a helper who was told not to open ``colonlight/synth/`` and followed only the issue's
description of the independent renderer the default model is judged on (lagging auto-exposure, gain jumps,
power-curve events, 320x256, 60 frames). Its geometry, texture, optics, camera response and disturbance model are
its own. It exists to check that the default model generalises beyond the generator it was trained on, and is
**never** used to train or choose a model (:mod:`benchmarks.blind_renderer_check` runs the check).

It writes clip folders in the layout ``colonlight evaluate`` reads for synthetic clips:

    clip_NNN/frames/000000.png   recorded frames (RGB PNG, with lighting disturbances)
    clip_NNN/clean/000000.png    the same render at a fixed exposure, without disturbances
    clip_NNN/depth/000000.png    z-depth along the optical axis, uint16 PNG, 0.1 mm units, 0 = no surface
    clip_NNN/poses.txt           camera-to-world, TUM "timestamp tx ty tz qx qy qz qw", metres, OpenCV axes
    clip_NNN/intrinsics.json     pinhole fx fy cx cy width height (pixel centres at integer coordinates)
    clip_NNN/lighting.json       per-frame gain, contrast exponent, exposure (+ the events that made them)
    clip_NNN/synth.json          this renderer's settings for the clip and its seed

Scene model (all lengths in millimetres, world +Z runs down the colon):

* Geometry: an implicit bent tube. Its centreline is (cx(z), cy(z), z), with cx, cy sums of two sinusoids (bends of
  tens of mm over a few hundred mm). In each z-slice the wall is at radius R(z, theta) around the centreline:
  a base radius, a three-lobed (taenia) section that slowly twists, and haustral folds: narrow ridges, periodic
  in z with a jittered phase and varying depth, shallowest at the taeniae. The surface is F(p) = r - R = 0 with
  F < 0 inside. Each pixel's ray is marched from the camera (step a fraction of -F, capped) and the crossing is
  refined by bisection, so the depth map is exact for this surface. Normals are -grad F (central differences).
* Camera: pinhole, 95-110 degrees horizontal field of view. It moves forward along the centreline at 4-16 mm/s
  (18 fps: well under 1 mm per frame), with a slowly wandering lateral offset, yaw/pitch wobble around the
  direction of the lumen ahead, and a slow roll.
* Shading: two point lights on the scope tip, 3 mm either side of the lens, each with inverse-square falloff and
  a cosine-power spot profile; Lambertian diffuse with a procedural albedo (pinkish-red base, low-frequency blotches,
  two scales of vessel networks from the zero-crossings of domain-warped 3-D value noise, fine granularity) plus
  a Blinn-Phong "wet" specular with a sharp and a broad lobe. Optics: slight blur and radial vignetting
  1 / (1 + v rho^2)^2.
* Sensor and camera response: linear exposure, Gaussian shot+read noise in the linear domain, then a log-ish
  curve log(1 + c x) / log(1 + c) blended with a smoothstep (an S shoulder), then 8-bit clipping. No plain gamma.
* Lighting disturbances (the recorded frames; the clean frames keep exposure E0, gain 1 and exponent 1):
  - auto-exposure: every frame it meters the recorded (pre-tone-curve) centre-weighted luminance of the frame
    ``delay`` frames back and moves log-exposure a fraction ``rate`` of the way toward its own set-point (which
    differs from the clean frames' level), clamped to [0.3, 3.5] x E0: a lagging, drifting exposure;
  - gain jumps: abrupt multiplicative gain changes (x0.5-0.8 or x1.25-1.8) held 4-12 frames, then released
    abruptly or with a short exponential recovery;
  - tone-curve events: the display value y becomes y ** g (g 0.6-0.85 or 1.2-1.6), ramping in and out over a few
    frames;
  - flicker: an AR(1) log-gain jitter of 1-3 % per frame.
  The first two frames of every clip are undisturbed (frames == clean there) so restoration can be scored from
  frame 2 on, as colonlight's evaluator does. "Steady" clips have no disturbance at all: frames == clean.

Use :func:`render_clips` (``python -m benchmarks blind_renderer`` renders and scores 24 clips).

The same seed gives the same bytes (each clip draws everything from numpy's default_rng([seed, clip index])).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

RENDERER = "indep-render"
RENDERER_VERSION = "1.0"
FPS = 18.0
MAX_DEPTH_MM = 220.0  # rays travelling farther see nothing (depth 0, black)


# ----------------------------------------------------------------------------------------------- clip settings


@dataclass
class ClipSettings:
    """Everything random about one clip, drawn once from the clip's generator."""

    width: int
    height: int
    n_frames: int
    fps: float
    steady: bool
    # geometry
    radius_mm: float
    lobe: float  # depth of the three-lobed (taenia) section, fraction of the radius
    twist_rad_per_mm: float
    lobe_phase: float
    bend: list  # [(amplitude_mm, wavelength_mm, phase), ...] for x then y, two terms each
    fold_spacing_mm: float
    fold_jitter: float
    fold_depth: float  # fraction of the radius
    fold_depth_var: float
    fold_sharpness: float  # exponent of the raised cosine: higher = narrower ridges
    # camera and motion
    hfov_deg: float
    speed_mm_s: float
    speed_var: float
    offset_frac: float  # lateral offset amplitude as a fraction of the radius
    wobble_deg: float  # yaw/pitch wobble amplitude
    roll_rate_deg_s: float
    # appearance
    albedo_rgb: list
    mottle: float
    vessel_contrast: float
    vessel_scale_mm: float
    spec_strength: float
    spec_shininess: float
    spot_power: float
    vignetting: float
    blur_px: float
    # sensor / response
    response_c: float
    response_s: float
    shot_noise: float
    read_noise: float
    target_level: float  # linear level the clean exposure puts the clip's median lit pixel at
    # disturbances
    ae_rate: float
    ae_delay: int
    ae_setpoint: float  # AE target luminance relative to the clean frames' first-frame mean
    n_gain_jumps: int
    n_tone_events: int
    flicker_std: float
    flicker_corr: float


def draw_settings(rng: np.random.Generator, width: int, height: int, n_frames: int, steady: bool) -> ClipSettings:
    u = rng.uniform
    return ClipSettings(
        width=width,
        height=height,
        n_frames=n_frames,
        fps=FPS,
        steady=steady,
        radius_mm=u(12.5, 17.0),
        lobe=u(0.04, 0.12),
        twist_rad_per_mm=u(-0.004, 0.004),
        lobe_phase=u(0, 2 * math.pi),
        bend=[[u(8, 22), u(160, 380), u(0, 2 * math.pi)] for _ in range(4)],
        fold_spacing_mm=u(14, 24),
        fold_jitter=u(0.05, 0.25),
        fold_depth=u(0.15, 0.32),
        fold_depth_var=u(0.2, 0.5),
        fold_sharpness=u(6, 16),
        hfov_deg=u(95, 110),
        speed_mm_s=u(4, 16),
        speed_var=u(0.1, 0.4),
        offset_frac=u(0.05, 0.25),
        wobble_deg=u(3, 12),
        roll_rate_deg_s=u(-8, 8),
        albedo_rgb=[u(0.75, 0.9), u(0.30, 0.46), u(0.26, 0.40)],
        mottle=u(0.08, 0.25),
        vessel_contrast=u(0.3, 0.6),
        vessel_scale_mm=u(3, 6),
        spec_strength=u(0.15, 0.5),
        spec_shininess=u(40, 200),
        spot_power=u(1.0, 3.0),
        vignetting=u(0.2, 0.6),
        blur_px=u(0.4, 0.9),
        response_c=u(6, 20),
        response_s=u(0.2, 0.5),
        shot_noise=u(0.002, 0.006),
        read_noise=u(0.001, 0.004),
        target_level=u(0.10, 0.22),
        ae_rate=u(0.15, 0.45),
        ae_delay=int(rng.integers(1, 4)),
        ae_setpoint=float(np.exp(u(-0.35, 0.35))),
        n_gain_jumps=int(rng.integers(1, 4)),
        n_tone_events=int(rng.integers(1, 3)),
        flicker_std=u(0.01, 0.03),
        flicker_corr=u(0.0, 0.6),
    )


# ---------------------------------------------------------------------------------------------- solid noise

_M1, _M2, _M3 = np.uint64(0x9E3779B185EBCA87), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9)
_MIX1, _MIX2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def _lattice_value(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, salt: int) -> np.ndarray:
    """A pseudo-random value in [-1, 1] per integer lattice point (a splitmix-style integer hash)."""
    h = (ix.astype(np.uint64) * _M1) ^ (iy.astype(np.uint64) * _M2) ^ (iz.astype(np.uint64) * _M3)
    h ^= np.uint64((salt * 0x27D4EB2F165667C5) & 0xFFFFFFFFFFFFFFFF)
    h ^= h >> np.uint64(30)
    h *= _MIX1
    h ^= h >> np.uint64(27)
    h *= _MIX2
    h ^= h >> np.uint64(31)
    return (h >> np.uint64(40)).astype(np.float32) * np.float32(2.0 / (1 << 24)) - np.float32(1.0)


def value_noise(p: np.ndarray, salt: int) -> np.ndarray:
    """Smooth 3-D value noise in [-1, 1] at points ``p`` (N, 3) in lattice units (quintic-faded trilinear)."""
    fl = np.floor(p)
    f = (p - fl).astype(np.float32)
    i = fl.astype(np.int64)
    w = f * f * f * (f * (f * 6 - 15) + 10)
    out = np.zeros(len(p), dtype=np.float32)
    for dx in (0, 1):
        wx = w[:, 0] if dx else 1 - w[:, 0]
        for dy in (0, 1):
            wy = w[:, 1] if dy else 1 - w[:, 1]
            for dz in (0, 1):
                wz = w[:, 2] if dz else 1 - w[:, 2]
                out += wx * wy * wz * _lattice_value(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, salt)
    return out


def fbm(p: np.ndarray, octaves: int, salt: int) -> np.ndarray:
    """Fractal sum of value noise, roughly in [-1, 1]."""
    total, amp, norm = np.zeros(len(p), dtype=np.float32), 1.0, 0.0
    for o in range(octaves):
        total += amp * value_noise(p * (2.0**o), salt + 101 * o)
        norm += amp
        amp *= 0.5
    return total / norm


# ------------------------------------------------------------------------------------------------- the tube


class Tube:
    """The implicit colon wall F(p) = r(p) - R(z, theta), F < 0 inside (mm)."""

    def __init__(self, s: ClipSettings, rng: np.random.Generator):
        self.s = s
        self.fold_phase0 = rng.uniform(0, 1)
        self.fold_aux = rng.uniform(0, 2 * math.pi, size=4)

    def centre(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        b = self.s.bend
        cx = sum(a * np.sin(2 * np.pi * z / lam + ph) for a, lam, ph in b[:2])
        cy = sum(a * np.sin(2 * np.pi * z / lam + ph) for a, lam, ph in b[2:])
        return cx, cy

    def centre_tangent(self, z: float) -> np.ndarray:
        b = self.s.bend
        dx = sum(a * 2 * np.pi / lam * np.cos(2 * np.pi * z / lam + ph) for a, lam, ph in b[:2])
        dy = sum(a * 2 * np.pi / lam * np.cos(2 * np.pi * z / lam + ph) for a, lam, ph in b[2:])
        t = np.array([dx, dy, 1.0])
        return t / np.linalg.norm(t)

    def radius(self, z: np.ndarray, theta: np.ndarray) -> np.ndarray:
        s = self.s
        taenia = 0.5 + 0.5 * np.cos(3 * (theta - s.lobe_phase - s.twist_rad_per_mm * z))  # 1 on a taenia
        a1, a2, a3, a4 = self.fold_aux
        sp = s.fold_spacing_mm
        # fold positions: a jittered phase along z (two incommensurate slow sinusoids)
        phase = (
            z / sp
            + self.fold_phase0
            + s.fold_jitter * (np.sin(2 * np.pi * z / (3.7 * sp) + a1) + 0.6 * np.sin(2 * np.pi * z / (6.1 * sp) + a2))
        )
        ridge = (0.5 + 0.5 * np.cos(2 * np.pi * phase)) ** s.fold_sharpness
        depth = s.fold_depth * (1 + s.fold_depth_var * np.sin(2 * np.pi * z / (2.3 * sp) + a3) * np.cos(theta + a4))
        depth = depth * (1 - 0.75 * taenia**2)  # folds are interrupted at the taeniae
        return s.radius_mm * (1 - s.lobe * taenia) * (1 - depth * ridge)

    def field(self, p: np.ndarray) -> np.ndarray:
        cx, cy = self.centre(p[:, 2])
        dx, dy = p[:, 0] - cx, p[:, 1] - cy
        return np.hypot(dx, dy) - self.radius(p[:, 2], np.arctan2(dy, dx))

    def normal(self, p: np.ndarray, h: float = 0.03) -> np.ndarray:
        """Unit surface normal pointing into the lumen (-grad F)."""
        g = np.empty_like(p)
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            g[:, k] = self.field(p + e) - self.field(p - e)
        g = -g
        return g / np.linalg.norm(g, axis=1, keepdims=True)


def march(tube: Tube, origin: np.ndarray, dirs: np.ndarray, dir_len: np.ndarray) -> np.ndarray:
    """Ray parameter t (z-depth in mm, since ``dirs`` have camera z = 1) of each ray's first wall hit; inf if none.

    Sphere-tracing-like steps of 0.35 * (-F) in mm, at least 0.25 mm and at most 1.5 mm + 2 % of the distance
    so far; a step that lands outside is refined by 12 bisections.
    """
    n = len(dirs)
    t = np.zeros(n)
    hit = np.full(n, np.inf)
    active = np.arange(n)
    f = tube.field(origin + 0 * dirs)
    if np.any(f >= 0):
        raise RuntimeError("camera outside the tube")
    for _ in range(2000):
        if active.size == 0:
            break
        ta, fa = t[active], f[active]
        step_mm = np.clip(-0.35 * fa, 0.25, 1.5 + 0.02 * ta * dir_len[active])
        tn = ta + step_mm / dir_len[active]
        fn = tube.field(origin + dirs[active] * tn[:, None])
        crossed = fn >= 0
        if np.any(crossed):
            idx = active[crossed]
            lo, hi = ta[crossed], tn[crossed]
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                fm = tube.field(origin + dirs[idx] * mid[:, None])
                inside = fm < 0
                lo = np.where(inside, mid, lo)
                hi = np.where(inside, hi, mid)
            hit[idx] = 0.5 * (lo + hi)
        t[active], f[active] = tn, fn
        keep = ~crossed & (tn * dir_len[active] < MAX_DEPTH_MM)
        active = active[keep]
    return hit


# ---------------------------------------------------------------------------------------------- the camera


def _smooth_signal(rng: np.random.Generator, times: np.ndarray, n_terms: int = 3, f_lo=0.04, f_hi=0.3) -> np.ndarray:
    """A smooth random signal of unit-ish amplitude: a sum of sinusoids with random slow frequencies (Hz)."""
    out = np.zeros_like(times)
    for _ in range(n_terms):
        out += rng.uniform(0.4, 1.0) * np.sin(2 * np.pi * rng.uniform(f_lo, f_hi) * times + rng.uniform(0, 2 * np.pi))
    return out / n_terms * 1.6


def camera_path(s: ClipSettings, tube: Tube, rng: np.random.Generator) -> list[np.ndarray]:
    """Camera-to-world 4x4 poses (mm, OpenCV axes: x right, y down, z forward) for every frame."""
    times = np.arange(s.n_frames) / s.fps
    speed = s.speed_mm_s * (1 + s.speed_var * _smooth_signal(rng, times))
    z = rng.uniform(0, 500) + np.concatenate([[0.0], np.cumsum(np.maximum(speed, 0.5)[:-1] / s.fps)])
    off_x = s.offset_frac * s.radius_mm * _smooth_signal(rng, times)
    off_y = s.offset_frac * s.radius_mm * _smooth_signal(rng, times)
    yaw = np.radians(s.wobble_deg) * _smooth_signal(rng, times)
    pitch = np.radians(s.wobble_deg) * _smooth_signal(rng, times)
    roll = (
        rng.uniform(0, 2 * np.pi) + np.radians(s.roll_rate_deg_s) * times + np.radians(4.0) * _smooth_signal(rng, times)
    )
    poses = []
    for k in range(s.n_frames):
        cx, cy = tube.centre(np.array([z[k]]))
        pos = np.array([cx[0] + off_x[k], cy[0] + off_y[k], z[k]])
        # look toward the lumen ahead: the mean tangent over the next 25 mm
        ahead = sum(tube.centre_tangent(z[k] + d) for d in (0.0, 8.0, 16.0, 25.0))
        fwd = ahead / np.linalg.norm(ahead)
        x = np.cross([0.0, 1.0, 0.0], fwd)
        x /= np.linalg.norm(x)
        y = np.cross(fwd, x)
        fwd = fwd + math.tan(yaw[k]) * x + math.tan(pitch[k]) * y  # wobble around the lumen direction
        fwd /= np.linalg.norm(fwd)
        x = np.cross([0.0, 1.0, 0.0], fwd)
        x /= np.linalg.norm(x)
        y = np.cross(fwd, x)
        c, sn = math.cos(roll[k]), math.sin(roll[k])
        xr, yr = c * x + sn * y, -sn * x + c * y  # roll about the optical axis
        T = np.eye(4)
        T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = xr, yr, fwd, pos
        poses.append(T)
    return poses


# --------------------------------------------------------------------------------------------- appearance


def albedo(s: ClipSettings, p: np.ndarray, salt: int) -> np.ndarray:
    """Mucosa reflectance (N, 3) at world points ``p`` (mm): a solid texture, so it sticks to the wall."""
    base = np.array(s.albedo_rgb, dtype=np.float32)
    blotch = fbm(p / 7.0, 3, salt + 1)
    warp = np.stack([fbm(p / 5.0, 2, salt + 10 + k) for k in range(3)], axis=1) * 1.2
    q = p / s.vessel_scale_mm + warp
    v_big = np.clip(1 - np.abs(value_noise(q, salt + 20)) / 0.07, 0, 1)
    v_small = np.clip(1 - np.abs(value_noise(q * 2.7, salt + 30)) / 0.06, 0, 1) * 0.55
    vessels = np.maximum(v_big, v_small) * (0.6 + 0.4 * fbm(p / 9.0, 1, salt + 40))
    grain = value_noise(p / 0.45, salt + 50)
    a = base[None, :] * (1 + s.mottle * blotch[:, None] * np.array([0.4, 1.0, 1.1], dtype=np.float32))
    a = a * (1 - s.vessel_contrast * vessels[:, None] * np.array([0.35, 0.8, 0.65], dtype=np.float32))
    a = a * (1 + 0.05 * grain[:, None])
    return np.clip(a, 0.02, 1.0)


def response(x: np.ndarray, c: float, s_blend: float) -> np.ndarray:
    """The camera's tone curve on linear exposure x >= 0: log-ish with a smoothstep shoulder (1 -> 1)."""
    y = np.log1p(c * np.maximum(x, 0)) / math.log1p(c)
    yc = np.clip(y, 0, 1)
    return (1 - s_blend) * y + s_blend * yc * yc * (3 - 2 * yc)


def effective_gamma(s: ClipSettings) -> float:
    """1 / (d log response / d log x) at a mid-grey display value (what a gamma camera model would call gamma)."""
    xs = np.geomspace(1e-3, 1, 2000)
    ys = response(xs, s.response_c, s.response_s)
    k = int(np.argmin(np.abs(ys - 0.45)))
    slope = (math.log(ys[k + 1]) - math.log(ys[k - 1])) / (math.log(xs[k + 1]) - math.log(xs[k - 1]))
    return 1.0 / slope


def render_radiance(s: ClipSettings, tube: Tube, pose: np.ndarray, K: np.ndarray, salt: int):
    """Linear scene radiance (H, W, 3) at exposure 1 and z-depth (H, W) in mm (inf = no surface)."""
    h, w = s.height, s.width
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    d_cam = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu)], -1).reshape(-1, 3)
    R, o = pose[:3, :3], pose[:3, 3]
    dirs = d_cam @ R.T
    dlen = np.linalg.norm(d_cam, axis=1)
    t = march(tube, o, dirs, dlen)
    valid = np.isfinite(t)
    rad = np.zeros((h * w, 3), dtype=np.float32)
    p = o + dirs[valid] * t[valid, None]
    n = tube.normal(p)
    a = albedo(s, p, salt)
    view = o - p
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    total = np.zeros((len(p), 3), dtype=np.float32)
    for side in (-1.0, 1.0):  # two light guides beside the lens
        lp = o + R @ np.array([3.0 * side, 1.0, 0.0])
        ld = lp - p
        dist = np.linalg.norm(ld, axis=1)
        ld /= dist[:, None]
        # the light's spot profile: cosine power around the optical axis
        spot = np.clip(-(ld @ R[:, 2]), 0, 1) ** s.spot_power
        fall = (15.0 / dist) ** 2
        ndl = np.clip(np.sum(n * ld, axis=1), 0, None)
        hv = ld + view
        hv /= np.linalg.norm(hv, axis=1, keepdims=True)
        ndh = np.clip(np.sum(n * hv, axis=1), 0, None)
        spec = s.spec_strength * (ndh**s.spec_shininess + 0.15 * ndh**12) * (ndl > 0)
        total += (0.5 * fall * spot)[:, None] * (a * ndl[:, None] + spec[:, None])
    rad[valid] = total
    rad = rad.reshape(h, w, 3)
    # optics: slight blur and radial vignetting
    rad = cv2.GaussianBlur(rad, (0, 0), s.blur_px)
    rho2 = ((uu - K[0, 2]) ** 2 + (vv - K[1, 2]) ** 2) / (K[0, 2] ** 2 + K[1, 2] ** 2)
    rad *= (1.0 / (1 + s.vignetting * rho2) ** 2)[..., None].astype(np.float32)
    return rad, t.reshape(h, w)


# -------------------------------------------------------------------------------------------- disturbances


def luma(img: np.ndarray) -> np.ndarray:
    return 0.299 * img[..., 0] + 0.587 * img[..., 1] + 0.114 * img[..., 2]


def plan_events(s: ClipSettings, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, list]:
    """Per-frame gain (jumps and flicker, without AE) and tone exponent, and the event list."""
    n = s.n_frames
    gain = np.ones(n)
    expo = np.ones(n)
    events: list = []
    if s.steady:
        return gain, expo, events
    for _ in range(s.n_gain_jumps):
        start = int(rng.integers(4, max(5, n - 6)))
        factor = float(rng.uniform(0.5, 0.8) if rng.random() < 0.5 else rng.uniform(1.25, 1.8))
        hold = int(rng.integers(4, 13))
        recovery = float(rng.choice([1.0, rng.uniform(0.3, 0.7)]))  # fraction of log-gain removed per frame
        g = np.zeros(n)
        g[start : start + hold] = math.log(factor)
        for k in range(start + hold, n):
            g[k] = g[k - 1] * (1 - recovery)
        gain *= np.exp(g)
        events.append(
            {"type": "gain_jump", "start": start, "factor": factor, "hold": hold, "recovery_per_frame": recovery}
        )
    for _ in range(s.n_tone_events):
        start = int(rng.integers(4, max(5, n - 8)))
        g = float(rng.uniform(0.6, 0.85) if rng.random() < 0.5 else rng.uniform(1.2, 1.6))
        ramp_in, hold, ramp_out = int(rng.integers(1, 4)), int(rng.integers(3, 12)), int(rng.integers(0, 5))
        env = np.zeros(n)
        for k in range(n):
            d = k - start
            if 0 <= d < ramp_in:
                env[k] = (d + 1) / ramp_in
            elif ramp_in <= d < ramp_in + hold:
                env[k] = 1.0
            elif ramp_in + hold <= d < ramp_in + hold + ramp_out:
                env[k] = 1 - (d - ramp_in - hold + 1) / (ramp_out + 1)
        expo *= np.exp(math.log(g) * env)
        events.append(
            {
                "type": "tone_curve",
                "start": start,
                "exponent": g,
                "ramp_in": ramp_in,
                "hold": hold,
                "ramp_out": ramp_out,
            }
        )
    e = np.zeros(n)
    for k in range(1, n):
        e[k] = s.flicker_corr * e[k - 1] + math.sqrt(1 - s.flicker_corr**2) * rng.normal(0, s.flicker_std)
    gain *= np.exp(e)
    events.append({"type": "flicker", "log_gain_std": s.flicker_std, "corr": s.flicker_corr})
    events.append({"type": "auto_exposure", "rate": s.ae_rate, "delay": s.ae_delay, "setpoint": s.ae_setpoint})
    # undisturbed start, so the clean exposure is visible in the recording
    gain[:2] = 1.0
    expo[:2] = 1.0
    return gain, expo, events


def _to8(y: np.ndarray) -> np.ndarray:
    return (np.clip(y, 0, 1) * 255 + 0.5).astype(np.uint8)


# ------------------------------------------------------------------------------------------------- a clip


def intrinsics(s: ClipSettings) -> np.ndarray:
    fx = (s.width / 2) / math.tan(math.radians(s.hfov_deg) / 2)
    return np.array([[fx, 0, (s.width - 1) / 2], [0, fx, (s.height - 1) / 2], [0, 0, 1]])


def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(qx, qy, qz, qw) of a rotation matrix, qw >= 0."""
    tr = np.trace(R)
    if tr > 0:
        w = math.sqrt(1 + tr) / 2
        q = [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        r = math.sqrt(1 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0] * 4
        q[i] = r / 2
        q[j] = (R[j, i] + R[i, j]) / (2 * r)
        q[k] = (R[k, i] + R[i, k]) / (2 * r)
        q[3] = (R[k, j] - R[j, k]) / (2 * r)
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def render_clip(out: Path, seed: int, index: int, width: int, height: int, n_frames: int, steady: bool) -> Path:
    rng = np.random.default_rng([seed, index])
    s = draw_settings(rng, width, height, n_frames, steady)
    tube = Tube(s, rng)
    poses = camera_path(s, tube, rng)
    K = intrinsics(s)
    salt = int(rng.integers(1, 2**31))
    radiance, depth = [], []
    for pose in poses:
        r, d = render_radiance(s, tube, pose, K, salt)
        radiance.append(r)
        depth.append(d)
    # clean exposure: the clip's median lit pixel (over all frames) lands at target_level
    lit = np.concatenate([luma(r)[np.isfinite(d)].ravel()[::7] for r, d in zip(radiance, depth, strict=True)])
    E0 = s.target_level / float(np.median(lit))
    gain, expo, events = plan_events(s, rng)
    noise = [rng.standard_normal((height, width, 3)).astype(np.float32) for _ in range(n_frames)]

    def develop(k: int, exposure: float) -> np.ndarray:
        """Display value (before the tone exponent and clipping) of frame k at a linear exposure."""
        x = radiance[k] * exposure
        x = x + np.sqrt(s.shot_noise**2 * np.maximum(x, 0) + s.read_noise**2) * noise[k]
        return response(x, s.response_c, s.response_s)

    clean = [_to8(develop(k, E0)) for k in range(n_frames)]
    # centre-weighted meter for the auto-exposure
    uu, vv = np.meshgrid(np.linspace(-1, 1, width), np.linspace(-1, 1, height))
    meter_w = np.exp(-(uu**2 + vv**2) / 0.5)
    meter_w /= meter_w.sum()
    setpoint = float((luma(clean[0] / 255.0) * meter_w).sum()) * s.ae_setpoint
    exposure = np.ones(n_frames)  # relative to E0
    metered: list[float] = []
    frames = []
    for k in range(n_frames):
        if s.steady:
            frames.append(clean[k])
            metered.append(float("nan"))
            continue
        if k >= 2:
            j = max(0, k - 1 - s.ae_delay)  # the meter reading the AE loop acts on now (delayed)
            step = s.ae_rate * (math.log(setpoint) - math.log(max(metered[j], 1e-3)))
            exposure[k] = float(np.clip(exposure[k - 1] * math.exp(step), 0.3, 3.5))
        y = develop(k, E0 * exposure[k] * gain[k])
        metered.append(float((luma(np.clip(y, 0, 1)) * meter_w).sum()))
        frames.append(_to8(np.clip(y, 0, 1) ** expo[k]))
    if s.steady:
        exposure[:] = 1.0

    cam_gamma = effective_gamma(s)
    folder = Path(out) / f"clip_{index:03d}"
    for sub in ("frames", "clean", "depth"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    for k in range(n_frames):
        cv2.imwrite(str(folder / "frames" / f"{k:06d}.png"), cv2.cvtColor(frames[k], cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "clean" / f"{k:06d}.png"), cv2.cvtColor(clean[k], cv2.COLOR_RGB2BGR))
        d = depth[k]
        code = np.where(np.isfinite(d), np.clip(np.round(d * 10.0), 1, 65535), 0).astype(np.uint16)
        cv2.imwrite(str(folder / "depth" / f"{k:06d}.png"), code)
    with open(folder / "poses.txt", "w") as fh:
        for k, T in enumerate(poses):
            q = rotation_to_quaternion(T[:3, :3])
            t = T[:3, 3] / 1000.0  # mm -> m
            fh.write(f"{k / s.fps:.6f} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")
    intr = {
        "model": "pinhole",
        "fx": K[0, 0],
        "fy": K[1, 1],
        "cx": K[0, 2],
        "cy": K[1, 2],
        "width": width,
        "height": height,
    }
    (folder / "intrinsics.json").write_text(json.dumps(intr, indent=1))
    per_frame = []
    for k in range(n_frames):
        g, e, c = float(gain[k]), float(exposure[k]), float(expo[k])
        per_frame.append(
            {
                "index": k,
                "time_s": k / s.fps,
                "gain": g,
                "contrast": c,
                "exposure": e,
                # multiplicative effect on display values of a mid-grey pixel (a gamma-camera approximation)
                "display_gain": g ** (c / cam_gamma) * e ** (c / cam_gamma),
                "disturbed": bool(not s.steady and (abs(math.log(g * e)) > 1e-6 or abs(c - 1) > 1e-6)),
                "close_occluder": False,
            }
        )
    lighting = {
        "model": "recorded = clip(response(E0 * exposure * gain * L + noise) ** contrast); clean = "
        "clip(response(E0 * L + noise)); response = log-ish S curve (see synth.json); camera_gamma is "
        "the response's effective gamma at mid-grey",
        "camera_gamma": cam_gamma,
        "clean_exposure": E0,
        "steady": steady,
        "undisturbed_seeds": True,
        "events": events,
        "frames": per_frame,
    }
    (folder / "lighting.json").write_text(json.dumps(lighting, indent=1))
    cfg = asdict(s)
    cfg.update({"split": "indep", "close_occluder": "forbid", "undisturbed_seeds": True})
    meta = {
        "generator": RENDERER,
        "generator_version": RENDERER_VERSION,
        "seed": seed,
        "clip_index": index,
        "config": cfg,
        "formats": {
            "frames": "RGB PNG, 8 bit, disturbed (recorded)",
            "clean": "RGB PNG, 8 bit, fixed exposure",
            "depth": {
                "encoding": "uint16 PNG",
                "unit_m": 0.0001,
                "invalid": 0,
                "kind": "z-depth along the optical axis",
            },
            "poses": "TUM 'timestamp tx ty tz qx qy qz qw', camera-to-world, metres, OpenCV axes",
        },
    }
    (folder / "synth.json").write_text(json.dumps(meta, indent=1))
    return folder


def _job(args: tuple[Path, int, int, int, int, int, bool]) -> str:
    cv2.setNumThreads(1)
    return str(render_clip(*args))


def render_clips(
    out: Path,
    seed: int,
    clips: int = 12,
    frames: int = 60,
    width: int = 320,
    height: int = 256,
    workers: int = 2,
    only: Sequence[int] | None = None,
) -> list[Path]:
    """Render clips ``0..clips-1`` of ``seed`` (or the indices ``only``) into ``out/clip_NNN`` (every 4th
    steady: ``is_steady``), skipping those already complete (``synth.json`` is written last); the clip folders."""
    indices = list(range(clips)) if only is None else list(only)
    jobs = [(out, seed, i, width, height, frames, is_steady(i)) for i in indices]
    todo = [j for j in jobs if not (out / f"clip_{j[2]:03d}" / "synth.json").is_file()]
    if workers > 1 and len(todo) > 1:
        with ProcessPoolExecutor(workers) as pool:
            list(pool.map(_job, todo))
    else:
        for job in todo:
            _job(job)
    return [out / f"clip_{i:03d}" for i in indices]


def is_steady(index: int) -> bool:
    """Whether clip ``index`` of a seed is rendered steady (no lighting disturbance): every 4th, from 3."""
    return index % 4 == 3
