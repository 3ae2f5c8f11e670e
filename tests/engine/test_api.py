"""The public API is what `colonlight.__all__` says, sorted, and every name in it exists."""

from __future__ import annotations

import colonlight


def test_all_is_sorted_and_pinned() -> None:
    assert colonlight.__all__ == sorted(colonlight.__all__)
    assert colonlight.__all__ == [
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
    for name in colonlight.__all__:
        assert hasattr(colonlight, name), name


def test_engine_imports_no_shell_code() -> None:
    import pathlib

    root = pathlib.Path(colonlight.__file__).parent
    for path in root.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        for banned in ("colonlight_cli", "colonlight_service", "import typer", "import fastapi", "from fastapi"):
            assert banned not in text, f"{path} mentions {banned}"
