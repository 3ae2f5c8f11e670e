"""Helpers shared by the benchmarks: timing medians, the reference fixture, table printing, synthetic clips
encoded by FFmpeg."""

from __future__ import annotations

import hashlib
import os
import pickle
import statistics
import subprocess
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


def ffmpeg_exe() -> str:
    """The ffmpeg binary imageio-ffmpeg ships (the one the tests serve streams with)."""
    import imageio_ffmpeg

    return str(imageio_ffmpeg.get_ffmpeg_exe())


def encode_synthetic_clip(
    path: Path,
    *,
    seed: int,
    render_size: tuple[int, int],
    size: tuple[int, int],
    fps: int,
    rendered: int,
    frames: int,
    crf: int,
    gop: int | None = None,
) -> Path:
    """An H.264 clip of ``frames`` frames at ``size`` (width, height): ``rendered`` frames of the generator's held-out
    family at ``render_size`` (rendering a full-size frame takes seconds), played back and forth and upscaled
    (bicubic) by FFmpeg; ``gop``: a keyframe every that many frames, as a live encoder sends."""
    import numpy as np

    from colonlight.synth import SynthConfig, generate_clip

    cfg = SynthConfig.sample(
        np.random.default_rng(seed),
        split="heldout",
        width=render_size[0],
        height=render_size[1],
        n_frames=rendered,
        fps=float(fps),
    )
    images = [f.image for f in generate_clip(cfg, seed=seed)]
    raw_input = ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{cfg.width}x{cfg.height}", "-framerate", str(fps)]
    x264 = ["-c:v", "libx264", "-preset", "veryfast", "-crf", str(crf), *(["-g", str(gop)] if gop else [])]
    cmd = [ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y", *raw_input, "-i", "-"]
    cmd += ["-vf", f"scale={size[0]}:{size[1]}:flags=bicubic", *x264, "-pix_fmt", "yuv420p", str(path)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE)
    assert proc.stdin is not None
    period = 2 * len(images) - 2
    for i in range(frames):
        k = i % period
        proc.stdin.write(images[k if k < len(images) else period - k].tobytes())
    proc.stdin.close()
    if proc.wait() != 0:
        raise RuntimeError(f"ffmpeg failed to encode the benchmark clip {path.name}")
    return path
