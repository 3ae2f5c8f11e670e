"""The rnn method's network step on ONNX Runtime (``--runtime onnxruntime``), as a drop-in for ``net.step``.

Measured faster than torch for the step on small CPUs (``python -m benchmarks onnx_step``; README, "Benchmarks").
The graph is the one ``colonlight export`` writes (``onnx_step``), made from the loaded weights and kept in a
cache folder keyed by the weights' sha256, the input size and the torch and colonlight versions, because torch's
exporter takes seconds; every new graph is checked against torch before it is used. One intra-op thread, no
spinning: the step must not take the cores that decoding and encoding use. CPU only.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import __version__
from ..atomic import write_bytes_atomic
from ..checkpoint import LoadedWeights
from ..errors import MissingExtraError, OptionError
from ..extras import install_command
from ..onnx_step import ExportError, StepSignature, compare_with_torch, cpu_session, export_model_bytes, step_signature

RUNTIMES = ("torch", "onnxruntime")
#: Largest |torch - ONNX Runtime| in ``a`` accepted when a new graph is checked.
CHECK_TOLERANCE = 1e-5

StepFn = Callable[[torch.Tensor, Any], tuple[Any, Any]]


def cache_dir() -> Path:
    """``$COLONLIGHT_CACHE_DIR``, else ``$XDG_CACHE_HOME/colonlight``, else ``~/.cache/colonlight``; plus ``onnx``."""
    root = (
        os.environ.get("COLONLIGHT_CACHE_DIR")
        or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "colonlight"
    )
    return Path(root) / "onnx"


def cached_graph_path(weights: LoadedWeights, size: int) -> Path:
    """Where the step graph for these weights and size is kept."""
    tag = f"{weights.sha256[:16]}-{size}px-colonlight{__version__}-torch{torch.__version__}".replace("+", "_")
    return cache_dir() / f"{tag}.onnx"


def _session(weights: LoadedWeights, size: int) -> Any:
    """An ONNX Runtime session for the step: from the cached graph, else (absent or unreadable) a new one."""
    try:
        return cpu_session(cached_graph_path(weights, size).read_bytes())
    except Exception:  # noqa: BLE001 - absent, or damaged by something else: export again
        return cpu_session(_new_graph(weights, size))


def _new_graph(weights: LoadedWeights, size: int) -> bytes:
    """Export the step graph, check it against torch and cache it."""
    path = cached_graph_path(weights, size)
    data, sig, _ = export_model_bytes(weights, size)
    rng = np.random.default_rng(0)
    frames = [rng.random(sig.frame_shape, dtype=np.float32) * (0.3 + 0.1 * i) for i in range(6)]
    worst = compare_with_torch(weights, cpu_session(data), sig, frames)
    if not worst <= CHECK_TOLERANCE:
        raise ExportError(f"{weights.path}: ONNX Runtime differs from torch by {worst:.3g}; use --runtime torch")
    with contextlib.suppress(OSError):  # a read-only home: run from memory, export again next time
        write_bytes_atomic(path, data)
    return data


class OnnxStep:
    """Called like ``GammaNet.step``: ``(frame (1, 3, S, S) CPU tensor, state or None) -> (out, state)``; ``out``
    is the head's array (``a`` ``(1,)``, or ``z`` ``(1, 2)``), the state an opaque tuple of arrays to hand back
    with the next frame."""

    def __init__(self, weights: LoadedWeights, size: int) -> None:
        self.signature: StepSignature = step_signature(weights, size)[0]
        if len(self.signature.head_names) != 1:
            raise OptionError(
                f"--runtime onnxruntime runs networks with one output tensor; these weights have "
                f"{', '.join(self.signature.head_names)}"
            )
        self.session = _session(weights, size)

    def __call__(self, frame: torch.Tensor, state: Any) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        sig = self.signature
        feeds = dict(zip(sig.state_names, state if state is not None else sig.zero_state(), strict=True))
        a, *new_state = self.session.run(None, {"frame": frame.numpy(), **feeds})
        return a, tuple(new_state)


def make_step(weights: LoadedWeights, size: int | None, device: torch.device, runtime: str = "torch") -> StepFn:
    """The step function the rnn method calls per frame: the network's own (``torch``) or ONNX Runtime's."""
    if runtime == "torch":
        return weights.net.step
    if runtime != "onnxruntime":
        raise OptionError(f"unknown runtime {runtime!r}; choose {' or '.join(RUNTIMES)}")
    if size is None:
        raise OptionError("--runtime onnxruntime needs a fixed network input size (not --model-size full)")
    if device.type != "cpu":
        raise OptionError(f"--runtime onnxruntime runs on the CPU, not {device} (use --device cpu)")
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        raise MissingExtraError(f"--runtime onnxruntime needs the export extra: {install_command('export')}") from None
    return OnnxStep(weights, size)
