"""The methods on clips of a second renderer, written blind to colonlight's generator (:mod:`.blind_renderer`).

The default model was trained and chosen on colonlight's own generator; issue 12 judges it also on an independent
renderer that the project never sees. This is the nearest check the project can run itself: 12 clips of 60
frames at 320x256 per seed (clips 3, 7 and 11 steady), each scored by ``colonlight evaluate --brightness both``
as a user runs it (a real process), with the oracles and, where ``../shared`` holds it, the authors' checkpoint.
The clips are never used to train or choose a model.

Reported per method, pooled over the seeds: whole clips tracked and the fraction of frames tracked with the
tracker's per-frame brightness fixed (the paper's setting) and fitted; flicker against the clean frames' own;
PSNR to the clean frames over the disturbed clips; on the steady clips (input == clean) the largest darkening of
the mean luminance (input minus output, in [0, 1]; the quality gate allows 0.005); the cost.

Run: ``python -m benchmarks blind_renderer [--seeds 0,1] [--clips 12] [--workdir DIR]`` (about 10 minutes of
rendering and 10 of evaluation per seed on 2 cores; the clips are kept in the work folder and reused).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .blind_renderer import render_clips
from .common import AUTHORS_CKPT, markdown_table

METHODS = "none,he,clahe,deflicker,zerodce,zerodce++,rnn"
MODES = ("fixed", "affine")
#: Where the clips and reports are kept between runs (``--workdir``; ``motion_cue`` reads the same clips).
WORKDIR = Path(tempfile.gettempdir()) / "colonlight-blind-renderer"


def _evaluate(clips: Path, out: Path) -> dict[str, Any]:
    """``colonlight evaluate`` on the clip folder (a real process, as a user runs it); its results.json."""
    cmd = [sys.executable, "-m", "colonlight_cli.main", "evaluate", str(clips), "-o", str(out), "--methods", METHODS]
    cmd += ["--brightness", "both", "--no-colmap", "-q"]
    if AUTHORS_CKPT.is_file():
        cmd += ["--authors-checkpoint", str(AUTHORS_CKPT)]
    subprocess.run(cmd, check=True)
    results: dict[str, Any] = json.loads((out / "results.json").read_text())
    return results


def _is_steady(clip: dict[str, Any]) -> bool:
    lighting = json.loads((Path(clip["info"]["source"]) / "lighting.json").read_text())
    return bool(lighting.get("steady"))


def _row(label: str, clips: list[dict[str, Any]], steady: list[bool]) -> list[object]:
    """One method's cells over every clip of every seed (``steady``: each clip's flag, in order)."""
    rs = [(c["results"][label], s) for c, s in zip(clips, steady, strict=True) if label in c["results"]]
    cells: list[object] = [label]
    for mode in MODES:
        tracks = [t for r, _ in rs if (t := (r.get("tracking") or {}).get(mode)) and t.get("applicable")]
        whole = sum(bool(t["success"]) for t in tracks)
        cells += [f"{whole}/{len(tracks)}", f"{np.mean([t['tracked_fraction'] for t in tracks]):.3f}"]
    clean = [c["results"]["clean"]["flicker_out"] for c, s in zip(clips, steady, strict=True) if not s]
    flicker = np.mean([r["flicker_out"] for r, steady in rs if not steady]) / np.mean(clean)
    psnr = [r["psnr_out"] for r, steady in rs if not steady]
    dark = [r["mean_luma_in"] - r["mean_luma_out"] for r, steady in rs if steady]
    cells += [
        f"{flicker:.2f}x",
        "-" if any(p is None for p in psnr) else f"{np.mean(psnr):.2f}",
        f"{max(dark):+.4f}",
        f"{np.mean([r['ms_per_frame'] for r, _ in rs]):.1f}",
    ]
    return cells


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m benchmarks blind_renderer")
    parser.add_argument("--seeds", default="0,1", help="comma-separated renderer seeds (12 clips each)")
    parser.add_argument("--clips", type=int, default=12)
    parser.add_argument("--workdir", type=Path, default=WORKDIR)
    args = parser.parse_args(argv or [])
    seeds = [int(s) for s in args.seeds.split(",")]
    clips: list[dict[str, Any]] = []
    labels: list[str] = []
    for seed in seeds:
        folder = args.workdir / f"seed{seed}"
        render_clips(folder / "clips", seed, args.clips)
        results = _evaluate(folder / "clips", folder / "eval")
        clips += results["clips"]
        labels = [m["label"] for m in results["methods"]]
    headers = ["method"]
    for mode in MODES:
        headers += [f"{mode}: whole clips", f"{mode}: tracked"]
    headers += ["flicker vs clean", "PSNR to clean (dB)", "steady: max darkening", "ms/frame"]
    steady = [_is_steady(c) for c in clips]  # read once per clip, not once per method and column
    rows = [_row(label, clips, steady) for label in labels]
    psnr_in = np.mean([c["results"]["none"]["psnr_in"] for c, s in zip(clips, steady, strict=True) if not s])
    return (
        f"## Blind second renderer: seeds {args.seeds}, {len(clips)} clips ({sum(steady)} steady), 60 frames at "
        f"320x256\n\n{markdown_table(headers, rows)}\n\nInput PSNR to clean: {psnr_in:.2f} dB. "
        f"Clips and reports: {args.workdir}"
    )
