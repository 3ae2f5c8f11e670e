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
    "FrameResult": "methods",
    "Method": "methods",
    "MethodStream": "methods",
    "available_methods": "methods",
    "create_method": "methods",
    "GammaNet": "model",
    "ClipOptions": "pipeline",
    "ClipResult": "pipeline",
    "enhance_clip": "pipeline",
    "iter_enhanced": "pipeline",
    "enhance_frames": "streaming",
}

if TYPE_CHECKING:
    from .checkpoint import LoadedWeights, load_weights, save_weights
    from .curves import apply_gamma, apply_lut, gamma_lut
    from .device import resolve_device
    from .errors import CheckpointError, ColonlightError, DeviceError, InputError
    from .methods import FrameResult, Method, MethodStream, available_methods, create_method
    from .model import GammaNet
    from .pipeline import ClipOptions, ClipResult, enhance_clip, iter_enhanced
    from .streaming import enhance_frames


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
    "ClipOptions",
    "ClipResult",
    "ColonlightError",
    "DeviceError",
    "FrameResult",
    "GammaNet",
    "InputError",
    "LoadedWeights",
    "Method",
    "MethodStream",
    "__version__",
    "apply_gamma",
    "apply_lut",
    "available_methods",
    "create_method",
    "enhance_clip",
    "enhance_frames",
    "gamma_lut",
    "iter_enhanced",
    "load_weights",
    "resolve_device",
    "save_weights",
]
