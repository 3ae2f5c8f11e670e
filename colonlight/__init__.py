"""colonlight: consistent lighting for colonoscopy video (Zhang et al., IPMI 2021), as a streaming library.

Quick start::

    import colonlight
    method = colonlight.create_method("rnn")          # the shipped default model, CPU
    stream = method.stream()                          # one per clip: carries the recurrent state
    for frame in frames:                              # (H, W, 3) uint8 RGB, in order
        for result in stream.push(frame):
            result.frame, result.gamma                # enhanced frame, gamma applied (1.0 for the 2 seeds)

    colonlight.enhance_clip("clip.mp4", "out/clip", method)   # frames/, gammas.json (+ enhanced.mp4)
"""

from __future__ import annotations

__version__ = "0.1.0"

from .checkpoint import LoadedWeights, load_weights, save_weights
from .curves import apply_gamma, apply_lut, gamma_lut
from .device import resolve_device
from .errors import CheckpointError, ColonlightError, DeviceError, InputError
from .methods import FrameResult, Method, MethodStream, available_methods, create_method
from .model import GammaNet
from .pipeline import ClipOptions, ClipResult, enhance_clip, iter_enhanced

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
    "gamma_lut",
    "iter_enhanced",
    "load_weights",
    "resolve_device",
    "save_weights",
]
