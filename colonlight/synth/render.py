"""Shading (scene radiance) and the sensor (exposure, noise, tone curve) of one frame.

Light model: a point light at the tip (offset by a few mm like a light guide), radiance

    L = (d_ref / d)^falloff * spot(angle)^k * (albedo * wrapdiffuse(n.l) + specular) * vignetting

with d the light-to-wall distance (inverse-square for falloff = 2), "wrap" diffuse that lets red light bleed
further than blue (a cheap stand-in for subsurface scattering in mucosa), and a sharp plus a broad Blinn-Phong
lobe on bump-mapped normals for wet glints. No shadows: the light sits next to the lens, so they are hidden
anyway.

Sensor: ``v = clean_exposure * L * white_balance`` (optionally blurred by the optics), plus shot and read
noise, then the camera's response: the power law ``y = v ** (1 / camera_gamma)`` followed by a highlight shoulder
``f(y) = y (1 + s) / (1 + s y)`` (``s = response_shoulder``; 0 is a pure power law); ``y = 1`` is white. Real
cameras' response curves are neither pure power laws nor known, so the shoulder varies per clip.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .camera import T_MAX_MM, Intrinsics
from .config import SynthConfig
from .geometry import Tube
from .raymarch import march
from .texture import WallTexture

D_REF_MM = 20.0
_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


@dataclass
class Radiance:
    """Linear scene radiance (H,W,3) float32 (vignetting included) and z-depth (H,W) float32 mm, inf = no
    wall."""

    rgb: np.ndarray
    depth_mm: np.ndarray


class Shader:
    """Renders radiance for a fixed camera model, scene and settings (rays and vignetting are precomputed)."""

    def __init__(self, cfg: SynthConfig, tube: Tube, tex: WallTexture, intr: Intrinsics) -> None:
        self.cfg = cfg
        self.tube = tube
        self.tex = tex
        self.intr = intr
        self.rays_cam = intr.rays().astype(np.float32)
        h, w = intr.height, intr.width
        u, v = np.meshgrid(np.arange(w) - intr.cx, np.arange(h) - intr.cy)
        rr = (u**2 + v**2) / (intr.cx**2 + intr.cy**2)  # 1 at the corners
        self.vignette = np.clip(1 - cfg.vignetting * rr, 0.05, 1).astype(np.float32)
        if cfg.mask_radius > 0:
            r = np.sqrt(rr) / cfg.mask_radius
            self.field = np.clip((1 - r) * np.sqrt(intr.cx**2 + intr.cy**2) * cfg.mask_radius + 0.5, 0, 1)
            self.field = self.field.astype(np.float32)
        else:
            self.field = None
        self.wrap = (cfg.wrap * np.array([1.0, 0.55, 0.35])).astype(np.float32)

    def render(self, pos: np.ndarray, rot: np.ndarray, light_offset_cam: np.ndarray) -> Radiance:
        """Radiance seen from tip position ``pos`` (mm) with camera-to-world rotation ``rot``."""
        rad = self.render_batch(pos[None], rot[None], light_offset_cam)
        return Radiance(rgb=rad.rgb[0], depth_mm=rad.depth_mm[0])

    def render_batch(self, pos: np.ndarray, rot: np.ndarray, light_offset_cam: np.ndarray) -> Radiance:
        """Radiance of several views at once, (F,H,W,3) and (F,H,W): one march over all their rays, which is
        much cheaper than one march per view when the views are small (the march's cost is mostly per
        iteration)."""
        cfg = self.cfg
        nf = len(pos)
        h, w = self.intr.height, self.intr.width
        hw = h * w
        rot32 = rot.astype(np.float32)
        d = np.einsum("fij,nj->fni", rot32, self.rays_cam).reshape(nf * hw, 3)
        o = np.repeat(pos.astype(np.float32), hw, axis=0)
        fwd = np.repeat(rot32[:, :, 2], hw, axis=0)
        t, hit = march(self.tube, o, d, T_MAX_MM, pixel_angle=0.5 / self.intr.fx)
        depth = np.where(hit, t * np.einsum("ij,ij->i", d, fwd), np.float32(np.inf)).astype(np.float32)
        rgb = np.zeros((nf * hw, 3), np.float32)
        hi = np.nonzero(hit)[0]
        if hi.size:
            dh = d[hi]
            th = t[hi]
            p = o[hi] + th[:, None] * dh
            _, g, c, s = self.tube.evaluate(p, grad=True)
            n = g / np.linalg.norm(g, axis=1, keepdims=True)
            view = -dh
            ndv = np.sum(n * view, axis=1)
            # texture lookup on full-size maps (cv2.remap wants 2-D maps); non-hit pixels read anything
            theta = np.zeros(nf * hw, np.float32)
            arc = np.full(nf * hw, self.tex.v0, np.float32)
            foot = np.ones(nf * hw, np.float32)
            theta[hi] = np.arctan2(s, c)
            arc[hi] = self.tube.arc_at(p[:, 2])
            foot[hi] = th / self.intr.fx / np.maximum(np.abs(ndv), 0.25)
            shape2 = (nf * h, w)
            smp = self.tex.sample(theta.reshape(shape2), arc.reshape(shape2), foot.reshape(shape2))
            smp = smp.reshape(nf * hw, 6)[hi]
            alb, gu, gv, specw = smp[:, :3], smp[:, 3], smp[:, 4], smp[:, 5]
            # bump mapping: tilt the normal against the height slopes along the wall's angle and meridian
            e_th = np.stack([-s, c, np.zeros_like(s)], axis=1)
            t_v = np.cross(e_th, n)
            t_v /= np.maximum(np.linalg.norm(t_v, axis=1, keepdims=True), 1e-6)
            e_u = np.cross(n, t_v)
            nb = n - gu[:, None] * e_u - gv[:, None] * t_v
            nb /= np.linalg.norm(nb, axis=1, keepdims=True)
            # light
            lpos = np.repeat((pos + rot @ light_offset_cam).astype(np.float32), hw, axis=0)[hi]
            lv = lpos - p
            dl = np.maximum(np.linalg.norm(lv, axis=1), 0.5)
            lv /= dl[:, None]
            ndl = np.sum(nb * lv, axis=1)
            cos_a = np.maximum(-np.einsum("ij,ij->i", lv, fwd[hi]), 0.0)
            power = (D_REF_MM / dl) ** cfg.light_falloff
            if cfg.light_spot > 0:
                power = power * cos_a**cfg.light_spot
            diff = np.clip((ndl[:, None] + self.wrap) / (1 + self.wrap), 0, None)
            hv = lv + view
            hv /= np.maximum(np.linalg.norm(hv, axis=1, keepdims=True), 1e-6)
            nh = np.clip(np.sum(nb * hv, axis=1), 0, 1)
            shin = cfg.spec_shininess
            lobe = np.sqrt(shin) / 4 * nh**shin + cfg.spec_broad * nh ** max(shin / 12, 2.0)
            spec = cfg.spec_strength * specw * lobe * (ndl > 0)
            rgb[hi] = power[:, None] * (alb * diff + spec[:, None])
        rgb = rgb.reshape(nf, h, w, 3) * self.vignette[None, :, :, None]
        return Radiance(rgb=rgb, depth_mm=depth.reshape(nf, h, w))

    def luminance_stats(self, rgb: np.ndarray) -> tuple[float, float]:
        """(mean, 95th percentile) of linear luminance inside the field stop: what auto-exposure meters."""
        y = rgb @ _LUMA
        if self.field is not None:
            y = y[self.field > 0.5]
        return float(np.mean(y)), float(np.percentile(y, 95))


def sensor(
    cfg: SynthConfig, rgb: np.ndarray, exposure: float, noise: np.ndarray | None, field: np.ndarray | None
) -> np.ndarray:
    """Display-domain frame ``y`` (H,W,3) float32, unclipped (``y > 1`` saturates), from linear radiance."""
    wb = np.array([cfg.wb_r, cfg.wb_g, cfg.wb_b], np.float32) * np.float32(exposure)
    v = rgb * wb
    if cfg.blur_px > 0.2:
        v = cv2.GaussianBlur(v, (0, 0), cfg.blur_px)
    if noise is not None:
        v = v + np.sqrt(cfg.shot_noise * np.maximum(v, 0) + cfg.read_noise**2) * noise
    y: np.ndarray = np.power(np.maximum(v, 0), np.float32(1.0 / cfg.camera_gamma))
    if field is not None:
        y *= field[..., None]
    return y


def response(y: np.ndarray, shoulder: float) -> np.ndarray:
    """The camera response's highlight shoulder on the power-law output ``y`` (identity for ``shoulder = 0``).

    ``f(y) = y (1 + s) / (1 + s y)``: f(0) = 0, f(1) = 1, increasing, slope ``1 + s`` at black (lifted shadows)
    and ``1 / (1 + s)`` at white (compressed highlights).
    """
    if shoulder == 0:
        return y
    s = np.float32(shoulder)
    shaped: np.ndarray = y * (1 + s) / (1 + s * np.maximum(y, 0))
    return shaped


def to_uint8(y: np.ndarray) -> np.ndarray:
    """Quantise a display-domain frame to 8 bits with clipping (what the recorder stores)."""
    u8: np.ndarray = np.rint(np.clip(y, 0, 1) * 255).astype(np.uint8)
    return u8
