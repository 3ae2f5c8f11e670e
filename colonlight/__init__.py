"""colonlight: consistent lighting for colonoscopy video (Zhang et al., IPMI 2021), as a streaming library.

Quick start::

    import colonlight
    method = colonlight.create_method("rnn")          # the shipped default model, CPU; build once
    for result in colonlight.enhance_frames(frames, method):   # one clip: (H, W, 3) uint8 RGB, in order
        result.frame, result.gamma                    # one result per frame, in order (held-back ones flushed)

    colonlight.enhance_clip("clip.mp4", "out/clip", method)   # frames/, gammas.json (+ enhanced.mp4)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# The public names load on first use (PEP 562): ``import colonlight`` stays light, and ``colonlight enhance`` pays
# only for what the clip needs (no torch for ``--method none``; nothing of training or evaluation).
_EXPORTS: dict[str, str] = {
    "ManifestError": "batch",
    "default_workers": "batch",
    "run_batch": "batch",
    "warm_method": "batch",
    "LoadedWeights": "checkpoint",
    "load_weights": "checkpoint",
    "save_weights": "checkpoint",
    "apply_gamma": "curves",
    "apply_lut": "curves",
    "gamma_lut": "curves",
    "resolve_device": "device",
    "CheckpointError": "errors",
    "ColonlightError": "errors",
    "DeviceError": "errors",
    "InputError": "errors",
    "OptionError": "errors",
    "PathProblem": "discovery",
    "discover": "discovery",
    "discover_clips": "discovery",
    "ClipJob": "jobs",
    "ClipOutcome": "jobs",
    "MethodSpec": "jobs",
    "estimate_frames": "jobs",
    "method_for": "jobs",
    "run_clip": "jobs",
    "FrameResult": "methods",
    "Method": "methods",
    "MethodStream": "methods",
    "available_methods": "methods",
    "create_method": "methods",
    "is_available": "methods",
    "OutputError": "outdir",
    "output_lock": "outdir",
    "GammaNet": "model",
    "ClipOptions": "pipeline",
    "ClipResult": "pipeline",
    "enhance_clip": "pipeline",
    "iter_enhanced": "pipeline",
    "read_camera": "slam_layout",
    "enhance_frames": "streaming",
    "network_threads": "tuning",
    "reuse_frame_memory": "tuning",
    "tune_for_clips": "tuning",
}

if TYPE_CHECKING:
    from .batch import ManifestError, default_workers, run_batch, warm_method
    from .checkpoint import LoadedWeights, load_weights, save_weights
    from .curves import apply_gamma, apply_lut, gamma_lut
    from .device import resolve_device
    from .discovery import PathProblem, discover, discover_clips
    from .errors import CheckpointError, ColonlightError, DeviceError, InputError, OptionError
    from .jobs import ClipJob, ClipOutcome, MethodSpec, estimate_frames, method_for, run_clip
    from .methods import FrameResult, Method, MethodStream, available_methods, create_method, is_available
    from .model import GammaNet
    from .outdir import OutputError, output_lock
    from .pipeline import ClipOptions, ClipResult, enhance_clip, iter_enhanced
    from .slam_layout import read_camera
    from .streaming import enhance_frames
    from .tuning import network_threads, reuse_frame_memory, tune_for_clips


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


__all__ = [
    "CheckpointError",
    "ClipJob",
    "ClipOptions",
    "ClipOutcome",
    "ClipResult",
    "ColonlightError",
    "DeviceError",
    "FrameResult",
    "GammaNet",
    "InputError",
    "LoadedWeights",
    "ManifestError",
    "Method",
    "MethodSpec",
    "MethodStream",
    "OptionError",
    "OutputError",
    "PathProblem",
    "__version__",
    "apply_gamma",
    "apply_lut",
    "available_methods",
    "create_method",
    "default_workers",
    "discover",
    "discover_clips",
    "enhance_clip",
    "enhance_frames",
    "estimate_frames",
    "gamma_lut",
    "is_available",
    "iter_enhanced",
    "load_weights",
    "method_for",
    "network_threads",
    "output_lock",
    "read_camera",
    "resolve_device",
    "reuse_frame_memory",
    "run_batch",
    "run_clip",
    "save_weights",
    "tune_for_clips",
    "warm_method",
]
