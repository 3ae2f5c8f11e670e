"""Helpers shared by the benchmarks: timing medians, the reference fixture, table printing."""

from __future__ import annotations

import hashlib
import os
import pickle
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("COLONLIGHT_SHARED", REPO.parent / "shared"))
REFERENCE = SHARED / "fixtures" / "colonlight-reference"
AUTHORS_CKPT = REFERENCE / "gamma_thru10_first2prev2_ssimALL_Epoch6.pth"


def median_time(fn: Callable[[], object], repeats: int = 5, warmup: int = 1) -> float:
    """Median wall time of ``fn`` in seconds."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def markdown_table(headers: list[str], rows: list[list[object]]) -> str:
    """A GitHub-flavoured markdown table."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _generator_digest() -> str:
    """A hash of the generator's source: a rendered clip is reused only while the code that drew it is unchanged."""
    import colonlight.synth

    h = hashlib.sha256()
    for path in sorted(Path(colonlight.synth.__file__).parent.glob("*.py")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:16]


def clip_cache(name: str, render: Callable[[], list[Any]]) -> list[Any]:
    """``render()``'s frames, kept in the cache under ``name`` for the generator's current source: rendering
    takes most of a benchmark's time on a busy machine, and the same seeds are scored again and again."""
    from colonlight.methods.rnn_onnx import cache_dir

    cached = cache_dir().parent / "benchmark-clips" / _generator_digest() / f"{name}.pickle"
    if cached.is_file():
        frames: list[Any] = pickle.loads(cached.read_bytes())  # our own cache, written below
        return frames
    frames = render()
    cached.parent.mkdir(parents=True, exist_ok=True)
    from colonlight.atomic import write_bytes_atomic

    write_bytes_atomic(cached, pickle.dumps(frames))
    return frames
