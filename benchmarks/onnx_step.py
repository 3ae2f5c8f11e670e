"""ONNX Runtime against torch for the network step, measured in the same run on this CPU.

The shipped model at its default input (48x48), one intra-op thread for both (as ``colonlight enhance`` runs the
step beside decoding and encoding) and ONNX Runtime's thread spinning off (``session.intra_op.allow_spinning=0``).
Two rows: the bare step (a prepared input, the state carried), and the rnn method's whole per-frame work
(``predict_a`` on a 1350x1080 frame: the reduction to 48x48, the tensor, the step) with ``--runtime torch`` and
``--runtime onnxruntime``. The two runtimes alternate in rounds, so that a change of load hits both; each
round's median ms per step (wall, and CPU time of the calling thread, where both runtimes compute with one thread)
gives a ratio onnxruntime/torch; the table shows the medians over rounds and the range of the ratios.

``python -m benchmarks onnx_step [--rounds N] [--steps N]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch

from colonlight.checkpoint import load_weights
from colonlight.methods.rnn import DEFAULT_MODEL_SIZE, RecurrentGammaMethod
from colonlight.onnx_step import cpu_session, export_model_bytes

from .common import markdown_table


def _per_step_ms(run: Callable[[], object], steps: int) -> tuple[float, float]:
    """Median wall and CPU ms of ``steps`` calls (after 20 warm-up calls). With one thread both runtimes compute
    in the calling thread, so its CPU time is the work done, whatever else the machine runs meanwhile."""
    for _ in range(20):
        run()
    wall, cpu = [], []
    for _ in range(steps):
        t0, c0 = time.perf_counter(), time.thread_time()
        run()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    return 1e3 * statistics.median(wall), 1e3 * statistics.median(cpu)


def _bare_steps(size: int) -> dict[str, Callable[[], object]]:
    weights = load_weights()
    net = weights.net.eval()
    data, sig, _ = export_model_bytes(weights, size)
    session = cpu_session(data, threads=1)
    rng = np.random.default_rng(0)
    frame = rng.random(sig.frame_shape, dtype=np.float32)
    x = torch.from_numpy(frame)
    torch_state: list[object] = [None]
    onnx_state = [sig.zero_state()]

    def torch_step() -> None:
        with torch.inference_mode():
            a, torch_state[0] = net.step(x, torch_state[0])  # type: ignore[arg-type]
        float(a.item())

    def onnx_step() -> None:
        a, *onnx_state[0] = session.run(
            None, {"frame": frame, **dict(zip(sig.state_names, onnx_state[0], strict=True))}
        )
        float(a.item())

    return {"torch": torch_step, "onnxruntime": onnx_step}


def _method_steps(size: int) -> dict[str, Callable[[], object]]:
    rng = np.random.default_rng(1)
    frame = (rng.random((1080, 1350, 3)) * 255).astype(np.uint8)
    out = {}
    for runtime in ("torch", "onnxruntime"):
        stream = RecurrentGammaMethod(model_size=size, device="cpu", runtime=runtime).stream()
        out[runtime] = lambda s=stream: s.predict_a(frame)
    return out


def measure(rounds: int, steps: int, size: int = DEFAULT_MODEL_SIZE) -> list[list[object]]:
    torch.set_num_threads(1)
    rows = []
    for label, runs in (("bare step", _bare_steps(size)), ("rnn method per frame (1350x1080 in)", _method_steps(size))):
        got: dict[str, dict[str, list[float]]] = {k: {"torch": [], "onnxruntime": []} for k in ("wall", "cpu")}
        for r in range(rounds):
            order = ["torch", "onnxruntime"] if r % 2 == 0 else ["onnxruntime", "torch"]
            for name in order:
                wall, cpu = _per_step_ms(runs[name], steps)
                got["wall"][name].append(wall)
                got["cpu"][name].append(cpu)
        row: list[object] = [label, f"{size}x{size}"]
        for kind in ("wall", "cpu"):
            ms = got[kind]
            ratios = [o / t for o, t in zip(ms["onnxruntime"], ms["torch"], strict=True)]
            row += [
                f"{statistics.median(ms['torch']):.2f}",
                f"{statistics.median(ms['onnxruntime']):.2f}",
                f"**{statistics.median(ratios):.2f}x** ({min(ratios):.2f}-{max(ratios):.2f})",
            ]
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m benchmarks onnx_step")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args(argv or [])
    load_before = os.getloadavg()[0]
    rows = measure(args.rounds, args.steps)
    load_after = os.getloadavg()[0]
    import onnxruntime

    table = markdown_table(
        [
            "what",
            "input",
            "torch wall ms",
            "onnxruntime wall ms",
            "ratio wall (range)",
            "torch CPU ms",
            "onnxruntime CPU ms",
            "ratio CPU (range)",
        ],
        rows,
    )
    return (
        f"## ONNX Runtime vs torch, one thread each, spinning off ({args.rounds} alternating rounds x {args.steps} "
        f"steps; torch {torch.__version__}, onnxruntime {onnxruntime.__version__}; load avg "
        f"{load_before:.1f}-{load_after:.1f})\n\n{table}"
    )
