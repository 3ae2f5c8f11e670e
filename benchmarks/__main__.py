"""Run the benchmarks (default: all): `python -m benchmarks [input_size] [enhance] [service] [stream] [ws_stream]
[quality_gate] [objective_landscape] [onnx_step] [model_validation] [model_cost] [video_encoding]
[blind_renderer] [motion_cue]`.

Options after a name go to that benchmark: `python -m benchmarks quality_gate --json gate.json`.
"""

from __future__ import annotations

import importlib
import inspect
import sys

BENCHMARKS = {
    "input_size": "benchmarks.input_size",
    "enhance": "benchmarks.enhance_vs_ffmpeg",
    "service": "benchmarks.service_load",
    "stream": "benchmarks.stream_realtime",
    "ws_stream": "benchmarks.ws_stream",
    "quality_gate": "benchmarks.quality_gate",
    "objective_landscape": "benchmarks.objective_landscape",
    "onnx_step": "benchmarks.onnx_step",
    "model_validation": "benchmarks.model_validation",
    "model_cost": "benchmarks.model_cost",
    "video_encoding": "benchmarks.video_encoding",
    "blind_renderer": "benchmarks.blind_renderer_check",
    "motion_cue": "benchmarks.motion_cue",
}


def parse(argv: list[str]) -> list[tuple[str, list[str]]]:
    """``["quality_gate", "--json", "f", "enhance"]`` -> ``[("quality_gate", ["--json", "f"]), ("enhance", [])]``."""
    runs: list[tuple[str, list[str]]] = []
    for arg in argv:
        if runs and (
            arg.startswith("-") or (runs[-1][1] and runs[-1][1][-1].startswith("-") and arg not in BENCHMARKS)
        ):
            runs[-1][1].append(arg)
        elif arg in BENCHMARKS:
            runs.append((arg, []))
        else:
            raise SystemExit(f"unknown benchmark {arg!r}; choose from {', '.join(BENCHMARKS)}")
    return runs or [(name, []) for name in BENCHMARKS]


def main(argv: list[str]) -> None:
    if argv[:1] in (["-h"], ["--help"]):
        print((__doc__ or "").strip())
        return
    for name, options in parse(argv):
        try:
            module = importlib.import_module(BENCHMARKS[name])
        except ImportError as exc:
            print(f"## {name}: not available ({exc})\n")
            continue
        if options and not inspect.signature(module.main).parameters:
            raise SystemExit(f"benchmark {name!r} takes no options (got {' '.join(options)})")
        print(module.main(options) if options else module.main(), flush=True)
        print()


if __name__ == "__main__":
    main(sys.argv[1:])
