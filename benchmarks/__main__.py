"""Run the benchmarks: `python -m benchmarks [input_size] [enhance] [service] [quality_gate] [objective_landscape]` (default: all)."""

from __future__ import annotations

import importlib
import sys

BENCHMARKS = {
    "input_size": "benchmarks.input_size",
    "enhance": "benchmarks.enhance_vs_ffmpeg",
    "service": "benchmarks.service_load",
    "quality_gate": "benchmarks.quality_gate",
    "objective_landscape": "benchmarks.objective_landscape",
}


def main(argv: list[str]) -> None:
    names = argv or list(BENCHMARKS)
    for name in names:
        if name not in BENCHMARKS:
            raise SystemExit(f"unknown benchmark {name!r}; choose from {', '.join(BENCHMARKS)}")
        try:
            module = importlib.import_module(BENCHMARKS[name])
        except ImportError as exc:
            print(f"## {name}: not available ({exc})\n")
            continue
        print(module.main(), flush=True)
        print()


if __name__ == "__main__":
    main(sys.argv[1:])
