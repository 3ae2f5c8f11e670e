"""Choosing among checkpoints on validation clips (held-out generator family, seeds 720000+, never the gate's).

Per checkpoint: PSNR to the clean frames, flicker against the clean frames' own, and the tracker's success and
tracked fraction with per-frame brightness fixed (the paper's RNNSLAM setting) and fitted, on clips rendered at a
size training never used (160x128). The first clip of every four is steady (scored only for darkening); the others
start with two undisturbed frames.

Run: ``python -m benchmarks model_validation [--clips 8] [--first 0] [--weights W ...] [--methods he,clahe]``
(``none``, ``clean`` and the three oracles unless ``--no-references``: the ceilings of one global correction per
frame (the shipped curve head's family), of a gain and a gamma (the previous default's) and of one gamma;
``--methods`` adds built-in baselines, to see whether a candidate is ahead of them; ``--first N`` starts at clip
N, so that a lead found on the first clips can be checked on clips that chose nothing).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from colonlight.evaluation.oracles import CLEAN_LABEL, REFERENCE_LABELS, oracle_frames
from colonlight.evaluation.tracker import TrackerSettings, track_clip
from colonlight.methods import create_method
from colonlight.metrics import clip_lighting, content_masks
from colonlight.synth import SynthConfig, generate_clip
from colonlight.synth.camera import Intrinsics

from .common import clip_cache, markdown_table

SEED0, WIDTH, HEIGHT, FRAMES = 720_000, 160, 128, 60


def clip_overrides(i: int) -> dict[str, object]:
    if i % 4 == 0:
        return {"steady": True}
    return {"undisturbed_seeds": True, "close_occluder": "forbid" if i % 3 else "random"}


def validation_clips(n: int, first: int = 0) -> list[tuple[dict[str, object], SynthConfig, list]]:  # type: ignore[type-arg]
    """Clips ``first`` .. ``first + n - 1`` of the validation sequence (seed ``SEED0 + i``, clip ``i``'s mix)."""
    out = []
    for i in range(first, first + n):
        seed, over = SEED0 + i, clip_overrides(i)
        cfg = SynthConfig.sample(
            np.random.default_rng([seed, 1]), split="heldout", width=WIDTH, height=HEIGHT, n_frames=FRAMES, **over
        )
        out.append(
            (
                over,
                cfg,
                clip_cache(
                    f"{seed}-{WIDTH}x{HEIGHT}x{FRAMES}", lambda cfg=cfg, seed=seed: list(generate_clip(cfg, seed))
                ),
            )
        )
    return out


def _track(frames: list[np.ndarray], clip: list, cfg: SynthConfig, brightness: str) -> tuple[bool, float]:  # type: ignore[type-arg]
    i = Intrinsics.from_fov(cfg.width, cfg.height, cfg.fov_deg)
    K = np.array([[i.fx, 0, i.cx], [0, i.fy, i.cy], [0, 0, 1.0]])
    with np.errstate(all="ignore"):
        r = track_clip(
            frames, [f.depth for f in clip], K, [f.pose for f in clip], TrackerSettings(brightness=brightness)
        )
    return bool(r.success), float(np.mean(r.frame_ok[1:]))


def score(label: str, weights: str | None, clips: list, baseline: str | None = None) -> list[str]:  # type: ignore[type-arg]
    # weights None: the shipped default (the none, clean and oracle rows need no method); baseline: a built-in one
    if baseline is not None:
        method = create_method(baseline)
    else:
        method = None if label in ("none", *REFERENCE_LABELS) else create_method("rnn", weights=weights, device="cpu")
    psnr_in, psnr_out, fl_out, fl_clean, dark = [], [], [], [], []
    track: dict[str, list[tuple[bool, float]]] = {"fixed": [], "affine": []}
    for over, cfg, clip in clips:
        inp, clean = [f.image for f in clip], [f.clean for f in clip]
        if label == "none":
            out = inp
        elif label == CLEAN_LABEL:
            out = clean
        elif label in REFERENCE_LABELS:
            out = oracle_frames(inp, clean, label)[0]
        else:
            assert method is not None
            stream = method.stream()
            out = [r.frame for f in inp for r in stream.push(f)] + [r.frame for r in stream.flush()]
        masks = content_masks(inp)
        light = clip_lighting(inp, out, clean, masks=masks)
        if over.get("steady"):
            dark.append(light.mean_luma_in - light.mean_luma_out)
            continue
        psnr_in.append(light.psnr_in)
        psnr_out.append(min(float(light.psnr_out or 60.0), 60.0))
        fl_out.append(light.flicker_out)
        fl_clean.append(clip_lighting(inp, clean, clean, masks=masks).flicker_out)
        for mode in track:
            track[mode].append(_track(out, clip, cfg, mode))
    cells = [label, f"{np.mean(psnr_in):.2f} -> {np.mean(psnr_out):.2f}", f"{np.mean(fl_out) / np.mean(fl_clean):.2f}x"]
    for mode in ("fixed", "affine"):
        ok = track[mode]
        cells.append(f"{sum(s for s, _ in ok)}/{len(ok)}, {np.mean([t for _, t in ok]):.3f}")
    cells.append(f"{max(dark):+.4f}" if dark else "-")
    return cells


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m benchmarks model_validation")
    parser.add_argument("--clips", type=int, default=8)
    parser.add_argument(
        "--first",
        type=int,
        default=0,
        help=f"index of the first clip (seed {SEED0} + FIRST): fresh clips to confirm a lead found on the first ones",
    )
    parser.add_argument(
        "--weights", action="append", default=[], help="checkpoints to score (default: the shipped one)"
    )
    parser.add_argument(
        "--no-references",
        action="store_true",
        help="skip the none, clean and oracle rows (they do not change between runs)",
    )
    parser.add_argument(
        "--methods", default="", help="built-in baselines to score too, comma-separated (e.g. he,clahe)"
    )
    args = parser.parse_args(argv or [])
    clips = validation_clips(args.clips, args.first)
    rows = [] if args.no_references else [score(label, None, clips) for label in ("none", *REFERENCE_LABELS)]
    for name in filter(None, args.methods.split(",")):
        rows.append(score(name, None, clips, baseline=name))
    for w in args.weights or [None]:
        rows.append(score(w or "rnn (shipped)", w or None, clips))
    return "\n".join(
        [
            f"## Validation: {args.clips} held-out clips x {FRAMES} frames ({WIDTH}x{HEIGHT}), "
            f"seeds {SEED0 + args.first}..{SEED0 + args.first + args.clips - 1}",
            "",
            markdown_table(
                [
                    "weights",
                    "PSNR to clean (dB)",
                    "flicker vs clean",
                    "fixed: success, tracked",
                    "affine: success, tracked",
                    "steady: max darkening",
                ],
                rows,
            ),
        ]
    )


if __name__ == "__main__":
    print(main(sys.argv[1:]))
