"""Lighting disturbances and their per-frame ground truth.

Model (display domain, ``y`` = the clean frame before 8-bit clipping, see ``render.sensor``)::

    image_t = clip( gain_t * f(exposure_t ** (1 / camera_gamma) * y) ** contrast_t )   (f: the response's shoulder)
            = clip( display_gain_t * y ** contrast_t ),
    display_gain_t = gain_t * exposure_t ** (contrast_t / camera_gamma)
    clean_t = clip( y )

* ``exposure_t`` (relative to the clip's fixed clean exposure, linear light): a lagging auto-exposure. Its
  target is ``(M / m_{t-delay}) ** ae_strength`` with ``m`` the frame's mean linear luminance at the clean
  exposure and ``M`` the clip's geometric mean of ``m``; log exposure follows the target through a damped
  second-order filter (speed ``ae_speed``, damping ``ae_damping``: under-damped ones overshoot), so it trails
  scene changes and over/undershoots (e.g. when a close occluder appears or leaves).
* ``gain_t``: abrupt jumps by a factor in 0.4..0.8 or 1.25..2.5, held for a while, then recovering abruptly or
  exponentially. Overlapping jumps multiply, clipped to 0.4..2.5.
* ``contrast_t``: power-curve changes to an exponent in 0.6..1.6 (away from 1), with abrupt or ramped onset
  and recovery.
* frame-to-frame flicker on both (exposure control hunting, light-source ripple): log gain and log contrast
  get AR(1) noise of standard deviation ``flicker_gain`` / ``flicker_contrast`` and lag-1 correlation
  ``flicker_corr``. The contrast part changes the tone curve, which no affine brightness model absorbs.

The clean frames use the fixed clean exposure (chosen per clip from all frames so they are well exposed on
average) and gain = contrast = 1. ``steady`` clips have no disturbance (image == clean); ``undisturbed_seeds``
keeps frames 0 and 1 undisturbed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .config import SynthConfig
from .render import response

GAIN_RANGE = (0.4, 2.5)
CONTRAST_RANGE = (0.6, 1.6)
EXPOSURE_RANGE = (1 / 6, 6.0)


@dataclass
class LightingSchedule:
    """Per-frame disturbance parameters and the events that produced them."""

    camera_gamma: float
    clean_exposure: float
    gain: np.ndarray
    contrast: np.ndarray
    exposure: np.ndarray
    events: list[dict[str, Any]] = field(default_factory=list)

    def display_gain(self, i: int) -> float:
        return float(self.gain[i] * self.exposure[i] ** (self.contrast[i] / self.camera_gamma))

    def disturbed(self, i: int) -> bool:
        return bool(
            abs(np.log(self.gain[i])) > 1e-3
            or abs(np.log(self.contrast[i])) > 1e-3
            or abs(np.log(self.exposure[i])) > 1e-3
        )

    def frame(self, i: int) -> dict[str, Any]:
        """Ground truth of frame ``i`` (the ``SynthFrame.lighting`` dict)."""
        return {
            "gain": float(self.gain[i]),
            "contrast": float(self.contrast[i]),
            "exposure": float(self.exposure[i]),
            "display_gain": self.display_gain(i),
            "disturbed": self.disturbed(i),
        }

    def apply(self, i: int, y: np.ndarray, shoulder: float = 0.0) -> np.ndarray:
        """The disturbed display-domain frame (unclipped) from the clean power-law output ``y`` (before the
        response's shoulder): exposure acts on linear light, so it goes in before the shoulder; gain and the
        contrast power curve act on the display signal after it."""
        k = np.float32(self.contrast[i])
        if shoulder == 0:
            g = np.float32(self.display_gain(i))
            return y * g if k == 1 else g * np.power(y, k)
        exposed = response(y * np.float32(self.exposure[i] ** (1.0 / self.camera_gamma)), shoulder)
        g = np.float32(self.gain[i])
        return exposed * g if k == 1 else g * np.power(exposed, k)


def plan_lighting(
    cfg: SynthConfig, rng: np.random.Generator, mean_lum: np.ndarray, p95_lum: np.ndarray
) -> LightingSchedule:
    """Schedule for a clip whose frames have the given unit-exposure luminance statistics."""
    n = cfg.n_frames
    mean_lum = np.maximum(mean_lum, 1e-9)
    p95_lum = np.maximum(p95_lum, 1e-9)
    clean_exposure = cfg.exposure_level / float(np.exp(np.mean(np.log(p95_lum))))
    gain = np.ones(n)
    contrast = np.ones(n)
    exposure = np.ones(n)
    events: list[dict[str, Any]] = []
    # draw everything even when steady so the stream does not depend on flags
    first = 2 if cfg.undisturbed_seeds else 0
    log_g, ev_g = _gain_events(cfg, rng, n, first)
    log_k, ev_k = _contrast_events(cfg, rng, n, first)
    log_e = _auto_exposure(cfg, mean_lum, first)
    fl_g, fl_k = _flicker(cfg, rng, n, first)
    flickers = cfg.flicker_gain != 0 or cfg.flicker_contrast != 0  # the AR(1) noise is applied
    if not cfg.steady and n > first:
        if not ev_g and not ev_k and cfg.ae_strength == 0 and not flickers:
            # a disturbed clip should disturb something: force one gain jump
            log_g, ev_g = _gain_events(cfg, rng, n, first, at_least_one=True)
        gain = np.exp(np.clip(log_g + fl_g, *np.log(GAIN_RANGE)))
        contrast = np.exp(np.clip(log_k + fl_k, *np.log(CONTRAST_RANGE)))
        exposure = np.exp(np.clip(log_e, *np.log(EXPOSURE_RANGE)))
        events = ev_g + ev_k
        if flickers:
            events.append(
                {
                    "type": "flicker",
                    "gain_std": cfg.flicker_gain,
                    "contrast_std": cfg.flicker_contrast,
                    "corr": cfg.flicker_corr,
                }
            )
        if cfg.ae_strength > 0:
            events.append(
                {
                    "type": "auto_exposure",
                    "strength": cfg.ae_strength,
                    "speed": cfg.ae_speed,
                    "damping": cfg.ae_damping,
                    "delay": cfg.ae_delay,
                }
            )
    return LightingSchedule(cfg.camera_gamma, clean_exposure, gain, contrast, exposure, events)


def _flicker(cfg: SynthConfig, rng: np.random.Generator, n: int, first: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame log gain and log contrast noise: stationary AR(1), zero on the undisturbed seed frames."""
    white = rng.standard_normal((2, n))
    rho = float(np.clip(cfg.flicker_corr, 0.0, 0.95))
    ar = np.empty_like(white)
    ar[:, 0] = white[:, 0]
    for t in range(1, n):
        ar[:, t] = rho * ar[:, t - 1] + np.sqrt(1 - rho * rho) * white[:, t]
    ar[:, :first] = 0.0
    return cfg.flicker_gain * ar[0], cfg.flicker_contrast * ar[1]


def _auto_exposure(cfg: SynthConfig, mean_lum: np.ndarray, first: int) -> np.ndarray:
    """Log relative exposure from a lagging, possibly overshooting controller."""
    n = len(mean_lum)
    log_m = np.log(mean_lum)
    target = cfg.ae_strength * (np.mean(log_m) - log_m)  # log of the exposure that would compensate
    out = np.zeros(n)
    if cfg.ae_strength == 0:
        return out
    w0 = cfg.ae_speed
    # the per-frame (semi-implicit Euler) update is unstable once 2 * damping * speed > 1 (fast, heavily damped
    # controllers ring from frame to frame and diverge); cap the damping term there: no controller settles in
    # less than a frame anyway
    damp = min(2 * cfg.ae_damping * w0, 1.0)
    x = 0.0 if first > 0 else float(target[0])  # converged at the start unless the seeds must be clean
    v = 0.0
    for t in range(first, n):
        tgt = target[max(0, t - cfg.ae_delay)]
        acc = w0 * w0 * (tgt - x) - damp * v
        v += acc
        x += v
        out[t] = x
    return out


def _hold_profile(n: int, start: int, onset: int, hold: int, recover_rate: float | None, ramp_out: int) -> np.ndarray:
    """A 0..1 profile: ramp up over ``onset`` frames, hold, then decay exponentially or ramp down."""
    prof = np.zeros(n)
    t = np.arange(n) - start
    if onset > 0:
        prof = np.where((t >= 0) & (t < onset), (t + 1) / (onset + 1), prof)
    else:
        onset = 0
    end = onset + hold
    prof = np.where((t >= onset) & (t < end), 1.0, prof)
    after = t - end
    if recover_rate is not None:
        prof = np.where(after >= 0, (1 - recover_rate) ** (after + 1), prof)
    elif ramp_out > 0:
        prof = np.where((after >= 0) & (after < ramp_out), 1 - (after + 1) / (ramp_out + 1), prof)
    return prof


def _gain_events(
    cfg: SynthConfig, rng: np.random.Generator, n: int, first: int, at_least_one: bool = False
) -> tuple[np.ndarray, list[dict[str, Any]]]:
    k = int(rng.poisson(cfg.gain_rate_hz * n / cfg.fps))
    if at_least_one:
        k = max(k, 1)
    log_g = np.zeros(n)
    events = []
    for _ in range(k):
        start = int(rng.integers(first, max(first + 1, n)))
        mag = float(rng.uniform(np.log(1.25), np.log(2.5)))
        factor = float(np.exp(mag if rng.random() < 0.5 else -mag))
        factor = max(factor, GAIN_RANGE[0])
        hold = max(1, int(round(cfg.gain_hold_s * cfg.fps * rng.uniform(0.5, 1.5))))
        rate = float(rng.uniform(0.2, 0.7)) if rng.random() < 0.5 else None
        log_g += np.log(factor) * _hold_profile(n, start, 0, hold, rate, 0)
        events.append(
            {
                "type": "gain_jump",
                "start": start,
                "factor": factor,
                "hold": hold,
                "recovery": "abrupt" if rate is None else f"exponential {rate:.3f}/frame",
            }
        )
    return log_g, events


def _contrast_events(
    cfg: SynthConfig, rng: np.random.Generator, n: int, first: int
) -> tuple[np.ndarray, list[dict[str, Any]]]:
    k = int(rng.poisson(cfg.contrast_rate_hz * n / cfg.fps))
    log_k = np.zeros(n)
    events = []
    for _ in range(k):
        start = int(rng.integers(first, max(first + 1, n)))
        up = rng.random() < 0.5
        lo, hi = (np.log(1.12), np.log(CONTRAST_RANGE[1])) if up else (np.log(1.12), -np.log(CONTRAST_RANGE[0]))
        expo = float(np.exp(rng.uniform(lo, hi) * (1 if up else -1)))
        onset = int(rng.integers(0, 5))
        hold = max(1, int(round(cfg.contrast_hold_s * cfg.fps * rng.uniform(0.5, 1.5))))
        ramp_out = int(rng.integers(0, 6))
        log_k += np.log(expo) * _hold_profile(n, start, onset, hold, None, ramp_out)
        events.append(
            {
                "type": "contrast",
                "start": start,
                "exponent": expo,
                "onset": onset,
                "hold": hold,
                "ramp_out": ramp_out,
            }
        )
    return log_k, events
