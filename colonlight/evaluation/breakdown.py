"""Why the input fails where the clean frames track, and which methods rescue those frames.

A *failure* here is a frame j (the pair keyframe k -> frame j, k the keyframe the input's track used) that the
tracker fails on the input and passes on the clean frames, in one brightness setting: lighting, not motion, lost
it. Each is classified from the synthetic clip's recorded lighting ground truth (``lighting.json``) and the
frames, by what changed between k and j:

* ``close occluder``: the tip is at the wall in k or j (the generator's close-occluder moment);
* ``saturation``: at least 5 % more of the input's pixels are saturated (grey >= 250) than of the clean
  frames' (in k or j): information is gone, no tone curve brings it back;
* ``gain jump``: the display gain changed by more than 10 % (abrupt jumps, and gain flicker);
* ``exposure lag``: the auto-exposure's contribution ``exposure ** (contrast / camera_gamma)`` changed by
  more than 10 %;
* ``tone-curve change``: the power-curve exponent (contrast) changed by more than 5 %;
* ``after a failure``: none of these, but the input's previous frame failed too: a visual-odometry track that
  has just gone wrong starts from a wrong motion prediction (and keyframe), so failures cascade;
* ``other``: none of these (small changes together, noise).

``causes`` lists every one that applies; ``cause`` is the first of occluder and saturation that applies, else
the lighting change largest relative to its threshold, so counts per cause add up to the failures. A method
*rescues* a failure when its own track passes frame j in the same setting.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np

CAUSES = (
    "close occluder", "saturation", "gain jump", "exposure lag", "tone-curve change", "after a failure", "other",
)  # fmt: skip
GAIN_CHANGE = math.log(1.10)
EXPOSURE_CHANGE = math.log(1.10)
CONTRAST_CHANGE = math.log(1.05)
SATURATION_LEVEL = 250.0  # the tracker's own saturation level (TrackerSettings.saturation)
SATURATED_EXCESS = 0.05
DEFAULT_CAMERA_GAMMA = 2.2


def saturated_fraction(frame: np.ndarray) -> float:
    """Fraction of pixels whose grey value (the tracker's ``COLOR_RGB2GRAY``) is at least 250."""
    f = frame.astype(np.float32)
    grey = cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) if f.ndim == 3 else f
    return float(np.mean(grey >= SATURATION_LEVEL))


def _log_ratio(a: Any, b: Any) -> float:
    try:
        return abs(math.log(float(a) / float(b)))
    except (TypeError, ValueError, ZeroDivisionError):
        return 0.0


def classify(
    light_k: Mapping[str, Any],
    light_j: Mapping[str, Any],
    saturated_excess: float,
    camera_gamma: float | None = None,
    after_failure: bool = False,
) -> dict[str, Any]:
    """``cause``, ``causes`` and the measured ``changes`` between keyframe k and frame j (see the module)."""
    cg = float(camera_gamma or DEFAULT_CAMERA_GAMMA)
    exp_k = float(light_k.get("exposure", 1.0)) ** (float(light_k.get("contrast", 1.0)) / cg)
    exp_j = float(light_j.get("exposure", 1.0)) ** (float(light_j.get("contrast", 1.0)) / cg)
    changes = {
        "gain_ratio": float(light_j.get("gain", 1.0)) / float(light_k.get("gain", 1.0) or 1.0),
        "exposure_ratio": exp_j / exp_k if exp_k else 1.0,
        "contrast_ratio": float(light_j.get("contrast", 1.0)) / float(light_k.get("contrast", 1.0) or 1.0),
        "saturated_excess": saturated_excess,
    }
    scores = {
        "gain jump": _log_ratio(light_j.get("gain", 1.0), light_k.get("gain", 1.0)) / GAIN_CHANGE,
        "exposure lag": _log_ratio(exp_j, exp_k) / EXPOSURE_CHANGE,
        "tone-curve change": _log_ratio(light_j.get("contrast", 1.0), light_k.get("contrast", 1.0)) / CONTRAST_CHANGE,
    }
    causes = []
    if light_k.get("close_occluder") or light_j.get("close_occluder"):
        causes.append("close occluder")
    if saturated_excess >= SATURATED_EXCESS:
        causes.append("saturation")
    lighting = sorted((c for c, v in scores.items() if v >= 1.0), key=lambda c: -scores[c])
    causes += lighting
    if after_failure and not causes:
        causes.append("after a failure")
    return {"cause": causes[0] if causes else "other", "causes": causes or ["other"], "changes": changes}


def clip_failures(
    frames: Sequence[np.ndarray],
    clean: Sequence[np.ndarray],
    lighting: Sequence[Mapping[str, Any]] | None,
    tracks: Mapping[str, Mapping[str, Mapping[str, Any]]],
    input_label: str,
    clean_label: str,
    camera_gamma: float | None = None,
) -> list[dict[str, Any]]:
    """Every frame the input fails and the clean frames pass, per brightness setting, classified, with the
    labels of the methods that pass it (``rescued_by``).

    ``tracks``: label -> brightness setting -> the runner's tracking dict (``frame_ok``, ``keyframe_of``)."""
    out: list[dict[str, Any]] = []
    inp, ref = tracks.get(input_label) or {}, tracks.get(clean_label) or {}
    saturation: dict[int, float] = {}

    def excess(i: int) -> float:
        if i not in saturation:
            saturation[i] = saturated_fraction(frames[i]) - saturated_fraction(clean[i])
        return saturation[i]

    for mode, t_in in inp.items():
        t_ref = ref.get(mode) or {}
        ok_in, ok_ref = t_in.get("frame_ok"), t_ref.get("frame_ok")
        if not ok_in or not ok_ref:
            continue
        for j in range(1, min(len(ok_in), len(ok_ref))):
            if ok_in[j] or not ok_ref[j]:
                continue
            k = int(t_in["keyframe_of"][j])
            light_k = lighting[k] if lighting else {}
            light_j = lighting[j] if lighting else {}
            info = classify(light_k, light_j, max(excess(k), excess(j)), camera_gamma, not ok_in[j - 1])
            rescued = [
                label
                for label, by_mode in tracks.items()
                if label not in (input_label, clean_label)
                and (by_mode.get(mode) or {}).get("frame_ok")
                and j < len(by_mode[mode]["frame_ok"])
                and by_mode[mode]["frame_ok"][j]
            ]
            out.append({"brightness": mode, "frame": j, "keyframe": k, **info, "rescued_by": rescued})
    return out


def summarize_failures(
    per_clip: Sequence[Sequence[Mapping[str, Any]]], labels: Sequence[str], modes: Sequence[str]
) -> dict[str, Any]:
    """Per brightness setting: failures, counts per cause, and each method's rescues (count, rate, per cause)."""
    out: dict[str, Any] = {}
    for mode in modes:
        items = [f for clip in per_clip for f in clip if f["brightness"] == mode]
        causes = {c: sum(1 for f in items if f["cause"] == c) for c in CAUSES}
        rescue: dict[str, Any] = {}
        for label in labels:
            hit = [f for f in items if label in f["rescued_by"]]
            by_cause = {c: (sum(1 for f in hit if f["cause"] == c) / causes[c]) if causes[c] else None for c in CAUSES}
            rescue[label] = {
                "rescued": len(hit),
                "rate": len(hit) / len(items) if items else None,
                "by_cause": by_cause,
            }
        out[mode] = {"failures": len(items), "causes": causes, "rescue": rescue}
    return out


__all__ = ["CAUSES", "classify", "clip_failures", "saturated_fraction", "summarize_failures"]
