"""The model's cost per frame as the CLI runs it: one torch thread, a 1350x1080 frame resized to the network's
input, the network step and the correction's table applied; the issue's budget is 5 ms per frame on 2 cores.

Reported: the network step with the resize (the model's cost, the budget's subject, as earlier runs gave it) and
the whole ``push`` (the correction's table applied to the full frame too). Side by side in one run, frames
interleaved so that a noisy shared machine slows both alike: the shipped default against the paper's architecture
(``rgb`` input, the same head, the same size: the baseline), so the ratio says what the default's own input costs
beyond the network every model shares.

Run: ``python -m benchmarks model_cost [--frames 200] [--weights W]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import torch

from colonlight.checkpoint import LoadedWeights, load_weights
from colonlight.methods.rnn import RecurrentGammaMethod
from colonlight.model import GammaNet

from .common import markdown_table

WIDTH, HEIGHT = 1350, 1080
BUDGET_MS = 5.0
BASELINE = "baseline: rgb input, same head and size"


def _baseline(weights: LoadedWeights) -> LoadedWeights:
    """The paper's architecture with the default's head (random weights: cost does not depend on them)."""
    torch.manual_seed(0)
    net = GammaNet(head=weights.head, inputs="rgb").eval()
    card = {"input_size": weights.input_size, "seed_frames": weights.seed_frames}
    return LoadedWeights(net=net, name="rgb baseline", sha256="0" * 64, path=weights.path, card=card)


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m benchmarks model_cost")
    parser.add_argument("--frames", type=int, default=200, help="frames timed per model (median reported)")
    parser.add_argument("--weights", default=None, help="weights to time (default: the shipped one)")
    args = parser.parse_args(argv if argv is not None else [])
    torch.set_num_threads(1)  # as `colonlight enhance` runs the network
    shipped = load_weights(args.weights)
    models = {"default": shipped, BASELINE: _baseline(shipped)}
    # the network step (resize included: the model cost, as earlier measurements gave it) and the whole push
    # (the correction's table applied to the full frame as well), each on its own stream
    steps = {name: RecurrentGammaMethod(weights=w, device="cpu").stream() for name, w in models.items()}
    pushes = {name: RecurrentGammaMethod(weights=w, device="cpu").stream() for name, w in models.items()}
    rng = np.random.default_rng(0)
    base = (rng.random((HEIGHT // 8, WIDTH // 8, 3)) * 200 + 20).astype(np.uint8)
    frame = np.ascontiguousarray(np.kron(base, np.ones((8, 8, 1), np.uint8))[:HEIGHT, :WIDTH])
    step_ms: dict[str, list[float]] = {name: [] for name in models}
    push_ms: dict[str, list[float]] = {name: [] for name in models}
    for i in range(args.frames + 10):
        for name in models:
            for stream, out in ((steps[name].predict, step_ms), (pushes[name].push, push_ms)):
                start = time.perf_counter()
                stream(frame)
                if i >= 10:  # warm-up frames are not timed
                    out[name].append((time.perf_counter() - start) * 1000)
    step = {name: float(np.median(t)) for name, t in step_ms.items()}
    push = {name: float(np.median(t)) for name, t in push_ms.items()}
    rows: list[list[object]] = [
        [
            name,
            f"{step[name]:.2f}",
            f"{step[name] / step[BASELINE]:.2f}x",
            f"{push[name]:.2f}",
            f"{push[name] / push[BASELINE]:.2f}x",
            f"<= {BUDGET_MS:g} ms: {'met' if step[name] <= BUDGET_MS else 'not met'}",
        ]
        for name in models
    ]
    load = os.getloadavg()[0]
    return (
        f"## Model cost per frame: {WIDTH}x{HEIGHT} input, 1 torch thread, median of {args.frames} "
        f"(load avg {load:.1f})\n\n"
        + markdown_table(
            [
                "model",
                "network step incl. resize, ms/frame",
                "vs baseline",
                "with the correction applied, ms/frame",
                "vs baseline",
                "target (network step)",
            ],
            rows,
        )
    )


if __name__ == "__main__":
    print(main(sys.argv[1:]))
