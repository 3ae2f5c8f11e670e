"""One step of the recurrent gamma network as an ONNX graph, and an ONNX Runtime session that runs it.

The graph is ``net.step`` with the recurrent state made explicit: ``frame, h, c -> <head outputs>, h_out, c_out``.
Whatever ``net.step`` returns as its head (one tensor today, ``a``; a tuple or a dict of tensors for a head with
more outputs) is exported as it is, so a new head needs no change here; the outputs are named from the weights'
card (its ``outputs`` list) where it has one. Used by ``colonlight export`` (``onnx_export``) and by the rnn
method's ONNX Runtime back end (``methods/rnn_onnx``). Needs the ``export`` extra (onnx, onnxscript for torch's
exporter, onnxruntime).
"""

from __future__ import annotations

import logging
import re
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from .checkpoint import LoadedWeights
from .errors import ColonlightError, MissingExtraError
from .extras import install_command

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")

#: What the shipped network's single output means, for weights whose card does not describe its outputs.
DEFAULT_OUTPUT = {
    "name": "a",
    "meaning": "the network's raw output; the gamma applied is 1 / a (see 'gamma')",
}
#: The same for the gain-gamma head's one (1, 2) output (colonlight.correction).
GAIN_GAMMA_OUTPUT = {
    "name": "z",
    "meaning": "the network's raw outputs (z0, z1); they give a gamma and a gain (see 'gamma')",
}
#: The same for the curve head's one (1, 8) output.
CURVE_OUTPUT = {
    "name": "z",
    "meaning": "the network's raw outputs z0..z7; they give the slopes of a monotone tone curve (see 'gamma')",
}
#: Head name -> the description of its one output.
HEAD_OUTPUT = {"gamma": DEFAULT_OUTPUT, "gain-gamma": GAIN_GAMMA_OUTPUT, "curve": CURVE_OUTPUT}


class ExportError(ColonlightError):
    """The network could not be exported, or its graph does not match torch."""


def _flatten_head(head: Any) -> tuple[list[str | None], list[Tensor]]:
    """The head outputs of one ``net.step`` as a flat list, with the names a dict head gives them."""
    if isinstance(head, Tensor):
        return [None], [head]
    if isinstance(head, dict):
        return [str(k) for k in head], list(head.values())
    if isinstance(head, (tuple, list)) and all(isinstance(t, Tensor) for t in head):
        return [None] * len(head), list(head)
    raise ExportError(f"net.step returned a head of type {type(head).__name__}; expected tensors")


def _split_step(result: Any) -> tuple[Any, tuple[Tensor, ...]]:
    """``net.step``'s result as ``(head, state)``: the state is its last element, the head everything before."""
    if not isinstance(result, tuple) or len(result) < 2:
        raise ExportError("net.step must return (outputs..., state)")
    head = result[0] if len(result) == 2 else tuple(result[:-1])
    state = result[-1]
    if not isinstance(state, (tuple, list)) or not all(isinstance(t, Tensor) for t in state):
        raise ExportError("net.step's state must be a tuple of tensors")
    return head, tuple(state)


class StepGraph(nn.Module):
    """``net.step`` with the state as separate tensors in and out: ``(frame, *state) -> (*head, *new_state)``."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net: Any = net  # any network with a ``step`` (not only GammaNet's signature)

    def forward(self, frame: Tensor, *state: Tensor) -> tuple[Tensor, ...]:
        head, new_state = _split_step(self.net.step(frame, tuple(state)))
        return (*_flatten_head(head)[1], *new_state)


@dataclass(frozen=True)
class StepSignature:
    """Names and shapes of the step's inputs and outputs at one input size."""

    size: int
    frame_shape: tuple[int, ...]
    state_names: tuple[str, ...]
    state_shapes: tuple[tuple[int, ...], ...]
    head_names: tuple[str, ...]
    head_shapes: tuple[tuple[int, ...], ...]

    @property
    def input_names(self) -> list[str]:
        return ["frame", *self.state_names]

    @property
    def output_names(self) -> list[str]:
        return [*self.head_names, *(f"{n}_out" for n in self.state_names)]

    def zero_state(self) -> list[np.ndarray]:
        return [np.zeros(s, dtype=np.float32) for s in self.state_shapes]


def _card_outputs(card: dict[str, Any]) -> list[dict[str, Any]]:
    """The card's description of the head outputs: a list of names or of ``{"name": ..., ...}``."""
    outputs = card.get("outputs")
    if not isinstance(outputs, list):
        return []
    described = []
    for item in outputs:
        entry = {"name": item} if isinstance(item, str) else dict(item) if isinstance(item, dict) else {}
        described.append(entry)
    return described


def describe_outputs(
    card: dict[str, Any], dict_names: Sequence[str | None], head: str | None = None
) -> list[dict[str, Any]]:
    """One description per head output: from the card when it lists as many valid names, else from the
    network's head (``gamma``: ``a``; ``gain-gamma`` and ``curve``: ``z``), else generic names."""
    n = len(dict_names)
    from_card = _card_outputs(card)
    if len(from_card) == n and all(_NAME.match(str(d.get("name", ""))) for d in from_card):
        return from_card
    if all(name is not None and _NAME.match(name) for name in dict_names):
        return [{"name": name, "meaning": "not described by the weights' card"} for name in dict_names]
    if n == 1:
        return [dict(HEAD_OUTPUT.get(head or "gamma", DEFAULT_OUTPUT))]
    return [{"name": f"out{i}", "meaning": "not described by the weights' card"} for i in range(n)]


def step_signature(weights: LoadedWeights, size: int) -> tuple[StepSignature, list[dict[str, Any]]]:
    """Run one step on a zero frame from the zero state to learn the state's and the head's shapes."""
    net: Any = weights.net.eval()  # any network with a ``step``: its state's length is learnt here
    frame = torch.zeros(1, 3, size, size)
    with torch.inference_mode():
        _, state = _split_step(net.step(frame, None))
        head, _ = _split_step(net.step(frame, state))
    dict_names, tensors = _flatten_head(head)
    described = describe_outputs(weights.card, dict_names, getattr(net, "head", None))
    # the network names its state where it says (GammaNet does); else h and c for two tensors, as a ConvLSTM's
    declared = tuple(getattr(net, "state_names", ("h", "c")))
    state_names = declared if len(declared) == len(state) else tuple(f"state{i}" for i in range(len(state)))
    sig = StepSignature(
        size=size,
        frame_shape=(1, 3, size, size),
        state_names=state_names,
        state_shapes=tuple(tuple(t.shape) for t in state),
        head_names=tuple(str(d["name"]) for d in described),
        head_shapes=tuple(tuple(t.shape) for t in tensors),
    )
    if len(set(sig.input_names + sig.output_names)) != len(sig.input_names) + len(sig.output_names):
        raise ExportError(f"output names {sig.head_names} clash with the inputs {sig.input_names}")
    return sig, described


@contextmanager
def _quiet_exporter() -> Iterator[None]:
    """torch's exporter logs each stage and warns about absent optional operators (torchvision): not the user's
    concern. Kept quiet for the duration of one export."""
    loggers = [logging.getLogger(n) for n in ("torch.onnx", "torch.export", "torch._dynamo", "onnxscript")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def export_model_bytes(weights: LoadedWeights, size: int) -> tuple[bytes, StepSignature, list[dict[str, Any]]]:
    """The ONNX graph of one step at ``size x size`` input, as bytes (weights inside), with its signature."""
    try:
        import onnx  # noqa: F401 - torch's exporter needs it
        import onnxscript  # noqa: F401
    except ImportError as exc:
        raise MissingExtraError(f"ONNX export needs the export extra: {install_command('export')} ({exc})") from None
    sig, described = step_signature(weights, size)
    graph = StepGraph(weights.net.cpu().eval()).eval()
    example = (torch.zeros(sig.frame_shape), *(torch.zeros(s) for s in sig.state_shapes))
    try:
        with _quiet_exporter():
            program = torch.onnx.export(
                graph,
                example,
                input_names=sig.input_names,
                output_names=sig.output_names,
                dynamo=True,
                external_data=False,
                verbose=False,
            )
    except Exception as exc:  # noqa: BLE001 - torch's exporter raises many kinds; the user gets one line
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ExportError(f"{weights.path}: torch could not export the network to ONNX ({first[:200]})") from exc
    if program is None:  # pragma: no cover - torch returns the program for dynamo=True
        raise ExportError("torch.onnx.export returned no program")
    return program.model_proto.SerializeToString(), sig, described


def cpu_session(model: bytes | str | Path, threads: int = 1) -> Any:
    """An ONNX Runtime CPU session as colonlight runs the step: ``threads`` intra-op threads, one inter-op thread,
    sequential execution and no spinning (a spinning idle thread would take the core decoding and encoding need)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.add_session_config_entry("session.inter_op.allow_spinning", "0")
    so.log_severity_level = 3
    return ort.InferenceSession(
        model if isinstance(model, bytes) else str(model), so, providers=["CPUExecutionProvider"]
    )


def compare_with_torch(weights: LoadedWeights, session: Any, sig: StepSignature, frames: Sequence[np.ndarray]) -> float:
    """Run torch and the ONNX session side by side over ``frames`` (each ``(1, 3, S, S)`` float32 in [0, 1]),
    each carrying its own state from zero; return the largest absolute difference in any head output."""
    net: Any = weights.net.cpu().eval()
    state: tuple[Tensor, ...] | None = None
    onnx_state = sig.zero_state()
    worst = 0.0
    n_head = len(sig.head_names)
    for frame in frames:
        with torch.inference_mode():
            head, state = _split_step(net.step(torch.from_numpy(frame), state))
        torch_out = [t.numpy() for t in _flatten_head(head)[1]]
        outs = session.run(None, {"frame": frame, **dict(zip(sig.state_names, onnx_state, strict=True))})
        onnx_state = list(outs[n_head:])
        for ours, theirs in zip(torch_out, outs[:n_head], strict=True):
            worst = max(worst, float(np.max(np.abs(ours.astype(np.float64) - theirs.astype(np.float64)))))
    return worst
