"""Choosing the network input size: how far gamma(size) strays from gamma(256), and what each size costs.

For the authors' checkpoint on the fixture frames (native 384x288) and on synthetic clips, each frame's gamma is
computed with the network fed a size x size copy (area-averaged) for sizes 48, 64, 96, 128 and 256, and compared
with gamma at 256 (the training resolution). Cost is the median ms per frame of the network step on this CPU,
with one torch thread (as `colonlight enhance` runs it, beside decoding and encoding) and with two.
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from colonlight.checkpoint import load_weights
from colonlight.methods.rnn import RecurrentGammaMethod, network_input, to_tensor

from .common import AUTHORS_CKPT, REFERENCE, markdown_table, median_time

SIZES = [48, 64, 96, 128, 256]


def _clip_gammas(weights: object, frames: list[np.ndarray], size: int) -> np.ndarray:
    stream = RecurrentGammaMethod(weights=weights, model_size=size, device="cpu").stream()  # type: ignore[arg-type]
    return np.array([1.0 / stream.predict_a(f) for f in frames])[2:]


def _fixture_frames() -> list[np.ndarray]:
    import cv2

    return [
        cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in sorted((REFERENCE / "frames_native").glob("*.png"))
    ]


def _synthetic_clips(n: int, frames: int) -> list[list[np.ndarray]]:
    from colonlight.synth import SynthConfig, generate_clip

    clips = []
    for seed in range(900_000, 900_000 + n):
        cfg = SynthConfig.sample(np.random.default_rng(seed), split="heldout", width=384, height=288, n_frames=frames)
        clips.append([f.image for f in generate_clip(cfg, seed=seed)])
    return clips


def main() -> str:
    if not AUTHORS_CKPT.is_file():
        return f"input_size: skipped (authors' checkpoint not found at {AUTHORS_CKPT})"
    weights = load_weights(AUTHORS_CKPT)
    sets = {
        "fixture (24 frames, 384x288)": [_fixture_frames()],
        "synthetic (8 clips x 40, 384x288)": _synthetic_clips(8, 40),
    }
    rows = []
    for label, clips in sets.items():
        ref = [_clip_gammas(weights, c, 256) for c in clips]
        for size in SIZES:
            diffs = np.concatenate(
                [np.abs(_clip_gammas(weights, c, size) - r) for c, r in zip(clips, ref, strict=True)]
            )
            rows.append([label, size, f"{diffs.mean():.4f}", f"{np.median(diffs):.4f}", f"{diffs.max():.4f}"])
    net = weights.net
    frame = _fixture_frames()[0]
    cost = []
    for size in SIZES + [None]:
        x = to_tensor(network_input(frame, size), torch.device("cpu"))
        state = None

        def step(x: torch.Tensor = x) -> None:  # this size's input (called only in this iteration)
            nonlocal state
            with torch.inference_mode():
                _, state = net.step(x, state)

        row: list[object] = [size or "full 384x288"]
        for threads in (1, 2):
            torch.set_num_threads(threads)
            row.append(f"{1000 * median_time(step, repeats=40, warmup=5):.2f}")
        cost.append(row)
    out = [
        "## Network input size (authors' checkpoint)",
        "",
        markdown_table(["clips", "size", "mean abs(gamma - gamma256)", "median", "max"], rows),
        "",
        markdown_table(["size", "ms/frame, 1 thread (median of 40)", "2 threads"], cost),
    ]
    return "\n".join(out)


if __name__ == "__main__":
    print(main())
    sys.exit(0)
