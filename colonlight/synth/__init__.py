"""Synthetic colonoscopy clips with ground truth, for training and evaluating lighting correction.

A physically motivated generator (no real video needed): a bending tube with haustral folds and a rounded
triangular section (``geometry``), a painted mucosa with vessels (``texture``), a scope tip moving through it
with a point light at the tip (``camera``, ``render``: inverse-square falloff, wrap diffuse, wet specular
glints, vignetting, sensor noise, 8-bit clipping), and recorded lighting disturbances (``disturb``: lagging
auto-exposure, gain jumps, contrast power curves) beside clean frames at a fixed exposure. Same config + seed
=> same bytes.

    from colonlight.synth import SynthConfig, generate_clip, write_clip, make_dataset
    cfg = SynthConfig.sample(np.random.default_rng(3), split="train", width=256, height=256)
    for f in generate_clip(cfg, seed=3):
        f.image, f.clean, f.depth, f.pose, f.lighting
"""

from __future__ import annotations

from ..discovery import SYNTH_FRAMES, SYNTH_VIDEO
from .clip import SynthFrame, build_scene, generate_clip, render_frame
from .config import PARAM_SPECS, SPLITS, Split, SynthConfig, parse_split
from .overlay import BORDERS, OverlaySpec
from .writer import GENERATOR_VERSION, clip_complete, decode_depth, encode_depth, make_dataset, write_clip

__all__ = [
    "BORDERS",
    "GENERATOR_VERSION",
    "OverlaySpec",
    "PARAM_SPECS",
    "SPLITS",
    "SYNTH_FRAMES",
    "SYNTH_VIDEO",
    "Split",
    "SynthConfig",
    "SynthFrame",
    "build_scene",
    "clip_complete",
    "decode_depth",
    "encode_depth",
    "generate_clip",
    "make_dataset",
    "parse_split",
    "render_frame",
    "write_clip",
]
