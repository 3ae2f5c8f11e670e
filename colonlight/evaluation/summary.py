"""The summary of an evaluation: one row per method (means over the clips it ran on), the tracking columns per
brightness setting, the gap to the oracle closed, and the breakdown of the input's failures.

It reads :mod:`.records` (imported for the annotations only: the records' JSON form includes this summary).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .breakdown import summarize_failures
from .colmap import APE_STATS
from .oracles import CLEAN_LABEL, CURVE_LABEL
from .tracker import BRIGHTNESS_MODES

if TYPE_CHECKING:
    from .records import EvaluationResult, MethodClipResult

#: The label of the unenhanced input (the ``none`` method), against which gaps are measured.
INPUT_NAME = "none"
#: The least lead of the oracle curve over the input (in success rate or tracked fraction) that a gap-closed
#: fraction is computed for: below it (1 frame pair in 700, as brightness fitted often gives) the ratio of two
#: tiny differences read -1300% or +500% and meant nothing.
MIN_GAP = 0.01


def nanmean(values: Iterable[float | None]) -> float:
    """The mean of the finite values (None and NaN left out); NaN when there are none."""
    v = np.array([x for x in values if x is not None], dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def nanmedian(values: Iterable[float | None]) -> float | None:
    """The median of the finite values (None and NaN left out); None when there are none."""
    v = np.array([x for x in values if x is not None], dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else None


def summarize(result: EvaluationResult) -> list[dict[str, Any]]:
    """One row per evaluated method: means over the clips it ran on (see the report for definitions).

    Tracking, per brightness setting ``m`` (``fixed``, ``affine``; fields of a setting not run are None): a clip
    counts when tracking applied (known depth); ``track_success_m`` clips tracked with no failing frame,
    ``track_success_rate_m`` that over ``tracked``; ``tracked_fraction_m`` the mean over clips of the fraction
    of frames 1.. within the thresholds; pose errors are the median over tracked clips of each clip's median
    frame error (robust to diverged tracks), and the mean over clips of each clip's mean error over the frames
    before its first failure. ``gap_closed_success_m`` / ``gap_closed_tracked_m``: the fraction of the input ->
    oracle-curve gap closed, (method - input) / (oracle-curve - input) over the clips all three ran on (None
    without an input row or an oracle-curve row, or where the oracle curve leads the input by less than
    ``MIN_GAP``). ``psnr_in`` / ``psnr_out``: PSNR to the clean frames, both over the same clips, those whose
    input differs from them. ``rescued_m`` / ``rescue_rate_m``: of the frames the
    input fails and the clean frames pass, those this method passes. COLMAP: ``registered`` is the mean over
    clips of the fraction of frames registered; ATE statistics are means over the clips where an ATE exists
    (at least 3 registered frames), in metres.
    """
    modes = tuple(result.settings.get("brightness") or BRIGHTNESS_MODES)
    breakdown = failure_breakdown(result)
    rows = []
    for label in result.labels:
        rs = [c.results[label] for c in result.clips if label in c.results and not c.results[label].error]
        frames = sum(r.frames for r in rs)
        cms = [r.colmap for r in rs if r.colmap is not None]
        ates = [c["ate"] for c in cms if c.get("ate")]
        row: dict[str, Any] = {
            "method": label,
            "clips": len(rs),
            "frames": frames,
            "ms_per_frame": sum(r.ms_per_frame * r.frames for r in rs) / frames if frames else float("nan"),
            "cpu_ms_per_frame": sum(r.cpu_ms_per_frame * r.frames for r in rs) / frames if frames else float("nan"),
            "flicker_in": nanmean(r.flicker_in for r in rs),
            "flicker_out": nanmean(r.flicker_out for r in rs),
            "flicker_reduction": nanmean(r.flicker_reduction for r in rs),
            "ssim_in": nanmean(r.ssim_in for r in rs),
            "ssim_out": nanmean(r.ssim_out for r in rs),
            "dark_in": nanmean(r.dark_in for r in rs),
            "dark_out": nanmean(r.dark_out for r in rs),
            "bright_in": nanmean(r.bright_in for r in rs),
            "bright_out": nanmean(r.bright_out for r in rs),
            **_restoration(rs),
            "tracked": max((len(_tracks(rs, m)) for m in modes), default=0),
        }
        for m in BRIGHTNESS_MODES:
            row.update(_tracking_fields(result, label, rs, m, breakdown.get(m) if m in modes else None, m in modes))
        row.update(
            colmap_clips=len(cms),
            registered=nanmean(c["fraction"] for c in cms) if cms else None,
            ate_clips=len(ates),
        )
        for k in APE_STATS:
            row[f"ate_{k}_m"] = nanmean(a[k] for a in ates) if ates else None
        rows.append(row)
    return rows


def _restoration(rs: Sequence[MethodClipResult]) -> dict[str, float]:
    """``psnr_in`` and ``psnr_out``, both means over the clips whose input differs from the clean frames.

    A clip whose input is its clean frames (steady lighting) has an infinite input PSNR and no restoration to
    measure (what a method does to it is the steady clips' darkening). Averaging each column over its own finite
    values compared the input on the disturbed clips with the output on all of them: a method that changed a
    steady clip slightly was credited with that clip's high PSNR (FFmpeg's deflicker, which restores nothing,
    read 25.3 dB on a second renderer's clips, where it gives 19.7 dB on the disturbed ones against the input's
    19.2)."""
    disturbed = [r for r in rs if r.psnr_in is not None and np.isfinite(r.psnr_in)]
    return {
        "psnr_in": nanmean(r.psnr_in for r in disturbed),
        "psnr_out": nanmean(r.psnr_out for r in disturbed),
    }


def _tracks(rs: Sequence[MethodClipResult], mode: str) -> list[dict[str, Any]]:
    return [t for r in rs if r.tracking and (t := r.tracking.get(mode)) and t.get("applicable")]


def _tracking_fields(
    result: EvaluationResult,
    label: str,
    rs: Sequence[MethodClipResult],
    mode: str,
    breakdown: dict[str, Any] | None,
    ran: bool,
) -> dict[str, Any]:
    """The tracking columns of one method in one brightness setting (all None when it was not run)."""
    tracked = _tracks(rs, mode) if ran else []
    n_ok = sum(1 for t in tracked if t["success"])
    rescue = (breakdown or {}).get("rescue", {}).get(label) or {}
    return {
        f"track_success_{mode}": n_ok if ran else None,
        f"track_success_rate_{mode}": n_ok / len(tracked) if tracked else None,
        f"tracked_fraction_{mode}": nanmean(t.get("tracked_fraction") for t in tracked) if tracked else None,
        f"gap_closed_success_{mode}": _gap_closed(result, label, mode, "success") if ran else None,
        f"gap_closed_tracked_{mode}": _gap_closed(result, label, mode, "tracked_fraction") if ran else None,
        f"rescued_{mode}": rescue.get("rescued"),
        f"rescue_rate_{mode}": rescue.get("rate"),
        f"track_te_{mode}_m": nanmedian(t.get("translation_error_m_median") for t in tracked),
        f"track_re_{mode}_deg": nanmedian(t.get("rotation_error_deg_median") for t in tracked),
        f"track_te_mean_tracked_{mode}_m": nanmean(t.get("translation_error_m_mean_tracked") for t in tracked)
        if tracked
        else None,
        f"track_re_mean_tracked_{mode}_deg": nanmean(t.get("rotation_error_deg_mean_tracked") for t in tracked)
        if tracked
        else None,
    }


def input_label(result: EvaluationResult) -> str | None:
    """The label of the unenhanced input's row (the ``none`` method), if it was evaluated."""
    return next((m["label"] for m in result.methods if m["name"] == INPUT_NAME), None)


def _gap_closed(result: EvaluationResult, label: str, mode: str, key: str) -> float | None:
    """(method - input) / (oracle-curve - input) of the clip mean of ``key`` over the clips all three tracked."""
    base = input_label(result)
    if base is None or CURVE_LABEL not in result.labels:
        return None
    values: dict[str, list[float]] = {label: [], base: [], CURVE_LABEL: []}
    for c in result.clips:
        got = {}
        for lab in values:
            r = c.results.get(lab)
            t = (r.tracking or {}).get(mode) if r is not None and not r.error else None
            if not t or not t.get("applicable"):
                break
            got[lab] = float(t[key])
        else:
            for lab, v in got.items():
                values[lab].append(v)
    if not values[base]:
        return None
    x, x_in, x_top = (float(np.mean(values[lab])) for lab in (label, base, CURVE_LABEL))
    gap = x_top - x_in
    return (x - x_in) / gap if gap >= MIN_GAP else None


def failure_breakdown(result: EvaluationResult) -> dict[str, Any]:
    """Per brightness setting, the frames the input fails and the clean frames pass: counts per cause and each
    method's rescues (see :mod:`.breakdown`); empty without clips that have clean frames and an input row."""
    per_clip = [c.input_failures for c in result.clips]
    if not any(c.input_failures for c in result.clips) and not any(CLEAN_LABEL in c.results for c in result.clips):
        return {}
    base = input_label(result)
    labels = [lab for lab in result.labels if lab not in (base, CLEAN_LABEL)]
    modes = tuple(result.settings.get("brightness") or BRIGHTNESS_MODES)
    return summarize_failures(per_clip, labels, modes)
