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
    "atomic_path": "atomic",
    "parent_problem": "atomic",
    "parse_json": "atomic",
    "read_json": "atomic",
    "write_json_atomic": "atomic",
    "MANIFEST_FILE": "batch",
    "ManifestError": "batch",
    "default_workers": "batch",
    "run_batch": "batch",
    "warm_method": "batch",
    "DEFAULT_WEIGHTS": "checkpoint",
    "LoadedWeights": "checkpoint",
    "load_weights": "checkpoint",
    "save_weights": "checkpoint",
    "DEFAULT_CONTENT": "content",
    "ContentMode": "content",
    "content_stream": "content",
    "find_content_area": "content",
    "check_mask_output": "content_mask",
    "content_mask_from_bytes": "content_mask",
    "load_content_mask": "content_mask",
    "read_content_mask": "content_mask",
    "write_content_mask": "content_mask",
    "live_content_stream": "content",
    "parse_content": "content",
    "parse_content_mode": "content",
    "apply_gamma": "curves",
    "apply_lut": "curves",
    "gamma_lut": "curves",
    "resolve_device": "device",
    "ClusterRunner": "cluster",
    "CheckpointError": "errors",
    "ColonlightError": "errors",
    "DeviceError": "errors",
    "decode_image": "frames",
    "encode_image": "frames",
    "InputError": "errors",
    "OptionError": "errors",
    "VIDEO_SUFFIXES": "discovery",
    "PathProblem": "discovery",
    "discover": "discovery",
    "discover_clips": "discovery",
    "synthetic_folder_of": "discovery",
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
    "method_problem": "methods",
    "METHOD_NAMES": "methods",
    "parse_model_size": "methods.rnn",
    "train_zerodce": "methods.zerodce_train",
    "OutputError": "outdir",
    "TRAIN_LOCK": "outdir",
    "output_lock": "outdir",
    "prepare_output": "outdir",
    "GammaNet": "model",
    "export_onnx": "onnx_export",
    "onnx_sidecar_path": "onnx_export",
    "GAMMAS_FILE": "pipeline",
    "VIDEO_FILE": "pipeline",
    "ClipOptions": "pipeline",
    "ClipResult": "pipeline",
    "enhance_clip": "pipeline",
    "iter_enhanced": "pipeline",
    "library_versions": "provenance",
    "read_camera": "slam_layout",
    "clip_frames": "sources",
    "enhance_frames": "streaming",
    "EpochRecord": "train",
    "TrainConfig": "train",
    "TrainResult": "train",
    "export_epoch": "train",
    "parse_frame_steps": "train",
    "train_model": "train",
    "network_threads": "tuning",
    "reuse_frame_memory": "tuning",
    "tune_for_clips": "tuning",
    "VideoInfo": "video",
    "probe_video": "video",
}

if TYPE_CHECKING:
    from .atomic import atomic_path, parent_problem, parse_json, read_json, write_json_atomic
    from .batch import MANIFEST_FILE, ManifestError, default_workers, run_batch, warm_method
    from .checkpoint import DEFAULT_WEIGHTS, LoadedWeights, load_weights, save_weights
    from .cluster import ClusterRunner
    from .content import (
        DEFAULT_CONTENT,
        ContentMode,
        content_stream,
        find_content_area,
        live_content_stream,
        parse_content,
        parse_content_mode,
    )
    from .content_mask import (
        check_mask_output,
        content_mask_from_bytes,
        load_content_mask,
        read_content_mask,
        write_content_mask,
    )
    from .curves import apply_gamma, apply_lut, gamma_lut
    from .device import resolve_device
    from .discovery import VIDEO_SUFFIXES, PathProblem, discover, discover_clips, synthetic_folder_of
    from .errors import CheckpointError, ColonlightError, DeviceError, InputError, OptionError
    from .frames import decode_image, encode_image
    from .jobs import ClipJob, ClipOutcome, MethodSpec, estimate_frames, method_for, run_clip
    from .methods import (
        METHOD_NAMES,
        FrameResult,
        Method,
        MethodStream,
        available_methods,
        create_method,
        is_available,
        method_problem,
    )
    from .methods.rnn import parse_model_size
    from .methods.zerodce_train import train_zerodce
    from .model import GammaNet
    from .onnx_export import export_onnx, onnx_sidecar_path
    from .outdir import TRAIN_LOCK, OutputError, output_lock, prepare_output
    from .pipeline import GAMMAS_FILE, VIDEO_FILE, ClipOptions, ClipResult, enhance_clip, iter_enhanced
    from .provenance import library_versions
    from .slam_layout import read_camera
    from .sources import clip_frames
    from .streaming import enhance_frames
    from .train import EpochRecord, TrainConfig, TrainResult, export_epoch, parse_frame_steps, train_model
    from .tuning import network_threads, reuse_frame_memory, tune_for_clips
    from .video import VideoInfo, probe_video


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
    "ClusterRunner",
    "ColonlightError",
    "ContentMode",
    "DEFAULT_CONTENT",
    "DEFAULT_WEIGHTS",
    "DeviceError",
    "EpochRecord",
    "FrameResult",
    "GAMMAS_FILE",
    "GammaNet",
    "InputError",
    "LoadedWeights",
    "MANIFEST_FILE",
    "METHOD_NAMES",
    "ManifestError",
    "Method",
    "MethodSpec",
    "MethodStream",
    "OptionError",
    "OutputError",
    "PathProblem",
    "TRAIN_LOCK",
    "TrainConfig",
    "TrainResult",
    "VIDEO_FILE",
    "VIDEO_SUFFIXES",
    "VideoInfo",
    "__version__",
    "apply_gamma",
    "apply_lut",
    "atomic_path",
    "available_methods",
    "check_mask_output",
    "clip_frames",
    "content_mask_from_bytes",
    "content_stream",
    "create_method",
    "decode_image",
    "default_workers",
    "discover",
    "discover_clips",
    "encode_image",
    "enhance_clip",
    "enhance_frames",
    "estimate_frames",
    "export_epoch",
    "export_onnx",
    "find_content_area",
    "gamma_lut",
    "is_available",
    "iter_enhanced",
    "library_versions",
    "live_content_stream",
    "load_content_mask",
    "load_weights",
    "method_for",
    "method_problem",
    "network_threads",
    "onnx_sidecar_path",
    "output_lock",
    "parent_problem",
    "parse_content",
    "parse_content_mode",
    "parse_frame_steps",
    "parse_json",
    "parse_model_size",
    "prepare_output",
    "probe_video",
    "read_camera",
    "read_content_mask",
    "read_json",
    "resolve_device",
    "reuse_frame_memory",
    "run_batch",
    "run_clip",
    "save_weights",
    "synthetic_folder_of",
    "train_model",
    "train_zerodce",
    "tune_for_clips",
    "warm_method",
    "write_content_mask",
    "write_json_atomic",
]
