"""Write an evaluation: ``results.json`` (everything), ``table.md``, ``table.csv``, ``clips.csv``, ``report.html``.

The HTML report is one self-contained file (plots as inline base64 PNG drawn by matplotlib's Agg renderer, CSS
inline, no scripts, fonts or links to fetch), so it can be mailed or archived as is. Every file is written
atomically. The records say what made them: colonlight and library versions, each method's parameters and
model sha256, the clips, the settings and the command.
"""

from __future__ import annotations

import base64
import csv
import datetime as _dt
import html
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..atomic import json_bytes, publish, write_temporary
from ..frames import encode_image
from ..limits import DEFAULT_FPS
from ..provenance import distribution_versions, library_versions
from .breakdown import CAUSES
from .records import EvaluationResult
from .summary import MIN_GAP, failure_breakdown, summarize
from .tracker import BRIGHTNESS_MODES

RESULTS_FILE, TABLE_MD, TABLE_CSV, CLIPS_CSV, REPORT_HTML = (
    "results.json",
    "table.md",
    "table.csv",
    "clips.csv",
    "report.html",
)
_EXTRA_LIBS = ("pycolmap", "evo", "scikit-image", "kornia", "matplotlib", "scipy")

DEFINITIONS: list[tuple[str, str]] = [
    (
        "flicker",
        (
            "mean over consecutive frames of |change in mean luma|, over content pixels (not specular "
            "in the input: luma <= 0.7; not black border); luma = Rec. 601 in [0, 1]. Input -> output."
        ),
    ),
    ("flicker cut", "1 - flicker out / flicker in, averaged over clips (50% = halved)."),
    (
        "MC-SSIM",
        (
            "SSIM (Gaussian window, sigma 1.5, on luma) of each frame with the next one warped into its "
            "view, over pixels with a valid correspondence that are content in both; warping by ground-truth "
            "depth and poses on synthetic clips, else by DIS optical flow computed once on the input "
            "(forward-backward checked). 1 = consecutive frames agree up to motion; lighting changes lower it."
        ),
    ),
    (
        "dark",
        (
            "fraction of content pixels with luma < 0.1, mean over frames (input -> output): dark regions "
            "brightened when it falls."
        ),
    ),
    (
        "bright",
        (
            "fraction of content pixels with luma > 0.95, mean over frames (input -> output): over-exposure "
            "introduced when it rises (input speculars are not content, so they do not count)."
        ),
    ),
    (
        "brightness fixed / affine",
        (
            "the tracker's per-frame affine brightness e^-a (I - b). fixed: a = b = 0, not optimised, only the "
            "6 pose unknowns solved: the paper's setting (RNNSLAM runs DSO with mode=2, "
            "setting_affineOptModeA/B = -1), in which every lighting change between keyframe and frame is a "
            "residual. affine: a and b fitted per frame (DSO mode=1), which absorbs gain and exposure changes."
        ),
    ),
    (
        "tracker success",
        (
            "clips tracked without any frame's pose error over the tracker's threshold (see "
            "colonlight.evaluation.tracker: translation > max(2 mm, 25% of the true keyframe-to-frame "
            "motion), rotation > 3 degrees, divergence or too few valid points), over clips with known depth "
            "(synthetic), per brightness setting."
        ),
    ),
    (
        "tracked",
        (
            "per clip, the fraction of frames 1.. (each a keyframe -> frame pair) whose pose is within those "
            "thresholds and not lost; the mean over clips."
        ),
    ),
    (
        "clean, oracle-curve, oracle-gain-gamma, oracle-gamma",
        (
            "reference rows on clips with clean frames. clean: the clean frames themselves. oracle-curve: "
            "each frame mapped by the least-squares best monotone 256-entry tone curve from input to clean "
            "(weighted isotonic regression). oracle-gain-gamma: the least-squares best gain and gamma per frame "
            "(the default model's own family, min(1, gain * v ** gamma)). oracle-gamma: the least-squares best "
            "single gamma per frame. Both are applied as the product applies them (256-entry LUT, within its "
            "clamp ranges). They see the answer: oracle-curve is the ceiling for any method that applies one "
            "global correction per frame, the other two for their own family."
        ),
    ),
    (
        "gap closed",
        (
            "(method - input) / (oracle-curve - input) for success rate and for tracked fraction, per "
            "brightness setting, over the clips the method, the input and oracle-curve all tracked: 0 = no "
            "better than the input, 100% = as good as the best global tone curve per frame; n/a when the "
            f"oracle leads the input by less than {MIN_GAP:g} (a ratio of two tiny differences means nothing)."
        ),
    ),
    (
        "failure breakdown",
        (
            "the frames the input fails and the clean frames pass (lighting, not motion, lost them), by what "
            "changed between keyframe and frame in the clip's lighting ground truth: close occluder (the tip "
            "at the wall), saturation (>= 5% more saturated pixels than clean), gain jump (display gain "
            "> 10%), exposure lag (auto-exposure > 10%), tone-curve change (contrast exponent > 5%), after a "
            "failure (none of these, but the previous frame failed: a lost track cascades), other; a method "
            "rescues a frame when its own track passes it."
        ),
    ),
    (
        "pose error",
        (
            "per clip the median over frames of the keyframe-relative pose error; the table gives the "
            "median over tracked clips (translation in mm, rotation in degrees). A diverged track's errors are "
            "astronomical, so a mean over all frames says nothing; results.json and table.csv also give the "
            "mean over the frames before each clip's first failure (track_te_mean_tracked_m)."
        ),
    ),
    (
        "registered",
        (
            "COLMAP (pycolmap): fraction of the clip's frames registered in its largest model, mean over "
            "clips; 0 when COLMAP cannot initialise."
        ),
    ),
    (
        "ATE",
        (
            "absolute trajectory error of COLMAP's camera centres against ground truth after a Sim(3) Umeyama "
            "alignment (evo APE, translation part), in mm: each statistic is the mean over clips with an ATE "
            "(at least 3 registered frames)."
        ),
    ),
    (
        "ms/frame",
        (
            "wall time of the method alone per frame at working size (no decoding or writing), and CPU "
            "time of this process (less sensitive to other jobs on a shared machine)."
        ),
    ),
]


# ----------------------------------------------------------------------------------------------- plain data


def clean_json(obj: Any) -> Any:
    """``obj`` with NaN/inf as ``None`` and numpy scalars/arrays as Python values (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): clean_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return clean_json(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def versions() -> dict[str, str]:
    return {**library_versions(), **distribution_versions(_EXTRA_LIBS)}


def provenance(result: EvaluationResult, command: str | None = None) -> dict[str, Any]:
    """What made the report: versions, methods (parameters, model sha256), settings, clips, command."""
    return {
        "colonlight_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": command,
        "versions": versions(),
        "methods": result.methods,
        "skipped_methods": result.skipped_methods,
        "settings": result.settings,
        "clips": [c.info for c in result.clips],
        "failures": result.failures,
    }


def fmt(x: Any, spec: str = ".4f", scale: float = 1.0, none: str = "n/a") -> str:
    """``x * scale`` formatted with ``spec``; ``none`` for a missing or non-finite value."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return none
    return format(float(x) * scale, spec)


def fmt_pair(a: Any, b: Any, spec: str = ".4f", scale: float = 1.0) -> str:
    """``"a -> b"`` (input -> output)."""
    return f"{fmt(a, spec, scale)} -> {fmt(b, spec, scale)}"


def table_rows(rows: Sequence[dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """Headers and formatted cells of the summary table (one row per method)."""
    headers = [
        "method", "clips", "flicker in -> out", "flicker cut", "MC-SSIM in -> out", "dark % in -> out",
        "bright % in -> out", "COLMAP registered",
        "ATE rmse / mean / std / min / median / max (mm)", "ms/frame (wall / CPU)",
    ]  # fmt: skip
    cells = []
    for r in rows:
        ate = " / ".join(fmt(r[f"ate_{k}_m"], ".2f", 1000) for k in ("rmse", "mean", "std", "min", "median", "max"))
        cells.append(
            [
                r["method"],
                str(r["clips"]),
                fmt_pair(r["flicker_in"], r["flicker_out"]),
                fmt(r["flicker_reduction"], ".0%"),
                fmt_pair(r["ssim_in"], r["ssim_out"], ".3f"),
                fmt_pair(r["dark_in"], r["dark_out"], ".1f", 100),
                fmt_pair(r["bright_in"], r["bright_out"], ".2f", 100),
                fmt(r["registered"], ".0%") if r["colmap_clips"] else "n/a",
                f"{ate} ({r['ate_clips']} clips)" if r["ate_clips"] else "n/a",
                f"{fmt(r['ms_per_frame'], '.1f')} / {fmt(r['cpu_ms_per_frame'], '.1f')}",
            ]
        )
    return headers, cells


def run_modes(result: EvaluationResult) -> tuple[str, ...]:
    """The brightness settings tracked in, in table order (fixed, the paper's, first)."""
    return tuple(result.settings.get("brightness") or ())


def success_cell(r: dict[str, Any], mode: str) -> str:
    """``"k/n (rate)"`` of one brightness setting."""
    if not r["tracked"] or r.get(f"track_success_{mode}") is None:
        return "n/a"
    return f"{r[f'track_success_{mode}']}/{r['tracked']} ({fmt(r[f'track_success_rate_{mode}'], '.0%')})"


def tracking_rows(rows: Sequence[dict[str, Any]], modes: Sequence[str]) -> tuple[list[str], list[list[str]]]:
    """Headers and cells of the tracking table: per brightness setting success, tracked fraction, the share of
    the input -> oracle-curve gap closed (success / tracked) and pose error."""
    headers = ["method", "clips"]
    for m in modes:
        headers += [f"{m}: success", f"{m}: tracked", f"{m}: gap closed (success / tracked)",
                    f"{m}: pose error (mm / deg)"]  # fmt: skip
    cells = []
    for r in rows:
        row = [r["method"], str(r["tracked"])]
        for m in modes:
            row += [
                success_cell(r, m),
                fmt(r[f"tracked_fraction_{m}"], ".3f"),
                f"{fmt(r[f'gap_closed_success_{m}'], '.0%')} / {fmt(r[f'gap_closed_tracked_{m}'], '.0%')}",
                f"{fmt(r[f'track_te_{m}_m'], '.2f', 1000)} / {fmt(r[f'track_re_{m}_deg'], '.2f')}",
            ]
        cells.append(row)
    return headers, cells


def breakdown_rows(breakdown: dict[str, Any], mode: str) -> tuple[list[str], list[list[str]]]:
    """Headers and cells of one setting's failure breakdown: per cause the input's failures (that the clean
    frames pass) and, per method, how many of them it rescues."""
    b = breakdown.get(mode) or {}
    labels = list(b.get("rescue") or {})
    headers = ["cause", "failures"] + [f"rescued by {lab}" for lab in labels]
    cells = []
    for cause in CAUSES:
        n = b["causes"][cause]
        if not n:
            continue
        row = [cause, str(n)]
        for lab in labels:
            rate = b["rescue"][lab]["by_cause"][cause]
            row.append(f"{round(rate * n)} ({fmt(rate, '.0%')})")
        cells.append(row)
    total = b.get("failures", 0)
    row = ["all", str(total)]
    for lab in labels:
        res = b["rescue"][lab]
        row.append(f"{res['rescued']} ({fmt(res['rate'], '.0%')})")
    cells.append(row)
    return headers, cells


NO_FAILURES = "No frame fails on the input where the clean frames track."
BRIGHTNESS_NOTE = (
    "Tracking is reported with the tracker's per-frame affine brightness **fixed** (a = b = 0) first: that is "
    "the paper's setting (RNNSLAM runs DSO with mode=2, so brightness is not optimised and every lighting change "
    "is left for the enhancement to fix). **affine** fits e^-a (I - b) per frame (DSO mode=1): stronger, it "
    "absorbs gain and exposure changes and so hides much of what a per-frame correction does."
)


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    out += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(out)


def _shown(text: str) -> str:
    """``text`` with a path's bytes that are not UTF-8 (surrogate escapes) as ``\\udcNN``, as :func:`_utf8`
    writes them."""
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _utf8(text: str) -> bytes:
    """``text`` as UTF-8, a clip path's bytes that are not UTF-8 (surrogate escapes) written as ``\\udcNN``, as
    :func:`colonlight.atomic.json_bytes` writes them: plain ``encode("utf-8")`` raised on them, a traceback after
    the whole evaluation had run, and no report."""
    return text.encode("utf-8", "backslashreplace")


def _csv(rows: Sequence[dict[str, Any]]) -> bytes:
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: "" if v is None else v for k, v in clean_json(r).items()})
    return _utf8(buf.getvalue())


def clip_rows(result: EvaluationResult) -> list[dict[str, Any]]:
    """One flat row per clip x method (for clips.csv)."""
    rows = []
    for c in result.clips:
        for label, r in c.results.items():
            t, cm = r.tracking or {}, r.colmap or {}
            ate = cm.get("ate") or {}
            rows.append(
                {
                    "clip": c.name,
                    "method": label,
                    "frames": r.frames,
                    "error": r.error,
                    "flicker_in": r.flicker_in,
                    "flicker_out": r.flicker_out,
                    "ssim_in": r.ssim_in,
                    "ssim_out": r.ssim_out,
                    "dark_in": r.dark_in,
                    "dark_out": r.dark_out,
                    "bright_in": r.bright_in,
                    "bright_out": r.bright_out,
                    "psnr_in": r.psnr_in,
                    "psnr_out": r.psnr_out,
                    **{
                        f"{key}_{m}": (t.get(m) or {}).get(field)
                        for m in BRIGHTNESS_MODES
                        for key, field in (
                            ("track_success", "success"),
                            ("tracked_fraction", "tracked_fraction"),
                            ("track_failed_at", "failed_at"),
                            ("track_te_median_m", "translation_error_m_median"),
                            ("track_re_median_deg", "rotation_error_deg_median"),
                        )
                    },
                    "colmap_registered": cm.get("registered"),
                    "colmap_fraction": cm.get("fraction"),
                    **{f"ate_{k}_m": ate.get(k) for k in ("rmse", "mean", "median", "std", "min", "max")},
                    "ms_per_frame": r.ms_per_frame,
                    "cpu_ms_per_frame": r.cpu_ms_per_frame,
                }
            )
    return rows


def markdown_report(result: EvaluationResult, rows: Sequence[dict[str, Any]]) -> str:
    headers, cells = table_rows(rows)
    n_gt = sum(1 for c in result.clips if c.info.get("ground_truth"))
    lines = [
        f"# colonlight evaluation: {len(result.clips)} clips ({n_gt} with ground truth)",
        "",
        markdown_table(headers, cells),
        "",
    ]
    lines += _markdown_tracking(result, rows)
    if result.skipped_methods:
        lines += ["Skipped methods:", ""] + [f"- {k}: {v}" for k, v in result.skipped_methods.items()] + [""]
    if result.failures:
        lines += ["Clips that could not be read:", ""] + [f"- {f['clip']}: {f['error']}" for f in result.failures]
        lines += [""]
    lines += ["Definitions:", ""] + [f"- **{k}**: {v}" for k, v in DEFINITIONS]
    return "\n".join(lines) + "\n"


def _markdown_tracking(result: EvaluationResult, rows: Sequence[dict[str, Any]]) -> list[str]:
    modes = run_modes(result)
    if not modes or not any(r["tracked"] for r in rows):
        return []
    headers, cells = tracking_rows(rows, modes)
    lines = ["## Tracking", "", BRIGHTNESS_NOTE, "", markdown_table(headers, cells), ""]
    breakdown = failure_breakdown(result)
    for m in modes:
        if breakdown.get(m):
            h, c = breakdown_rows(breakdown, m)
            lines += [f"### Why the input fails where the clean frames track (brightness {m})", "",
                      markdown_table(h, c) if breakdown[m]["failures"] else NO_FAILURES, ""]  # fmt: skip
    return lines


# ------------------------------------------------------------------------------------------------------ plots


def _colours(labels: Sequence[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return {label: cmap(i % 10) for i, label in enumerate(labels)}


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(b64: str, alt: str, mime: str = "image/png") -> str:
    return f'<img alt="{html.escape(alt)}" src="data:{mime};base64,{b64}">'


def clip_plot(result: EvaluationResult, clip_index: int) -> str:
    """Per-frame mean luma of the input and each method; gamma over time for methods that have one."""
    from matplotlib.figure import Figure

    c = result.clips[clip_index]
    colours = _colours(result.labels)
    with_gamma = [lab for lab, r in c.results.items() if r.gammas]
    fig = Figure(figsize=(9, 4.6 if with_gamma else 2.8))
    axes = fig.subplots(2 if with_gamma else 1, 1, sharex=True, squeeze=False)[:, 0]
    ax = axes[0]
    fps = float(c.info.get("fps") or DEFAULT_FPS)
    t = np.arange(len(c.luma_in)) / fps
    ax.plot(t, c.luma_in, color="black", lw=2, ls="--", label="input")
    for label, r in c.results.items():
        if r.luma_out:
            ax.plot(t, r.luma_out, color=colours[label], lw=1.2, label=label)
    ax.set_ylabel("mean luma")
    ax.set_title(_shown(c.name), fontsize=10)  # matplotlib refuses a name's surrogate escapes (a traceback)
    ax.legend(fontsize=7, ncol=4, loc="best")
    if with_gamma:
        for label in with_gamma:
            g = [np.nan if v is None else v for v in (c.results[label].gammas or [])]
            axes[1].plot(t[: len(g)], g, color=colours[label], label=label)
        axes[1].axhline(1.0, color="0.6", lw=0.8)
        axes[1].set_ylabel("gamma")
        axes[1].legend(fontsize=7)
    axes[-1].set_xlabel("time (s)")
    return _png(fig)


def bars_plot(result: EvaluationResult, rows: Sequence[dict[str, Any]]) -> str | None:
    """Success bars: tracker success rate, COLMAP registered fraction, flicker (input vs output) per method."""
    from matplotlib.figure import Figure

    if not rows:
        return None
    labels = [r["method"] for r in rows]
    colours = _colours(result.labels)
    panels: list[tuple[str, list[float], float | None]] = []
    if any(r["tracked"] for r in rows):
        for m in run_modes(result):
            panels.append((f"tracker success rate ({m})", [r[f"track_success_rate_{m}"] or 0.0 for r in rows], None))
            panels.append((f"tracked fraction ({m})", [r[f"tracked_fraction_{m}"] or 0.0 for r in rows], None))
    if any(r["colmap_clips"] for r in rows):
        panels.append(("COLMAP frames registered", [r["registered"] or 0.0 for r in rows], None))
    flick = [r["flicker_out"] if math.isfinite(r["flicker_out"]) else 0.0 for r in rows]
    panels.append(("flicker (mean |d luma|)", flick, rows[0]["flicker_in"]))
    fig = Figure(figsize=(3.4 * len(panels), 0.35 * len(labels) + 1.4))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    y = np.arange(len(labels))
    for ax, (title, values, ref) in zip(axes, panels, strict=True):
        ax.barh(y, values, color=[colours.get(lab, "0.5") for lab in labels])
        ax.set_yticks(y, labels if ax is axes[0] else [""] * len(labels), fontsize=8)
        ax.invert_yaxis()
        ax.set_title(title, fontsize=9)
        if ref is not None and math.isfinite(ref):
            ax.axvline(ref, color="black", ls="--", lw=1)
        if "rate" in title or "registered" in title or "fraction" in title:
            ax.set_xlim(0, 1)
    return _png(fig)


def strip_image(thumbs: Sequence[np.ndarray]) -> str:
    """Thumbnails side by side (2 px gaps) as base64 JPEG (sensor noise makes PNG strips 10x larger)."""
    h = max(t.shape[0] for t in thumbs)
    gap = np.full((h, 2, 3), 255, np.uint8)
    parts: list[np.ndarray] = []
    for t in thumbs:
        if t.shape[0] != h:
            t = np.pad(t, ((0, h - t.shape[0]), (0, 0), (0, 0)))
        parts += [t, gap]
    return base64.b64encode(encode_image(np.hstack(parts[:-1]), "jpg", quality=88)).decode("ascii")


# ------------------------------------------------------------------------------------------------------- HTML

_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222;max-width:1400px}
table{border-collapse:collapse;font-size:13px;margin:.5em 0}
th,td{border:1px solid #ccc;padding:3px 7px;text-align:right;vertical-align:middle}
th:first-child,td:first-child{text-align:left}
th{background:#f2f2f2}
pre{background:#f7f7f7;padding:.6em;font-size:11px;overflow:auto;max-height:30em}
img{max-width:100%}
.bad{color:#a00}
dt{font-weight:bold}
"""


def _html_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in headers) + "</tr>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>")
    return "".join(out) + "</table>"


def html_report(
    result: EvaluationResult, rows: Sequence[dict[str, Any]], prov: dict[str, Any], max_clip_plots: int = 60
) -> str:
    """The self-contained HTML report."""
    import json

    headers, cells = table_rows(rows)
    n_gt = sum(1 for c in result.clips if c.info.get("ground_truth"))
    e = html.escape
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>colonlight evaluation</title><style>{_CSS}</style></head><body>",
        (
            f"<h1>colonlight evaluation</h1><p>{len(result.clips)} clips ({n_gt} with ground truth), "
            f"{len(result.labels)} methods; colonlight {e(__version__)}; created {e(str(prov.get('created')))}; "
            f"{result.seconds:.0f} s.</p>"
        ),
    ]
    if prov.get("command"):
        parts.append(f"<p><code>{e(str(prov['command']))}</code></p>")
    parts += ["<h2>Summary</h2>", _html_table(headers, cells)]
    modes = run_modes(result)
    if modes and any(r["tracked"] for r in rows):
        th, tc = tracking_rows(rows, modes)
        note = e(BRIGHTNESS_NOTE).replace("**fixed**", "<b>fixed</b>").replace("**affine**", "<b>affine</b>")
        parts += ["<h2>Tracking</h2>", f"<p>{note}</p>", _html_table(th, tc)]
        breakdown = failure_breakdown(result)
        for m in modes:
            if breakdown.get(m):
                bh, bc = breakdown_rows(breakdown, m)
                parts += [f"<h3>Why the input fails where the clean frames track (brightness {e(m)})</h3>",
                          _html_table(bh, bc) if breakdown[m]["failures"] else f"<p>{e(NO_FAILURES)}</p>"]  # fmt: skip
    if result.skipped_methods:
        parts.append("<p class='bad'>Skipped methods:</p><ul>")
        parts += [f"<li>{e(k)}: {e(v)}</li>" for k, v in result.skipped_methods.items()]
        parts.append("</ul>")
    if result.failures:
        parts.append("<p class='bad'>Clips that could not be read:</p><ul>")
        parts += [f"<li>{e(f['clip'])}: {e(f['error'])}</li>" for f in result.failures]
        parts.append("</ul>")
    errors = [(c.name, r.method, r.error) for c in result.clips for r in c.results.values() if r.error]
    if errors:
        parts.append("<p class='bad'>Methods that failed on a clip:</p><ul>")
        parts += [f"<li>{e(c)} / {e(m)}: {e(str(err))}</li>" for c, m, err in errors]
        parts.append("</ul>")
    bars = bars_plot(result, rows)
    if bars:
        parts += ["<h2>Success and flicker per method</h2>", _img(bars, "success bars")]
    parts.append("<h2>Definitions</h2><dl>")
    parts += [f"<dt>{e(k)}</dt><dd>{e(v)}</dd>" for k, v in DEFINITIONS]
    parts.append("</dl>")
    if result.strips:
        parts.append("<h2>Before / after</h2>")
        for clip, strips in result.strips.items():
            idx = result.strip_frames.get(clip, [])
            parts.append(f"<h3>{e(clip)}</h3><p>frames {', '.join(map(str, idx))}</p><table>")
            for label, thumbs in strips.items():
                if thumbs:
                    parts.append(
                        f"<tr><td>{e(label)}</td><td>{_img(strip_image(thumbs), label, 'image/jpeg')}</td></tr>"
                    )
            parts.append("</table>")
    parts.append("<h2>Per clip: luminance and gamma over time</h2>")
    for i, c in enumerate(result.clips[:max_clip_plots]):
        info = c.info
        desc = f"{info.get('frames')} frames at {info.get('fps')} fps, {info.get('size')}; {c.correspondence}"
        if info.get("seed") is not None:
            desc += f"; seed {info['seed']}, close occluder: {info.get('close_occluder')}"
        parts.append(f"<details{' open' if i == 0 else ''}><summary>{e(c.name)} ({e(desc)})</summary>")
        parts.append(_img(clip_plot(result, i), f"luminance of {c.name}"))
        parts.append("</details>")
    if len(result.clips) > max_clip_plots:
        parts.append(f"<p>(plots of the first {max_clip_plots} clips; all numbers are in results.json)</p>")
    parts += [
        "<h2>Provenance</h2><pre>",
        e(json.dumps(clean_json(prov), indent=1, ensure_ascii=False)),
        "</pre></body></html>",
    ]
    return "\n".join(parts)


# ------------------------------------------------------------------------------------------------------ write


def write_report(result: EvaluationResult, out_dir: Path, command: str | None = None) -> dict[str, Path]:
    """Write every report file into ``out_dir`` (atomically); returns their paths by kind."""
    out_dir = Path(out_dir)
    rows = summarize(result)
    prov = provenance(result, command)
    paths = {
        "json": out_dir / RESULTS_FILE,
        "markdown": out_dir / TABLE_MD,
        "csv": out_dir / TABLE_CSV,
        "clips_csv": out_dir / CLIPS_CSV,
        "html": out_dir / REPORT_HTML,
    }
    record = {"provenance": prov, **result.to_dict()}
    # Every file is made, then written to a temporary, before any is renamed into place: written one by one, a
    # Ctrl-C while the HTML's plots were drawn left the new results.json and tables beside the last run's
    # report.html, one report set describing two evaluations.
    contents = {
        "json": json_bytes(clean_json(record)),
        "markdown": _utf8(markdown_report(result, rows)),
        "csv": _csv(rows),
        "clips_csv": _csv(clip_rows(result)),
        "html": _utf8(html_report(result, rows, prov)),
    }
    temporaries: dict[str, Path] = {}
    try:
        for kind, data in contents.items():
            temporaries[kind] = write_temporary(paths[kind], data)
        for kind in list(temporaries):
            # the name is let go only once renamed: popped first, an interrupt as publish was entered left it
            publish(temporaries[kind], paths[kind])
            del temporaries[kind]
    finally:  # none is left behind by a failure or an interrupt
        for tmp in temporaries.values():
            tmp.unlink(missing_ok=True)
    return paths


__all__ = [
    "DEFINITIONS",
    "breakdown_rows",
    "clean_json",
    "markdown_report",
    "provenance",
    "summarize",
    "table_rows",
    "tracking_rows",
    "write_report",
]
