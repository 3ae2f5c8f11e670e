"""Does a 3-D motion cue tell a scene that brightens from a camera's exposure change? (issue 12; measured, not used)

The default model darkens steady clips whose scene brightens (a wall coming near): from the frames alone one
global curve per frame cannot tell that from a gain or tone-curve change (README, session 26). Session 32 named a
3-D motion cue as the next input to try. This measures the simplest one before any training: with the light on
the scope tip, a surface point that comes nearer brightens with the inverse square of its distance, and its image
grows by the same factor, so a tracked point's brightening should follow the local area expansion of the optical
flow. Per frame pair, on 64 px greys:

* ``obs``: the median log brightening of the tracked pixels (DIS optical flow between histogram-equalised frames,
  which a monotone tone change leaves nearly unchanged, so the flow does not depend on the exposure);
* ``div``: the median log area expansion of the same pixels (``-log det`` of the flow map's Jacobian).

Only steady clips (recorded frames == clean frames) are used, so every brightening is the scene's. If ``obs``
followed ``div`` with one slope on both renderers, ``div`` would predict the scene's part of a brightening and the
rest would be the camera's. The table gives, per renderer, the least-squares slope of ``obs`` on ``div`` (through
zero) and their correlation over frame pairs, and the sums over the pairs where the frame's mean brightens.

Run: ``python -m benchmarks motion_cue [--workdir DIR]`` (the quality gate's cached held-out clips, and the
blind renderer's steady clips 3 and 7 of seed 0, rendered into the work folder that ``python -m benchmarks
blind_renderer`` uses and shares, unless there already: a few minutes).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from .blind_renderer import is_steady, render_clips
from .blind_renderer_check import WORKDIR
from .common import markdown_table
from .quality_gate import heldout_clips

SIDE = 64
#: Pixels darker or brighter than these (8-bit) in either frame are left out: no usable log ratio.
DARK, BRIGHT = 8, 250
#: A flow map that shrinks a pixel's area to less than this is a fold or an occlusion, not a surface coming nearer.
MIN_AREA = 0.2
MIN_PIXELS = 50
#: The blind renderer's clips measured (seed 0): its first two steady ones.
BLIND_CLIPS = tuple(i for i in range(8) if is_steady(i))


def grey(frame: np.ndarray) -> np.ndarray:
    """An RGB frame as a ``SIDE x SIDE`` area-averaged 8-bit grey."""
    return cv2.resize(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY), (SIDE, SIDE), interpolation=cv2.INTER_AREA)


def pair_cue(before: np.ndarray, after: np.ndarray, flow: cv2.DISOpticalFlow) -> tuple[float, float] | None:
    """``(obs, div)`` for one pair of greys (module docstring), or None with too few usable pixels."""
    back = flow.calc(cv2.equalizeHist(after), cv2.equalizeHist(before), None)  # after's pixel -> before's
    xs, ys = np.meshgrid(np.arange(SIDE, dtype=np.float32), np.arange(SIDE, dtype=np.float32))
    mx, my = xs + back[..., 0], ys + back[..., 1]
    warped = cv2.remap(before.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderValue=-1.0)
    det = np.gradient(mx, axis=1) * np.gradient(my, axis=0) - np.gradient(mx, axis=0) * np.gradient(my, axis=1)
    ok = (warped > DARK) & (warped < BRIGHT) & (after > DARK) & (after < BRIGHT) & (det > MIN_AREA)
    if ok.sum() < MIN_PIXELS:
        return None
    obs = np.log(after[ok].astype(np.float32)) - np.log(warped[ok])
    return float(np.median(obs)), float(np.median(-np.log(det[ok])))


def clip_cues(frames: Sequence[np.ndarray]) -> list[tuple[float, float, float]]:
    """``(mean log brightening, obs, div)`` for each usable pair of consecutive frames."""
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    greys = [grey(f) for f in frames]
    rows = []
    for before, after in zip(greys, greys[1:], strict=False):
        cue = pair_cue(before, after, flow)
        if cue is not None:
            rows.append((float(np.log(after.mean() / max(before.mean(), 1e-6))), *cue))
    return rows


def summary(name: str, clips: list[list[tuple[float, float, float]]]) -> list[object]:
    """One renderer's table row over its steady clips' pairs."""
    rows = np.array([r for clip in clips for r in clip])
    mean, obs, div = rows.T
    up = mean > 0
    slope = float(obs @ div / max(float(div @ div), 1e-12))
    corr = float(np.corrcoef(obs, div)[0, 1])
    return [name, len(clips), len(rows), f"{slope:.2f}", f"{corr:.2f}", f"{obs[up].sum():.3f}", f"{div[up].sum():.3f}"]


def read_clip(folder: Path) -> list[np.ndarray]:
    """A rendered clip's recorded frames, RGB."""
    return [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in sorted((folder / "frames").glob("*.png"))]


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m benchmarks motion_cue")
    parser.add_argument("--workdir", type=Path, default=WORKDIR, help="the blind renderer's clips (shared with it)")
    args = parser.parse_args(argv or [])
    gate = [clip_cues(images) for meta, images, _ in heldout_clips() if meta.get("steady")]
    folders = render_clips(args.workdir / "seed0" / "clips", seed=0, only=BLIND_CLIPS)
    blind = [clip_cues(read_clip(f)) for f in folders]
    head = ["steady clips of", "clips", "frame pairs", "slope obs/div", "corr", "sum obs (brightening)", "sum div"]
    table = markdown_table(head, [summary("colonlight's generator (gate)", gate), summary("blind renderer", blind)])
    return "## motion cue: tracked brightening (obs) against flow area expansion (div)\n\n" + table
