"""The generator's settings, and how they are drawn from disjoint "train" / "heldout" families.

Every physical knob is a field of :class:`SynthConfig` (so a clip is reproducible from ``synth.json``). The
trained model will be judged on real-looking clips this generator never made, so :meth:`SynthConfig.sample`
draws every knob widely; ``split="heldout"`` pushes a random subset (at least two) of the knobs listed in
``PARAM_SPECS`` with held-out intervals into ranges that ``split="train"`` never produces, so evaluation clips
use unseen settings. Units: millimetres for lengths, degrees for angles, seconds / hertz for time.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np

from ..limits import DEFAULT_FPS

Split = Literal["train", "heldout"]
#: The generator's two families, in the order help texts list them.
SPLITS: tuple[Split, ...] = get_args(Split)
OccluderMode = Literal["random", "force", "forbid"]


def parse_split(text: str) -> Split:
    """``text`` as one of ``SPLITS``; ValueError names the choices otherwise."""
    for split in SPLITS:
        if text == split:
            return split
    raise ValueError(f"split must be {' or '.join(repr(s) for s in SPLITS)}, got {text!r}")


@dataclass(frozen=True)
class ParamSpec:
    """Train interval, held-out intervals (never overlapping train) and whether to draw on a log scale."""

    train: tuple[float, float]
    heldout: tuple[tuple[float, float], ...] = ()
    log: bool = False


# name -> spec. Held-out intervals sit outside the train interval, on either side.
PARAM_SPECS: dict[str, ParamSpec] = {
    # geometry
    "radius_mm": ParamSpec((13.0, 24.0), ((24.0, 32.0), (10.0, 13.0)), log=True),
    "radius_var": ParamSpec((0.0, 0.15), ((0.15, 0.25),)),
    "triangularity": ParamSpec((0.0, 0.14), ((0.14, 0.2),)),
    "ellipticity": ParamSpec((0.0, 0.12), ((0.12, 0.2),)),
    "twist_deg_per_100mm": ParamSpec((-40.0, 40.0), ((40.0, 60.0), (-60.0, -40.0))),
    "fold_spacing_mm": ParamSpec((16.0, 36.0), ((36.0, 50.0), (11.0, 16.0)), log=True),
    "fold_spacing_jitter": ParamSpec((0.0, 0.35), ((0.35, 0.5),)),
    "fold_depth": ParamSpec((0.12, 0.45), ((0.45, 0.6), (0.05, 0.12))),
    "fold_depth_var": ParamSpec((0.0, 0.5), ((0.5, 0.7),)),
    "fold_width_mm": ParamSpec((1.5, 4.5), ((4.5, 7.0),), log=True),
    "fold_sharpness": ParamSpec((1.4, 2.6), ((1.0, 1.4), (2.6, 3.5))),
    "fold_taenia": ParamSpec((0.0, 0.8), ((0.8, 1.0),)),
    "fold_asym": ParamSpec((0.0, 0.5), ((0.5, 0.7),)),
    "fold_tilt": ParamSpec((0.0, 0.25), ((0.25, 0.35),)),
    "fold_gap_prob": ParamSpec((0.0, 0.2), ((0.2, 0.3),)),
    "bend_amp_mm": ParamSpec((0.0, 30.0), ((30.0, 45.0),)),
    "bend_wavelength_mm": ParamSpec((150.0, 500.0), ((500.0, 700.0), (100.0, 150.0)), log=True),
    # texture
    "hue_deg": ParamSpec((-8.0, 12.0), ((-18.0, -8.0), (12.0, 22.0))),
    "saturation": ParamSpec((0.45, 0.78), ((0.3, 0.45), (0.78, 0.9))),
    "albedo": ParamSpec((0.62, 0.88), ((0.5, 0.62), (0.88, 0.97))),
    "mottle": ParamSpec((0.03, 0.2), ((0.2, 0.3), (0.01, 0.03))),
    "vessel_density": ParamSpec((0.15, 1.5), ((1.5, 3.0),), log=True),
    "vessel_contrast": ParamSpec((0.2, 0.8), ((0.8, 0.95), (0.1, 0.2))),
    "vessel_width_mm": ParamSpec((0.15, 0.6), ((0.6, 0.9),), log=True),
    "bump": ParamSpec((0.1, 1.0), ((1.0, 1.5), (0.03, 0.1))),
    "debris": ParamSpec((0.0, 0.8), ((0.8, 1.0),)),
    # reflectance and light
    "spec_strength": ParamSpec((0.15, 1.2), ((1.2, 2.0), (0.05, 0.15)), log=True),
    "spec_shininess": ParamSpec((60.0, 500.0), ((500.0, 1200.0), (30.0, 60.0)), log=True),
    "spec_broad": ParamSpec((0.0, 0.15), ((0.15, 0.25),)),
    "light_falloff": ParamSpec((1.8, 2.2), ((1.6, 1.8), (2.2, 2.4))),
    "light_spot": ParamSpec((0.0, 2.5), ((2.5, 4.0),)),
    "light_offset_mm": ParamSpec((0.0, 4.0), ((4.0, 6.0),)),
    "wrap": ParamSpec((0.0, 0.5), ((0.5, 0.7),)),
    # camera and sensor
    "fov_deg": ParamSpec((75.0, 115.0), ((115.0, 135.0), (60.0, 75.0))),
    "vignetting": ParamSpec((0.0, 0.6), ((0.6, 0.9),)),
    "read_noise": ParamSpec((0.001, 0.012), ((0.012, 0.025),), log=True),
    "shot_noise": ParamSpec((0.0005, 0.01), ((0.01, 0.02),), log=True),
    "blur_px": ParamSpec((0.0, 0.9), ((0.9, 1.4),)),
    "camera_gamma": ParamSpec((1.9, 2.5), ((1.6, 1.9), (2.5, 2.8))),
    "wb_r": ParamSpec((0.9, 1.1), ((0.8, 0.9), (1.1, 1.2))),
    "wb_g": ParamSpec((0.9, 1.1), ((0.8, 0.9), (1.1, 1.2))),
    "wb_b": ParamSpec((0.9, 1.1), ((0.8, 0.9), (1.1, 1.2))),
    "exposure_level": ParamSpec((0.5, 0.85), ((0.4, 0.5), (0.85, 0.95))),
    # motion
    # withdrawal during inspection is slow (guidelines ask for >= 6 min over ~1.5 m: ~4 mm/s), insertion and
    # repositioning faster; held out: faster pulls and near-pauses
    "speed_mm_s": ParamSpec((1.5, 20.0), ((20.0, 35.0), (0.7, 1.5)), log=True),
    "speed_var": ParamSpec((0.0, 0.8), ((0.8, 1.0),)),
    "lateral": ParamSpec((0.0, 0.45), ((0.45, 0.6),)),
    "look_var_deg": ParamSpec((2.0, 20.0), ((20.0, 28.0),)),
    "jitter_deg": ParamSpec((0.1, 1.2), ((1.2, 2.5),), log=True),
    "roll_rate_deg_s": ParamSpec((-25.0, 25.0), ((25.0, 40.0), (-40.0, -25.0))),
    "roll_var_deg": ParamSpec((0.0, 25.0), ((25.0, 35.0),)),
    "motion_corr_s": ParamSpec((0.5, 2.5), ((2.5, 4.0), (0.3, 0.5)), log=True),
    # lighting disturbances
    "ae_strength": ParamSpec((0.4, 0.9), ((0.9, 1.1),)),
    "ae_speed": ParamSpec((0.15, 0.6), ((0.6, 0.9), (0.06, 0.15))),
    "ae_damping": ParamSpec((0.35, 1.2), ((1.2, 1.6), (0.2, 0.35))),
    "gain_rate_hz": ParamSpec((0.1, 0.8), ((0.8, 1.2),)),
    "gain_hold_s": ParamSpec((0.1, 1.5), ((1.5, 2.5), (0.05, 0.1)), log=True),
    "contrast_rate_hz": ParamSpec((0.1, 0.6), ((0.6, 0.9),)),
    "contrast_hold_s": ParamSpec((0.15, 2.0), ((2.0, 3.0), (0.08, 0.15)), log=True),
    # frame-to-frame flicker (exposure hunting, light-source ripple): std of per-frame log gain / log contrast
    "flicker_gain": ParamSpec((0.015, 0.12), ((0.12, 0.2),), log=True),
    "flicker_contrast": ParamSpec((0.01, 0.08), ((0.08, 0.12),), log=True),
    "flicker_corr": ParamSpec((0.0, 0.6), ((0.6, 0.8),)),
    # camera response: a highlight shoulder on top of the power law (0: a pure power law; render.response).
    # Last, so that adding it left the draws of every knob above unchanged.
    "response_shoulder": ParamSpec((0.0, 0.6), ((0.6, 1.2),)),
}

# Knobs that are switched off in a fraction of sampled clips (value forced to 0).
_OFF_PROB: dict[str, float] = {
    "debris": 0.6,
    "bend_amp_mm": 0.1,
    "ae_strength": 0.15,
    "gain_rate_hz": 0.15,
    "contrast_rate_hz": 0.2,
    "flicker_gain": 0.2,
    "flicker_contrast": 0.4,
    "fold_tilt": 0.2,
    "response_shoulder": 0.4,
}

#: Chance that a knob with held-out intervals is pushed out of the train range in a held-out clip (at least two
#: are); with every knob having held-out values, about a third of them are out in each held-out clip.
HELDOUT_PROB = 0.3


@dataclass
class SynthConfig:
    """All settings of one synthetic clip. Defaults are mid-range values; see ``PARAM_SPECS`` for the ranges.

    ``steady``: no lighting disturbance at all (``image == clean``).
    ``undisturbed_seeds``: frames 0 and 1 use the clean exposure (gain 1, contrast 1), as the model's seed
    frames.
    ``close_occluder``: "force" (at least one moment with the scope at the wall), "forbid", or "random".
    ``mask_radius``: 0 = full frame, else a circular field stop of that radius relative to half the diagonal.
    """

    width: int = 256
    height: int = 256
    n_frames: int = 100
    fps: float = DEFAULT_FPS
    steady: bool = False
    undisturbed_seeds: bool = False
    close_occluder: OccluderMode = "random"
    occluder_prob: float = 0.35
    split: str = "train"
    heldout_params: tuple[str, ...] = ()
    # geometry
    radius_mm: float = 18.0
    radius_var: float = 0.07
    triangularity: float = 0.08
    ellipticity: float = 0.05
    twist_deg_per_100mm: float = 0.0
    fold_spacing_mm: float = 24.0
    fold_spacing_jitter: float = 0.15
    fold_depth: float = 0.3
    fold_depth_var: float = 0.25
    fold_width_mm: float = 2.6
    fold_sharpness: float = 2.0
    fold_taenia: float = 0.45
    fold_asym: float = 0.25
    fold_tilt: float = 0.1
    fold_gap_prob: float = 0.1
    bend_amp_mm: float = 15.0
    bend_wavelength_mm: float = 280.0
    # texture
    hue_deg: float = 2.0
    saturation: float = 0.62
    albedo: float = 0.78
    mottle: float = 0.12
    vessel_density: float = 0.5
    vessel_contrast: float = 0.45
    vessel_width_mm: float = 0.3
    bump: float = 0.5
    debris: float = 0.0
    # reflectance and light
    spec_strength: float = 0.45
    spec_shininess: float = 160.0
    spec_broad: float = 0.07
    light_falloff: float = 2.0
    light_spot: float = 1.2
    light_offset_mm: float = 2.0
    wrap: float = 0.25
    # camera and sensor
    fov_deg: float = 95.0
    vignetting: float = 0.3
    read_noise: float = 0.004
    shot_noise: float = 0.002
    blur_px: float = 0.4
    camera_gamma: float = 2.2
    response_shoulder: float = 0.0
    wb_r: float = 1.0
    wb_g: float = 1.0
    wb_b: float = 1.0
    exposure_level: float = 0.7
    mask_radius: float = 0.0
    # motion
    speed_mm_s: float = 15.0
    speed_var: float = 0.4
    direction: int = -1
    lateral: float = 0.22
    look_var_deg: float = 10.0
    jitter_deg: float = 0.4
    roll_rate_deg_s: float = 0.0
    roll_var_deg: float = 12.0
    motion_corr_s: float = 1.2
    # lighting disturbances (ignored when steady)
    ae_strength: float = 0.7
    ae_speed: float = 0.35
    ae_damping: float = 0.7
    ae_delay: int = 1
    gain_rate_hz: float = 0.4
    gain_hold_s: float = 0.5
    contrast_rate_hz: float = 0.3
    contrast_hold_s: float = 0.6
    flicker_gain: float = 0.0
    flicker_contrast: float = 0.0
    flicker_corr: float = 0.3

    def __post_init__(self) -> None:
        if isinstance(self.close_occluder, bool):  # convenience: True -> force, False -> forbid
            self.close_occluder = "force" if self.close_occluder else "forbid"
        if self.close_occluder not in ("random", "force", "forbid"):
            raise ValueError(f"close_occluder must be 'random', 'force' or 'forbid', got {self.close_occluder!r}")
        if self.width < 16 or self.height < 16:
            raise ValueError(f"frame size must be at least 16x16, got {self.width}x{self.height}")
        if self.n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {self.n_frames}")
        if not self.fps > 0:
            raise ValueError(f"fps must be > 0, got {self.fps}")
        if self.direction not in (-1, 1):
            raise ValueError(f"direction must be +1 (insertion) or -1 (withdrawal), got {self.direction}")
        self.heldout_params = tuple(self.heldout_params)

    @classmethod
    def sample(cls, rng: np.random.Generator, split: Split = "train", **overrides: Any) -> SynthConfig:
        """Draw every physical knob from ``rng``; ``overrides`` (e.g. width=128, steady=True) are kept as
        given.

        ``split="heldout"``: each knob with held-out intervals goes out of the train range with probability
        ``HELDOUT_PROB``, and at least two do; their names are listed in ``heldout_params``.
        """
        split = parse_split(split)
        names = [n for n, s in PARAM_SPECS.items() if n not in overrides]
        out_names: set[str] = set()
        if split == "heldout":
            cand = [n for n in names if PARAM_SPECS[n].heldout]
            flags = rng.random(len(cand)) < HELDOUT_PROB
            if flags.sum() < 2 and len(cand) >= 2:
                flags[rng.choice(len(cand), size=2, replace=False)] = True
            out_names = {n for n, f in zip(cand, flags, strict=True) if f}
        values: dict[str, Any] = {}
        for name in names:
            spec = PARAM_SPECS[name]
            lo, hi = spec.train
            if name in out_names:
                widths = np.array([b - a for a, b in spec.heldout])
                lo, hi = spec.heldout[int(rng.choice(len(widths), p=widths / widths.sum()))]
            u = float(rng.random())
            if spec.log:
                values[name] = float(np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo))))
            else:
                values[name] = float(lo + u * (hi - lo))
            off = _OFF_PROB.get(name, 0.0)
            if off and name not in out_names and float(rng.random()) < off:
                values[name] = 0.0
        # discrete knobs (always drawn so the stream of draws does not depend on overrides' values)
        direction = -1 if rng.random() < 0.6 else 1
        ae_delay = int(rng.integers(1, 4))
        mask = float(rng.uniform(1.0, 1.35)) if rng.random() < 0.35 else 0.0
        if split == "heldout" and rng.random() < 0.3:  # a tighter field stop than training ever draws
            mask = float(rng.uniform(0.8, 1.0))
        values.setdefault("direction", direction)
        values.setdefault("ae_delay", ae_delay)
        values.setdefault("mask_radius", mask)
        values["split"] = split
        values["heldout_params"] = tuple(sorted(out_names))
        values.update(overrides)
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (tuples become lists)."""
        d = dataclasses.asdict(self)
        d["heldout_params"] = list(self.heldout_params)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SynthConfig:
        """Inverse of :meth:`to_dict`; unknown keys are rejected so stale files are noticed."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown SynthConfig fields: {sorted(unknown)}")
        return cls(**d)
