"""Assemble a clip: scene (tube, texture, path), lighting ground truth, then frames one at a time.

Everything derives from ``(config, seed)`` through named random streams, so the same pair gives byte-identical
frames. Memory is constant in the number of frames: only the path and the lighting schedule (a few numbers per
frame) are planned ahead; the schedule needs each frame's brightness, measured on a 32-pixel preview render
(all frames marched together).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import T_MAX_MM, Intrinsics, Trajectory, plan_depths, plan_trajectory
from .config import SynthConfig
from .disturb import LightingSchedule, plan_lighting
from .geometry import Tube
from .noise import stream
from .render import Shader, response, sensor, to_uint8
from .texture import WallTexture

PREVIEW_PX = 32


@dataclass
class SynthFrame:
    """One rendered frame with its ground truth.

    ``depth``: metres along the optical axis (z-depth), float32, ``inf`` where no wall is within reach (far
    lumen, > ~0.3 m). ``pose``: 4x4 camera-to-world, metres, OpenCV camera axes (x right, y down, z forward).
    ``lighting``: gain, contrast, exposure, display_gain, disturbed (see ``colonlight.synth.disturb``).
    ``occluder``: the tip is at the wall (a "close occluder" moment).
    """

    index: int
    time_s: float
    image: np.ndarray
    clean: np.ndarray
    depth: np.ndarray
    pose: np.ndarray
    lighting: dict[str, Any]
    occluder: bool


@dataclass
class Scene:
    """Everything planned before the first frame."""

    cfg: SynthConfig
    seed: int
    tube: Tube
    texture: WallTexture
    intrinsics: Intrinsics
    path: Trajectory
    shader: Shader
    lighting: LightingSchedule

    def pose(self, i: int) -> np.ndarray:
        """Camera-to-world 4x4 in metres."""
        m = np.eye(4)
        m[:3, :3] = self.path.rotations[i]
        m[:3, 3] = self.path.positions[i] / 1000.0
        return m


def build_scene(cfg: SynthConfig, seed: int) -> Scene:
    """Plan a clip: draw geometry, texture and path, meter a preview, plan the lighting disturbances."""
    z = plan_depths(cfg, stream(seed, "depths"))
    tube = Tube.build(cfg, stream(seed, "tube"), float(z.min()) - 40.0, float(z.max()) + T_MAX_MM + 40.0)
    intr = Intrinsics.from_fov(cfg.width, cfg.height, cfg.fov_deg)
    path = plan_trajectory(cfg, stream(seed, "path"), tube, z, intr.half_fov_diag)
    tex = WallTexture.paint(cfg, stream(seed, "texture"), float(tube.arc[0]), float(tube.arc[-1]))
    shader = Shader(cfg, tube, tex, intr)
    scale = PREVIEW_PX / max(cfg.width, cfg.height)
    w_p, h_p = max(8, round(cfg.width * scale)), max(8, round(cfg.height * scale))
    preview = Shader(cfg, tube, tex, Intrinsics.from_fov(w_p, h_p, cfg.fov_deg))
    stats = np.zeros((cfg.n_frames, 2))
    per_batch = max(1, 40000 // (w_p * h_p))
    for a in range(0, cfg.n_frames, per_batch):
        b = min(cfg.n_frames, a + per_batch)
        rad = preview.render_batch(path.positions[a:b], path.rotations[a:b], path.light_offset_cam)
        stats[a:b] = [preview.luminance_stats(im) for im in rad.rgb]
    lighting = plan_lighting(cfg, stream(seed, "lighting"), stats[:, 0], stats[:, 1])
    return Scene(cfg, int(seed), tube, tex, intr, path, shader, lighting)


def render_frame(scene: Scene, i: int) -> SynthFrame:
    """Frame ``i`` of a planned scene (independent of other frames, so any order gives the same bytes)."""
    cfg = scene.cfg
    rad = scene.shader.render(scene.path.positions[i], scene.path.rotations[i], scene.path.light_offset_cam)
    noise = stream(scene.seed, "noise", i).standard_normal((cfg.height, cfg.width, 3), dtype=np.float32)
    y = sensor(cfg, rad.rgb, scene.lighting.clean_exposure, noise, scene.shader.field)
    clean = to_uint8(response(y, cfg.response_shoulder))
    disturbed = scene.lighting.disturbed(i)
    image = clean.copy() if not disturbed else to_uint8(scene.lighting.apply(i, y, cfg.response_shoulder))
    return SynthFrame(
        index=i,
        time_s=i / cfg.fps,
        image=image,
        clean=clean,
        depth=(rad.depth_mm / 1000.0).astype(np.float32),
        pose=scene.pose(i),
        lighting=scene.lighting.frame(i),
        occluder=bool(scene.path.occluder[i] > 0.5),
    )


def generate_clip(cfg: SynthConfig, seed: int) -> Iterator[SynthFrame]:
    """Frames of the clip for ``(cfg, seed)``, in order, one at a time."""
    scene = build_scene(cfg, seed)
    for i in range(cfg.n_frames):
        yield render_frame(scene, i)
