"""The model's cost per frame as the CLI runs it: one torch thread, a 1350x1080 frame resized to the network's
input, the network step and the correction's table applied; the issue's budget is 5 ms per frame on 2 cores.

Reported: the network step with the resize (the model's cost, the budget's subject, as earlier runs gave it) and
the whole ``push`` (the correction's table applied to the full frame too). Side by side in one run, frames
interleaved so that a noisy shared machine slows both alike: the shipped default against the paper's architecture
(``rgb`` input, the same head, the same size: the baseline), so the ratio says what the default's own input costs
beyond the network every model shares.

A second table times the resize to the network's input (``network_input``) against the rule it replaced in
session 15 (a Gaussian pyramid, then an area average: the baseline) and one exact area average of the whole frame,
and says how far each moves the default's correction (the table it applies, and its gamma) from that exact
average's, over frames of one held-out clip rendered at the full size (cached between runs).

Run: ``python -m benchmarks model_cost [--frames 200] [--weights W]``.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import os
import sys
import time
from collections.abc import Callable, Hashable
from functools import partial
from typing import Any, TypeVar

import cv2
import numpy as np
import torch

from colonlight.checkpoint import LoadedWeights, load_weights
from colonlight.limits import DEFAULT_MODEL_SIZE
from colonlight.methods.rnn import PRESAMPLE, RecurrentGammaMethod, head_correction, network_input, to_tensor
from colonlight.model import GammaNet

from .common import clip_cache, markdown_table

K = TypeVar("K", bound=Hashable)

WIDTH, HEIGHT = 1350, 1080
BUDGET_MS = 5.0
BASELINE = "baseline: rgb input, same head and size"
PREVIOUS = "default as session 14 ran it (pyramid resize, contiguous weights)"
ONNX = "default, --runtime onnxruntime (one intra-op thread)"
RESIZE_BASELINE = "baseline: Gaussian pyramid, then area (before session 15)"
RESIZE_CLIP_SEED, RESIZE_CLIP_FRAMES = 810000, 12  # a held-out-family clip, rendered at WIDTH x HEIGHT


def _pyramid_then_area(frame: np.ndarray, size: int) -> np.ndarray:
    """The rule before session 15: halved with ``cv2.pyrDown`` while the shorter side is >= 4x the target."""
    while min(frame.shape[:2]) >= 4 * size:
        frame = cv2.pyrDown(frame)
    return cv2.resize(frame, (size, size), interpolation=cv2.INTER_AREA)


def _one_area_average(frame: np.ndarray, size: int) -> np.ndarray:
    return cv2.resize(frame, (size, size), interpolation=cv2.INTER_AREA)


RESIZES: dict[str, Callable[[np.ndarray, int], np.ndarray]] = {
    f"shipped: bilinear to {PRESAMPLE}x the size, then area": network_input,
    RESIZE_BASELINE: _pyramid_then_area,
    "one area average of the whole frame (the reference)": _one_area_average,
}


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
    cv2.setNumThreads(1)  # the resize alone, as `colonlight enhance` runs it beside decoding
    shipped = load_weights(args.weights)
    rng = np.random.default_rng(0)
    base = (rng.random((HEIGHT // 8, WIDTH // 8, 3)) * 200 + 20).astype(np.uint8)
    frame = np.ascontiguousarray(np.kron(base, np.ones((8, 8, 1), np.uint8))[:HEIGHT, :WIDTH])
    load = os.getloadavg()[0]
    return _cost_table(shipped, frame, args.frames, load) + "\n\n" + _resize_table(shipped, frame, args.frames, load)


def _previous_step(weights: LoadedWeights) -> Callable[[np.ndarray], object]:
    """The default's step as session 14 ran it: the Gaussian-pyramid resize and contiguous (NCHW) weights."""
    net = copy.deepcopy(weights.net).eval()
    for param in net.parameters():  # undo the channels-last layout load_weights' method gives: NCHW, as then
        if param.ndim == 4:
            param.data = param.data.contiguous()
    size = weights.input_size or DEFAULT_MODEL_SIZE
    state: list[Any] = [None]

    def predict(frame: np.ndarray) -> object:
        with torch.inference_mode():
            out, state[0] = net.step(to_tensor(_pyramid_then_area(frame, size), torch.device("cpu")), state[0])
        return out

    return predict


def _interleaved_ms(calls: dict[K, Callable[[], object]], frames: int, warmup: int = 10) -> dict[K, float]:
    """Median ms of each call over ``frames`` rounds, every round calling each once in order (so a busy moment
    of a shared machine falls on all of them alike), after ``warmup`` untimed rounds."""
    times: dict[K, list[float]] = {key: [] for key in calls}
    for i in range(warmup + frames):
        for key, call in calls.items():
            start = time.perf_counter()
            call()
            if i >= warmup:
                times[key].append((time.perf_counter() - start) * 1000)
    return {key: float(np.median(t)) for key, t in times.items()}


def _cost_table(shipped: LoadedWeights, frame: np.ndarray, frames: int, load: float) -> str:
    """The network step (resize included: the model cost, as earlier measurements gave it) and the whole push
    (the correction's table applied to the full frame as well), each on its own stream, models interleaved; and
    the default's step as session 14 ran it (step only)."""
    models = {"default": shipped, BASELINE: _baseline(shipped)}
    methods = {name: RecurrentGammaMethod(weights=w, device="cpu") for name, w in models.items()}
    if importlib.util.find_spec("onnxruntime") and importlib.util.find_spec("onnxscript"):  # the export extra
        methods[ONNX] = RecurrentGammaMethod(weights=shipped, device="cpu", runtime="onnxruntime")
    steps: dict[str, Callable[[np.ndarray], object]] = {name: m.stream().predict for name, m in methods.items()}
    steps[PREVIOUS] = _previous_step(shipped)
    pushes = {name: m.stream().push for name, m in methods.items()}
    calls: dict[tuple[str, str], Callable[[], object]] = {}
    for name in steps:  # each model's step, then its push: one model's runs side by side in every round
        calls[("step", name)] = partial(steps[name], frame)
        if name in pushes:
            calls[("push", name)] = partial(pushes[name], frame)
    ms = _interleaved_ms(calls, frames)
    step = {name: t for (kind, name), t in ms.items() if kind == "step"}
    push = {name: t for (kind, name), t in ms.items() if kind == "push"}
    rows: list[list[object]] = [
        [
            name,
            f"{step[name]:.2f}",
            f"{step[name] / step[BASELINE]:.2f}x",
            f"{push[name]:.2f}" if name in push else "-",
            f"{push[name] / push[BASELINE]:.2f}x" if name in push else "-",
            f"<= {BUDGET_MS:g} ms: {'met' if step[name] <= BUDGET_MS else 'not met'}",
        ]
        for name in steps
    ]
    return (
        f"## Model cost per frame: {WIDTH}x{HEIGHT} input, 1 torch thread, median of {frames} "
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


def _hd_clip() -> list[np.ndarray]:
    """Frames of one held-out-family clip rendered at the full size (the resize's subject: real texture, noise)."""
    from colonlight.synth import SynthConfig, generate_clip

    def render() -> list[np.ndarray]:
        cfg = SynthConfig.sample(
            np.random.default_rng(RESIZE_CLIP_SEED),
            split="heldout",
            width=WIDTH,
            height=HEIGHT,
            n_frames=RESIZE_CLIP_FRAMES,
        )
        return [f.image for f in generate_clip(cfg, seed=RESIZE_CLIP_SEED)]

    return clip_cache(f"model-cost-{RESIZE_CLIP_SEED}-{WIDTH}x{HEIGHT}-{RESIZE_CLIP_FRAMES}", render)


def _corrections(weights: LoadedWeights, inputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(tables (N, 256), gammas (N,))`` the network's head gives over ``inputs`` (already at its size), state
    carried, by the stream's own rule (``head_correction``): any head compares as the table it applies."""
    state = None
    luts, gammas = [], []
    with torch.inference_mode():
        for x in inputs:
            z, state = weights.net.step(to_tensor(x, torch.device("cpu")), state)
            correction = head_correction(weights.head, z.reshape(-1).tolist())
            luts.append(correction.table)
            gammas.append(correction.gamma)
    return np.array(luts, dtype=float), np.array(gammas)


def _resize_table(shipped: LoadedWeights, frame: np.ndarray, frames: int, load: float) -> str:
    """Each resize rule's time (interleaved, medians) and how far it moves the default's corrections."""
    size = shipped.input_size or DEFAULT_MODEL_SIZE
    ms = _interleaved_ms({name: partial(rule, frame, size) for name, rule in RESIZES.items()}, frames)
    clip = _hd_clip()
    small = {name: [rule(f, size) for f in clip] for name, rule in RESIZES.items()}
    reference = list(RESIZES)[-1]
    ref_luts, ref_gammas = _corrections(shipped, small[reference])
    rows: list[list[object]] = []
    for name in RESIZES:
        levels = np.mean(
            [np.abs(a.astype(float) - b).mean() for a, b in zip(small[name], small[reference], strict=True)]
        )
        luts, gammas = _corrections(shipped, small[name])
        moved = [f"{np.abs(luts - ref_luts).max():.0f}", f"{np.abs(gammas - ref_gammas).max():.4f}"]
        rows.append([name, f"{ms[name]:.2f}", f"{ms[name] / ms[RESIZE_BASELINE]:.2f}x", f"{levels:.2f}", *moved])
    return (
        f"## Resize to the network's {size}x{size} input from {WIDTH}x{HEIGHT}: median of {frames} "
        f"(load avg {load:.1f}); accuracy over {len(clip)} frames of held-out clip {RESIZE_CLIP_SEED}\n\n"
        + markdown_table(
            [
                "resize",
                "ms/frame",
                "vs baseline",
                "mean |input - reference|, 8-bit levels",
                f"max |{shipped.head} table - reference's|, levels",
                "max |gamma - reference's|",
            ],
            rows,
        )
    )


if __name__ == "__main__":
    print(main(sys.argv[1:]))
