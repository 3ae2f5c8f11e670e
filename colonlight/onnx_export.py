"""``colonlight export``'s engine: the step graph written as ``MODEL.onnx`` with a JSON sidecar, for hosts without
Python (a C++ SLAM system).

The sidecar (``MODEL.onnx.json``) says everything a host needs around the graph: the input size and normalisation,
the initial state, the seed frames, the gamma range and clamping rule, how to build and apply the lookup table,
the outputs (from the weights' card where it describes them), and which model (name, sha256) and colonlight made
it. Every export is checked against torch with ONNX Runtime before anything is written.
"""

from __future__ import annotations

import hashlib
import platform
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from . import __version__
from .atomic import (
    files_written_together,
    parent_problem,
    read_json,
    remove_stale_temporaries_of,
    write_bytes_atomic,
    write_json_atomic,
)
from .checkpoint import LoadedWeights, card_path
from .correction import CURVE_KNOTS, CURVE_SLOPE_MAX, LOG_GAIN_SPAN, LOG_GAMMA_SPAN, SLOPE_OFFSET
from .methods.rnn import CURVE_SUMMARY_AT, GAIN_MAX, GAIN_MIN, GAMMA_MAX, GAMMA_MIN, PRESAMPLE, SEED_FRAMES
from .onnx_step import ExportError, StepSignature, compare_with_torch, cpu_session, export_model_bytes
from .scene_cut import default_threshold
from .scene_cut import host_rule as scene_cut_rule
from .tone_match import default_weight, host_rule

SIDECAR_FORMAT = "colonlight-onnx-step"
SIDECAR_VERSION = 1
#: Largest |torch - ONNX Runtime| allowed in any head output by the check that follows every export.
EXPORT_TOLERANCE = 1e-5
_CHECK_FRAMES = 8


def onnx_sidecar_path(onnx_path: Path) -> Path:
    """The sidecar beside ``model.onnx``: ``model.onnx.json`` (never ``model.json``, a weights card's name)."""
    onnx_path = Path(onnx_path)
    return onnx_path.with_name(onnx_path.name + ".json")


def _check_frames(size: int, n: int = _CHECK_FRAMES, seed: int = 0) -> list[np.ndarray]:
    """Smooth random frames with a brightness ramp: enough to exercise every layer and the recurrence."""
    rng = np.random.default_rng(seed)
    base = rng.random((1, 3, size, size), dtype=np.float32)
    return [np.clip(base * (0.3 + 0.6 * i / max(1, n - 1)), 0, 1).astype(np.float32) for i in range(n)]


def sidecar_record(
    weights: LoadedWeights,
    sig: StepSignature,
    described: list[dict[str, Any]],
    onnx_file: str,
    onnx_sha256: str,
    opset: int,
    check_max_diff: float | None,
) -> dict[str, Any]:
    """Everything a host needs around the graph (see the README's "C++ SLAM host" section)."""
    card = weights.card
    seeds = weights.seed_frames if weights.seed_frames is not None else SEED_FRAMES
    head = getattr(weights.net, "head", "gamma") if sig.head_names == ("z",) else "gamma"
    outputs = [
        {**d, "shape": list(shape), "dtype": "float32"} for d, shape in zip(described, sig.head_shapes, strict=True)
    ] + [
        {
            "name": f"{n}_out",
            "shape": list(s),
            "dtype": "float32",
            "meaning": f"the new state: feed it as '{n}' with the next frame",
        }
        for n, s in zip(sig.state_names, sig.state_shapes, strict=True)
    ]
    return {
        "format": SIDECAR_FORMAT,
        "format_version": SIDECAR_VERSION,
        "onnx": {"file": onnx_file, "sha256": onnx_sha256, "opset": opset},
        "model": {
            "name": weights.name,
            "sha256": weights.sha256,
            "file": weights.path.name,
            "version": card.get("version"),
            "trained_input_size": card.get("input_size"),
        },
        "colonlight_version": __version__,
        "exported_with": {"torch": torch.__version__, "python": platform.python_version()},
        "input_size": sig.size,
        "inputs": [
            {
                "name": "frame",
                "shape": list(sig.frame_shape),
                "dtype": "float32",
                "layout": "NCHW, channels R, G, B",
                "normalisation": "value / 255: uint8 0..255 -> float 0..1; no mean or std",
                "resize": f"the full frame reduced to {sig.size}x{sig.size}: if its shorter side is over "
                f"{PRESAMPLE * sig.size}, first resampled to {PRESAMPLE * sig.size}x{PRESAMPLE * sig.size} "
                "(cv::resize, INTER_LINEAR), then area-averaged (cv::resize, INTER_AREA); the aspect ratio is "
                "not kept",
                "presample": PRESAMPLE,
            },
            *(
                {
                    "name": n,
                    "shape": list(s),
                    "dtype": "float32",
                    "initial": "zeros at the start of every clip or stream, then the previous step's output",
                }
                for n, s in zip(sig.state_names, sig.state_shapes, strict=True)
            ),
        ],
        "outputs": outputs,
        "seed_frames": {
            "count": seeds,
            "rule": f"the first {seeds} frames of a clip run the step (they build the state) but are passed "
            "through unchanged (gamma 1.0)",
        },
        "gamma": card.get("gamma") or _default_gamma_rule(sig, head),
        "lut": {
            "build": f"lut[v] = round(255 * {LUT_FORMULA[head].entry}) for v = 0..255, in double precision, "
            "rounding half to even (std::nearbyint in the default rounding mode), as uint8",
            "apply": "out = lut[in] for every sample of every channel of the full-resolution uint8 frame "
            f"(cv::LUT); that is {LUT_FORMULA[head].values} on [0, 1] values",
        },
        "correction": correction_parameters(head) if sig.head_names in (("a",), ("z",)) else None,
        # colonlight's own models pull each output frame's tones toward the last one's (colonlight.tone_match)
        "tone_match": host_rule(default_weight(head)),
        # and start afresh at a cut to another scene (colonlight.scene_cut), before the network's step
        "scene_cut": scene_cut_rule(default_threshold(head)),
        # what the network reads of the frame: the graph's input is RGB either way (an rgb-log network computes
        # its log channels inside the graph), so a host needs this only to know which model it runs
        "network_inputs": getattr(weights.net, "inputs", "rgb"),
        "check": {
            "onnxruntime_vs_torch_max_abs_diff": check_max_diff,
            "tolerance": EXPORT_TOLERANCE,
            "frames": _CHECK_FRAMES,
        },
    }


@dataclass(frozen=True)
class LutFormula:
    """One head's correction in the sidecar's words: a table entry for level ``v``, and the same on values."""

    entry: str
    values: str


#: Head -> its table entry and what applying the table does (the sidecar's ``lut.build`` and ``lut.apply``).
LUT_FORMULA = {
    "gamma": LutFormula("(v / 255) ^ gamma", "out = in ^ gamma (gamma < 1 brightens)"),
    "gain-gamma": LutFormula("min(1, gain * (v / 255) ^ gamma)", "out = min(1, gain * in ^ gamma)"),
    "curve": LutFormula("min(1, f(v / 255)), f the curve of 'gamma'", "out = min(1, f(in)), f the curve of 'gamma'"),
}


def correction_parameters(head: str) -> dict[str, Any]:
    """The numbers of the head's correction rule (``gamma``'s formula) as values, for a host that reads them
    instead of parsing text (``examples/cpp_host``)."""
    record: dict[str, Any] = {"head": head, "gamma_range": [GAMMA_MIN, GAMMA_MAX]}
    if head == "gain-gamma":
        record.update(log_gamma_span=LOG_GAMMA_SPAN, log_gain_span=LOG_GAIN_SPAN, gain_range=[GAIN_MIN, GAIN_MAX])
    elif head == "curve":
        record.update(
            knots=list(CURVE_KNOTS),
            slope_offset=SLOPE_OFFSET,
            slope_max=CURVE_SLOPE_MAX,
            summary_at=CURVE_SUMMARY_AT,
        )
    return record


def _default_gamma_rule(sig: StepSignature, head: str) -> dict[str, Any]:
    """How colonlight turns the output into the correction it applies (``methods/rnn.clamp_gamma``,
    ``clamp_gain_gamma`` and ``curve_correction``; ``correction.gain_gamma_values`` and ``curve_values``)."""
    if head == "curve":
        return {
            "from_output": "z",
            "knots": list(CURVE_KNOTS),
            "formula": f"slope[k] = min({CURVE_SLOPE_MAX}, log(1 + exp(z[k] + {SLOPE_OFFSET!r}))) for k = 0..7; "
            "y[0] = 0, y[k+1] = y[k] + slope[k] * (knots[k+1] - knots[k]); f is the piecewise-linear curve "
            "through (knots[k], y[k]); out = min(1, f(in)) on [0, 1] values",
            "clamping": "z not finite -> the frame unchanged",
            "summary_gamma": f"the 'gamma' colonlight records is log f({CURVE_SUMMARY_AT}) / log {CURVE_SUMMARY_AT}, "
            f"kept in [{GAMMA_MIN}, {GAMMA_MAX}]: a summary, the curve is what is applied",
        }
    if head == "gain-gamma":
        return {
            "from_output": "z",
            "formula": f"gamma = exp({LOG_GAMMA_SPAN} * tanh(z[0])), gain = exp({LOG_GAIN_SPAN} * tanh(z[1])); "
            "out = min(1, gain * in ^ gamma) on [0, 1] values",
            "range": [GAMMA_MIN, GAMMA_MAX],
            "gain_range": [GAIN_MIN, GAIN_MAX],
            "clamping": "gamma and gain are each clamped into their range; z not finite -> gain 1, gamma 1, frame "
            "unchanged",
        }
    if "a" not in sig.head_names:
        return {"note": "the weights' card does not say how these outputs become a correction (its 'gamma' entry)"}
    return {
        "from_output": "a",
        "formula": "gamma = 1 / a",
        "range": [GAMMA_MIN, GAMMA_MAX],
        "clamping": f"gamma below {GAMMA_MIN} becomes {GAMMA_MIN}, above {GAMMA_MAX} becomes {GAMMA_MAX}; "
        "a not finite or a <= 0 (the ReLU's floor: no usable answer) -> gamma 1.0, frame unchanged",
    }


def _check_targets(weights: LoadedWeights, out: Path) -> None:
    """ExportError before anything is written if ``out`` or its sidecar would replace a checkpoint: the weights
    exported, their card, or the card of any ``.safetensors`` beside (``-o wd/colonlight-rnn`` has the sidecar
    ``wd/colonlight-rnn.json``, the card of ``wd/colonlight-rnn.safetensors``: the weights could not be loaded
    after). Nor may either be a folder: the graph would be written without its sidecar; nor a device, FIFO or
    socket (``-o /dev/null``): the atomic rename would replace the node itself with a regular file."""
    protected = [weights.path, card_path(weights.path)]
    blocked = parent_problem(out)
    if blocked:  # before: mkdir's bare "File exists", after the graph was built and checked
        raise ExportError(f"{out}: {blocked}")
    if not out.name or out.name == ".." or out.is_dir():  # first: ``-o ""`` is ".", which has no sidecar name
        raise ExportError(f"{out}: a folder is in the way of the export")
    for target in (out, onnx_sidecar_path(out)):
        if target.is_dir():
            raise ExportError(f"{target}: a folder is in the way of the export")
        if target.exists() and not target.is_file():
            raise ExportError(
                f"{target}: not a regular file (a device, FIFO or socket); the export writes files: give another -o"
            )
        if any(p.exists() and target.exists() and target.samefile(p) for p in protected):
            raise ExportError(
                f"{target}: would overwrite the checkpoint being exported or its card ({weights.path}); give another -o"
            )
        if target.suffix == ".json" and target.with_suffix(".safetensors").is_file():
            raise ExportError(
                f"{target}: would overwrite the model card of {target.with_suffix('.safetensors')}; give another -o"
            )


def export_onnx(weights: LoadedWeights, out: Path, size: int, check: bool = True) -> dict[str, Any]:
    """Write ``out`` (the step graph, weights inside) and its sidecar ``out.json``, both atomically.

    With ``check`` (and onnxruntime installed) the graph is run against torch first; a difference above
    ``EXPORT_TOLERANCE`` raises :class:`ExportError` and nothing is written. Returns the sidecar record.
    """
    out = Path(out)
    if size < 8:
        raise ExportError(f"input size must be at least 8 pixels, got {size}")
    _check_targets(weights, out)
    data, sig, described = export_model_bytes(weights, size)
    import onnx

    opset = next((o.version for o in onnx.load_from_string(data).opset_import if o.domain in ("", "ai.onnx")), 0)
    worst: float | None = None
    if check:
        try:
            session = cpu_session(data)
        except ImportError:
            session = None
        if session is not None:
            worst = compare_with_torch(weights, session, sig, _check_frames(size))
            if not worst <= EXPORT_TOLERANCE:
                raise ExportError(f"{out}: ONNX Runtime differs from torch by {worst:.3g} (> {EXPORT_TOLERANCE})")
    record = sidecar_record(weights, sig, described, out.name, hashlib.sha256(data).hexdigest(), opset, worst)
    out.parent.mkdir(parents=True, exist_ok=True)
    with files_written_together(out.parent):  # the graph and its sidecar are one export's, whoever else exports
        # an export killed while writing left its temporaries beside ``out``: only theirs go, the folder is the user's
        remove_stale_temporaries_of(out)
        remove_stale_temporaries_of(onnx_sidecar_path(out))
        write_bytes_atomic(out, data)
        write_json_atomic(onnx_sidecar_path(out), record)
    return record


def read_sidecar(onnx_path: Path) -> dict[str, Any]:
    """The sidecar of an exported graph (``ExportError`` naming the file if absent or unreadable)."""
    path = onnx_sidecar_path(onnx_path)
    try:
        record: dict[str, Any] = read_json(path)
    except (OSError, ValueError) as exc:
        raise ExportError(f"{path}: no readable sidecar ({exc})") from None
    return record
