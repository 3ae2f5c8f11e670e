"""What the paper's training objective rewards on our synthetic clips: the loss of candidate outputs, no training.

For sequences cut exactly as in training (10 frames, stride 5, seeds 0 and 1), the paper's loss
(:func:`colonlight.train.sequence_loss`) is computed for outputs that no network made:

- ``input``: frames left unchanged (a = 1);
- ``clean``: the generator's undisturbed frames (a perfect restoration, scored against the clean seeds);
- ``flatten``: per frame the gamma that brings the frame's mean to its sequence's seeds' mean (an oracle
  flicker remover);
- ``washout``: a = 8 everywhere (gamma 1/8, the clamp the collapsed runs hit).

If the objective is to teach a network to remove flicker, ``flatten`` and ``clean`` must score clearly below
``input`` and ``washout`` must not. The table shows for which sizes and camera speeds that holds. Two families of
clips, both drawn from the generator's training split (seeds 1000..1005, the first training seeds): as sampled
(camera speeds from ``PARAM_SPECS["speed_mm_s"]``), and the same clips with the camera slowed to 2 mm/s with
little jitter and noise.

Run: ``python -m benchmarks objective_landscape`` (about 5 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import sys

import cv2
import numpy as np
import torch

from colonlight.synth.config import PARAM_SPECS
from colonlight.train import sequence_loss

from .common import markdown_table

SEEDS = range(1000, 1006)
N_FRAMES, RENDER = 40, 256
SIZES = (48, 64, 128, 256)
SLOW = {
    "speed_mm_s": 2.0,
    "speed_var": 0.0,
    "jitter_deg": 0.1,
    "look_var_deg": 2.0,
    "lateral": 0.0,
    "roll_var_deg": 0.0,
    "roll_rate_deg_s": 0.0,
    "read_noise": 0.001,
    "shot_noise": 0.0005,
}


def render(overrides: dict[str, object]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(disturbed, clean) frame stacks of the clips, each ``(T, H, W, 3)`` uint8."""
    from colonlight.synth import SynthConfig, generate_clip

    out = []
    for seed in SEEDS:
        cfg = SynthConfig.sample(
            np.random.default_rng(seed), split="train", width=RENDER, height=RENDER, n_frames=N_FRAMES, **overrides
        )
        frames = list(generate_clip(cfg, seed=seed))
        out.append((np.stack([f.image for f in frames]), np.stack([f.clean for f in frames])))
    return out


def sequences(stacks: list[np.ndarray], size: int) -> torch.Tensor:
    """Training sequences ``(N, 10, 3, size, size)`` in [0, 1], cut with stride 5."""
    seqs = []
    for stack in stacks:
        small = np.stack([cv2.resize(f, (size, size), interpolation=cv2.INTER_AREA) for f in stack])
        small = small.astype(np.float32) / 255.0
        seqs += [small[s : s + 10] for s in range(0, len(small) - 9, 5)]
    return torch.from_numpy(np.stack(seqs)).permute(0, 1, 4, 2, 3).contiguous()


def flatten_a(x: torch.Tensor) -> torch.Tensor:
    """Per-frame a whose correction brings each frame's mean to its sequence's seeds' mean (bisection on a)."""
    a = torch.ones(x.shape[:2])
    for b in range(x.shape[0]):
        target = float(x[b, :2].mean())
        for t in range(2, x.shape[1]):
            frame = x[b, t].clamp_min(1e-6)
            lo, hi = 0.125, 8.0
            for _ in range(30):
                mid = (lo * hi) ** 0.5
                lo, hi = (mid, hi) if float((frame ** (1.0 / mid)).mean()) < target else (lo, mid)
            a[b, t] = (lo * hi) ** 0.5
    return a


def losses(images: torch.Tensor, clean: torch.Tensor) -> dict[str, float]:
    ones = torch.ones(images.shape[:2])
    with torch.no_grad():
        return {
            "input": float(sequence_loss(images, ones)),
            "clean": float(sequence_loss(clean, ones)),
            "flatten": float(sequence_loss(images, flatten_a(images))),
            "washout": float(sequence_loss(images, torch.full_like(ones, 8.0))),
        }


def main(argv: list[str] | None = None) -> str:
    # no options: --help says what it measures, anything else is refused (it was ignored, and the run started)
    argparse.ArgumentParser(prog="python -m benchmarks objective_landscape", description=__doc__).parse_args(argv or [])
    torch.set_num_threads(1)
    rows = []
    lo, hi = PARAM_SPECS["speed_mm_s"].train
    for family, overrides in ((f"as sampled ({lo:g}-{hi:g} mm/s)", {}), ("slow camera (2 mm/s)", SLOW)):
        clips = render(overrides)
        for size in SIZES:
            loss = losses(sequences([c[0] for c in clips], size), sequences([c[1] for c in clips], size))
            best = min(loss, key=loss.__getitem__)
            rows.append(
                [family, str(size)] + [f"{loss[k]:.4f}" for k in ("input", "clean", "flatten", "washout")] + [best]
            )
    return "\n".join(
        [
            f"## The paper's loss for candidate outputs ({len(SEEDS)} training-split clips x {N_FRAMES} frames)",
            "",
            markdown_table(
                ["clips", "size", "input (a=1)", "clean frames", "flatten (oracle)", "washout (a=8)", "lowest"], rows
            ),
            "",
            "Lower is what training moves towards. Where `washout` is lowest, training collapses to white frames;",
            "where `flatten` is no lower than `input`, the objective gives no reason to remove flicker.",
        ]
    )


if __name__ == "__main__":
    print(main(sys.argv[1:]))
