"""What ``enhanced.mp4``'s reproducibility costs: the shipped encoder settings (x264 without its macroblock-tree
pass, ``X264_PARAMS``) against x264's default (the baseline), at the same CRF and preset.

For each of a few held-out-family synthetic clips rendered at 640x512 (cached between runs): the bytes of both
encodes, their ratio, the mean PSNR of the decoded frames to the frames encoded, and whether two encodes of the
same frames in one process gave the same bytes (the reason for the setting). Reported: the median ratio of bytes.

Run: ``python -m benchmarks video_encoding [--clips 4] [--frames 90]``.
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import tempfile
from pathlib import Path

import av
import numpy as np

from colonlight.metrics import psnr
from colonlight.video_writer import X264_PARAMS, VideoWriter

from .common import clip_cache, markdown_table

WIDTH, HEIGHT = 640, 512
FIRST_SEED = 910000  # held-out family; not a seed of the validation or gate clips
SHIPPED = f"shipped (x264-params {X264_PARAMS})"
BASELINE = "baseline: x264's default (macroblock tree on)"


def _clip(seed: int, frames: int) -> list[np.ndarray]:
    from colonlight.synth import SynthConfig, generate_clip

    def render() -> list[np.ndarray]:
        cfg = SynthConfig.sample(
            np.random.default_rng(seed), split="heldout", width=WIDTH, height=HEIGHT, n_frames=frames
        )
        return [f.image for f in generate_clip(cfg, seed=seed)]

    return clip_cache(f"video-encoding-{seed}-{WIDTH}x{HEIGHT}-{frames}", render)


def _encode(frames: list[np.ndarray], path: Path, x264_params: str) -> tuple[int, str, float]:
    """(bytes, sha256, mean PSNR of the decoded frames to ``frames``) of one encode."""
    with VideoWriter(path, fps=18.0, x264_params=x264_params) as writer:
        for frame in frames:
            writer.write(frame)
    data = path.read_bytes()
    with av.open(str(path)) as container:
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    whole = np.ones(frames[0].shape[:2], dtype=bool)
    per_frame = [psnr(a, b, whole) for a, b in zip(decoded, frames, strict=True)]
    return len(data), hashlib.sha256(data).hexdigest(), float(np.mean(per_frame))


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m benchmarks video_encoding")
    parser.add_argument("--clips", type=int, default=4)
    parser.add_argument("--frames", type=int, default=90)
    args = parser.parse_args(argv or [])
    rows: list[list[object]] = []
    ratios: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.clips):
            frames = _clip(FIRST_SEED + i, args.frames)
            results = {}
            for name, params in ((SHIPPED, X264_PARAMS), (BASELINE, "")):
                first = _encode(frames, Path(tmp) / "a.mp4", params)
                again = _encode(frames, Path(tmp) / "b.mp4", params)
                results[name] = (first, first[1] == again[1])
            ratio = results[SHIPPED][0][0] / results[BASELINE][0][0]
            ratios.append(ratio)
            for name, ((size, _digest, psnr), same) in results.items():
                rows.append([FIRST_SEED + i, name, f"{size:,}", f"{psnr:.2f}", "yes" if same else "**no**"])
            rows.append([FIRST_SEED + i, "ratio of bytes, shipped / baseline", f"**{ratio:.3f}x**", "", ""])
    table = markdown_table(["clip seed", "encoder", "bytes", "PSNR to frames (dB)", "same bytes twice"], rows)
    return (
        f"## video_encoding: {SHIPPED} vs {BASELINE}, CRF 18, preset medium, {args.clips} clips of {args.frames}"
        f" frames at {WIDTH}x{HEIGHT}\n\n{table}\n\nmedian ratio of bytes: **{statistics.median(ratios):.3f}x**"
    )
