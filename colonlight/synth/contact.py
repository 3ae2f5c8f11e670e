"""Contact sheets: look at what the generator makes (rows of frames from several clips, clean beside
disturbed).

python -m colonlight.synth.contact docs/synth_contact_sheet.png
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..atomic import write_bytes_atomic
from .clip import Scene, build_scene, render_frame
from .config import OccluderMode, Split, SynthConfig

LABEL_W = 120


@dataclass(frozen=True)
class SheetRow:
    """One clip of the sheet; ``show`` selects which rows it contributes ("image", "clean", "depth")."""

    label: str
    seed: int
    split: Split = "train"
    steady: bool = False
    close_occluder: OccluderMode = "random"
    show: tuple[str, ...] = ("image",)


DEFAULT_ROWS = (
    SheetRow("train, steady", 42, steady=True, close_occluder="forbid", show=("image", "depth")),
    SheetRow("train, steady", 9, steady=True, close_occluder="forbid"),
    SheetRow("close occluder", 4, steady=True, close_occluder="force"),
    SheetRow("disturbed clip", 3, close_occluder="forbid", show=("clean", "image")),
    SheetRow("held-out family", 33, split="heldout", steady=True),
)


def _label(text: str, lines: list[str], h: int) -> np.ndarray:
    tile = np.full((h, LABEL_W, 3), 24, np.uint8)
    for k, t in enumerate([text, *lines]):
        cv2.putText(
            tile,
            t,
            (4, 16 + 14 * k),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.36 if k else 0.42,
            (235, 235, 235) if k == 0 else (170, 170, 170),
            1,
            cv2.LINE_AA,
        )
    return tile


def _depth_tile(depth_m: np.ndarray) -> np.ndarray:
    """Log-depth colour map (near = warm); no wall = black."""
    fin = np.isfinite(depth_m)
    ld = np.log(np.where(fin, np.maximum(depth_m, 1e-3), 1.0))
    lo, hi = np.log(0.003), np.log(0.3)
    v = np.clip((hi - ld) / (hi - lo), 0, 1)
    rgb = cv2.applyColorMap((v * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1]
    return np.where(fin[..., None], rgb, 0).astype(np.uint8)


def _pick(scene: Scene, even: np.ndarray, disturbed: bool) -> list[int]:
    """Evenly spaced frames, or for a disturbed clip the most disturbed ones (in order) so events are seen."""
    if not disturbed:
        return [int(i) for i in even]
    lt = scene.lighting
    n = len(lt.gain)
    score = np.abs(np.log([lt.display_gain(i) for i in range(n)])) + 2 * np.abs(np.log(lt.contrast))
    chosen: list[int] = [0]
    for i in np.argsort(-score, kind="stable"):
        if len(chosen) == len(even):
            break
        if all(abs(int(i) - c) >= 3 for c in chosen):
            chosen.append(int(i))
    return sorted(chosen)


def contact_sheet(
    rows: tuple[SheetRow, ...] = DEFAULT_ROWS, size: int = 144, n_cols: int = 6, n_frames: int = 72
) -> np.ndarray:
    """An RGB sheet: each clip gives ``n_cols`` evenly spaced frames per requested row kind."""
    out = []
    picks = np.linspace(0, n_frames - 1, n_cols).round().astype(int)
    for row in rows:
        cfg = SynthConfig.sample(
            np.random.default_rng(row.seed),
            split=row.split,
            width=size,
            height=size,
            n_frames=n_frames,
            steady=row.steady,
            close_occluder=row.close_occluder,
        )
        scene = build_scene(cfg, row.seed)
        frames = [render_frame(scene, int(i)) for i in _pick(scene, picks, "clean" in row.show)]
        for kind in row.show:
            tiles = []
            for f in frames:
                if kind == "depth":
                    tile = _depth_tile(f.depth)
                else:
                    tile = (f.image if kind == "image" else f.clean).copy()
                    lt = f.lighting
                    if kind == "image" and lt["disturbed"]:
                        txt = f"g{lt['gain']:.2f} e{lt['exposure']:.2f} k{lt['contrast']:.2f}"
                        cv2.putText(
                            tile,
                            txt,
                            (3, size - 5),
                            cv2.FONT_HERSHEY_SIMPLEX,
                            0.33,
                            (255, 255, 120),
                            1,
                            cv2.LINE_AA,
                        )
                    if f.occluder:
                        cv2.putText(
                            tile,
                            "occluder",
                            (3, 11),
                            cv2.FONT_HERSHEY_SIMPLEX,
                            0.33,
                            (120, 255, 255),
                            1,
                            cv2.LINE_AA,
                        )
                tiles.append(tile)
            extra = [
                f"seed {row.seed}, {row.split}",
                {"image": "as recorded", "clean": "clean (fixed exposure)", "depth": "depth (log)"}[kind],
            ]
            if row.split == "heldout":
                extra += [p[:18] for p in cfg.heldout_params[:4]]
            out.append(np.concatenate([_label(row.label, extra, size), *tiles], axis=1))
        out.append(np.full((3, out[-1].shape[1], 3), 0, np.uint8))
    return np.concatenate(out[:-1], axis=0)


def main(argv: list[str]) -> None:
    dest = Path(argv[0]) if argv else Path("synth_contact_sheet.png")
    sheet = contact_sheet()
    ok, buf = cv2.imencode(".png", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise OSError("PNG encoding failed")
    write_bytes_atomic(dest, buf.tobytes())
    print(dest)


if __name__ == "__main__":
    main(sys.argv[1:])
