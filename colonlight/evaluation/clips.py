"""Clips to evaluate on: a user's videos and frame folders, or synthetic clips with ground truth.

Every clip is held in memory at a *working size* (long side at most ``max_size``, 256 px by default, shrunk with
``cv2.INTER_AREA``, never enlarged): evaluation runs every method, a tracker and COLMAP on each clip, and at full
resolution that would cost minutes per clip without changing what is compared. Intrinsics and depth are scaled
with the frames, so ground truth stays exact at the working size.

A synthetic clip folder (``colonlight synth`` / :func:`colonlight.synth.write_clip`) is recognised by its
``synth.json``; its frames, depth, poses, intrinsics and clean frames come along. Anything else is decoded by
:func:`colonlight.sources.clip_frames` (the FFmpeg ``fps=18`` frame choice) and has no ground truth.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..atomic import read_json, remove_stale_temporaries
from ..discovery import (
    SYNTH_FRAMES,
    SYNTH_MARKER,
    SYNTH_VIDEO,
    discover_clips,
    is_synthetic_folder,
    synthetic_folder_of,
)
from ..errors import InputError
from ..frames import list_image_frames, read_image
from ..limits import DEFAULT_FPS
from ..sources import clip_frames
from ..synth import SynthConfig, decode_depth, write_clip
from ..synth.config import Split
from ..synth.writer import read_tum
from ..worker_process import map_in_workers
from .consistency import MIN_FLOW_SIDE

DEFAULT_MAX_SIZE = 256
#: Seeds of the benchmark's clips start here: training used 1000-1099 and the quality gate 700000-700023.
BENCHMARK_SEED0 = 800_000


@dataclass
class EvalClip:
    """One clip in memory at working size.

    Attributes:
        name: relative name (as ``colonlight enhance`` would name its output folder).
        source: where it came from.
        frames: ``(H, W, 3)`` uint8 RGB frames in order.
        fps: frame rate of ``frames``.
        depths: z-depth per frame in metres, float32, ``inf`` where unknown (synthetic clips).
        poses: camera-to-world 4x4 per frame, metres, OpenCV axes (synthetic clips).
        K: 3x3 pinhole intrinsics at working size, pixel centres at integer coordinates.
        clean: the frames without lighting disturbance (synthetic clips; or a user's own ground truth).
        lighting: per-frame lighting ground truth of a synthetic clip (``lighting.json``'s ``frames``: gain,
            contrast, exposure, display_gain, disturbed, close_occluder), used to say why a frame failed.
        meta: facts about the clip worth recording (seed, close occluder moments, original size, scale).
    """

    name: str
    source: str
    frames: list[np.ndarray]
    fps: float = DEFAULT_FPS
    depths: list[np.ndarray] | None = None
    poses: list[np.ndarray] | None = None
    K: np.ndarray | None = None
    clean: list[np.ndarray] | None = None
    lighting: list[dict[str, Any]] | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def synthetic(self) -> bool:
        return self.depths is not None and self.poses is not None and self.K is not None

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary (no pixels)."""
        h, w = self.frames[0].shape[:2] if self.frames else (0, 0)
        return {
            "name": self.name,
            "source": self.source,
            "frames": len(self.frames),
            "fps": self.fps,
            "size": [w, h],
            "ground_truth": self.synthetic,
            **self.meta,
        }


@dataclass(frozen=True)
class ClipRef:
    """A clip found on disk, loaded only when evaluated (one clip in memory at a time)."""

    name: str
    path: Path
    kind: str  # "synthetic" | "video" (a video file or a frame folder)

    def load(
        self, max_size: int | None = DEFAULT_MAX_SIZE, fps: float = DEFAULT_FPS, max_frames: int | None = None
    ) -> EvalClip:
        """Read the clip at working size; :class:`InputError` (one line) if it cannot be used."""
        if self.kind == "synthetic":
            return load_synthetic_clip(self.path, max_size, max_frames, name=self.name)
        return load_user_clip(self.path, fps, max_size, max_frames, name=self.name)


# ------------------------------------------------------------------------------------------------- resizing


def working_scale(width: int, height: int, max_size: int | None) -> float:
    """Factor that brings the long side down to ``max_size`` (1.0 if already small enough or no limit)."""
    if not max_size or max(width, height) <= max_size:
        return 1.0
    return max_size / max(width, height)


def _target(width: int, height: int, scale: float) -> tuple[int, int]:
    return max(1, round(width * scale)), max(1, round(height * scale))


def resize_frame(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area-averaged ``(w, h)`` copy (the frame itself when already that size)."""
    if frame.shape[1::-1] == tuple(size):
        return frame
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA)


def resize_depth(depth: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Area average of the known depth; a working pixel is unknown (inf) unless all its source pixels are known.

    Averaging z-depth over a block gives the z of the block's centre on a locally planar wall, which is where
    the resized pixel's centre looks.
    """
    if depth.shape[1::-1] == tuple(size):
        return depth
    known = np.isfinite(depth)
    total = cv2.resize(np.where(known, depth, 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    cover = cv2.resize(known.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    full = cover > 0.999
    return np.where(full, total / np.where(full, cover, 1), np.inf).astype(np.float32)


def scale_intrinsics(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Intrinsics after resizing by ``(sx, sy)``, pixel centres at integer coordinates: ``c' = (c + .5) s - .5``."""
    out = np.array(K, dtype=np.float64, copy=True)
    out[0, 0] *= sx
    out[1, 1] *= sy
    out[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    out[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return out


# ------------------------------------------------------------------------------------------- ground truth


def _read_depth_png(path: Path) -> np.ndarray:
    data = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise InputError(f"{path}: not a 16-bit depth PNG")
    return decode_depth(img)


def _clean_frames(
    folder: Path, paths: list[Path], count: int, original: tuple[int, ...], size: tuple[int, int]
) -> list[np.ndarray]:
    """The clip's clean frames at working size; InputError naming them if they are not the clip's frame for frame:
    fewer than its frames were dropped without a word (no reference rows, no reason), and another size was
    stretched to the frames' and scored as the truth."""
    if len(paths) != count:
        raise InputError(f"{folder}: {len(paths)} clean frame(s) for the clip's {count} frames; they must match")
    clean = []
    for path in paths:
        image = read_image(path)
        if image.shape[1::-1] != original:
            raise InputError(
                f"{path}: clean frame of {image.shape[1]}x{image.shape[0]}, the clip's frames are "
                f"{original[0]}x{original[1]}"
            )
        clean.append(resize_frame(image, size))
    return clean


def load_synthetic_clip(
    folder: Path,
    max_size: int | None = DEFAULT_MAX_SIZE,
    max_frames: int | None = None,
    name: str | None = None,
) -> EvalClip:
    """A ``colonlight synth`` clip folder with its ground truth, at working size."""
    folder = Path(folder)
    try:
        meta = read_json(folder / SYNTH_MARKER)
        intr = read_json(folder / "intrinsics.json")
        cfg = meta["config"]
        fps = float(cfg.get("fps", DEFAULT_FPS))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"{folder}: incomplete synthetic clip ({exc})") from exc
    if (folder / SYNTH_FRAMES).is_dir():
        images = [read_image(p) for p in list_image_frames(folder / SYNTH_FRAMES)[:max_frames]]
    else:  # written with frames=False: every frame of the video (it was encoded at the clip's own rate)
        images = [f.image for f in clip_frames(folder / SYNTH_VIDEO, fps=None)][:max_frames]
    depth_paths = list_image_frames(folder / "depth")[: len(images)]
    poses = read_tum(folder / "poses.txt")[: len(images)]
    if not (len(images) == len(depth_paths) == len(poses)) or len(images) < 2:
        raise InputError(
            f"{folder}: {len(images)} frames, {len(depth_paths)} depth maps and {len(poses)} poses; "
            "they must match and be at least 2"
        )
    clean_dir = folder / "clean"
    clean_paths = list_image_frames(clean_dir)[: len(images)] if clean_dir.is_dir() else []
    w0, h0 = int(intr["width"]), int(intr["height"])
    scale = working_scale(w0, h0, max_size)
    size = _target(w0, h0, scale)
    K0 = np.array([[intr["fx"], 0, intr["cx"]], [0, intr["fy"], intr["cy"]], [0, 0, 1]], dtype=np.float64)
    frames = [resize_frame(f, size) for f in images]
    if any(f.shape[1::-1] != size for f in frames):
        raise InputError(f"{folder}: frame size differs from intrinsics.json ({w0}x{h0})")
    clean = (
        _clean_frames(clean_dir, clean_paths, len(frames), images[0].shape[1::-1], size) if clean_dir.is_dir() else None
    )
    occluder = None
    per_frame: list[dict[str, Any]] | None = None
    camera_gamma = None
    try:
        lighting = read_json(folder / "lighting.json")
        per_frame = [dict(f) for f in lighting["frames"]][: len(frames)]
        occluder = [bool(f.get("close_occluder")) for f in per_frame]
        camera_gamma = lighting.get("camera_gamma")
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        per_frame = None
    return EvalClip(
        name=name or folder.name,
        source=str(folder),
        frames=frames,
        fps=fps,
        depths=[resize_depth(_read_depth_png(p), size) for p in depth_paths],
        poses=poses,
        K=scale_intrinsics(K0, size[0] / w0, size[1] / h0),
        clean=clean,
        lighting=per_frame if per_frame is not None and len(per_frame) == len(frames) else None,
        meta={
            "seed": meta.get("seed"),
            "split": cfg.get("split"),
            "close_occluder": cfg.get("close_occluder"),
            "occluder_frames": int(sum(occluder)) if occluder else 0,
            "original_size": [w0, h0],
            "scale": scale,
            "camera_gamma": camera_gamma,
        },
    )


def load_user_clip(
    path: Path,
    fps: float = DEFAULT_FPS,
    max_size: int | None = DEFAULT_MAX_SIZE,
    max_frames: int | None = None,
    name: str | None = None,
) -> EvalClip:
    """A video (frames chosen like FFmpeg's ``fps=...``) or a frame folder, at working size; no ground truth."""
    path = Path(path)
    frames: list[np.ndarray] = []
    size: tuple[int, int] | None = None
    original: tuple[int, int] = (0, 0)
    scale = 1.0
    for f in clip_frames(path, fps=fps or None, folder_fps=fps or DEFAULT_FPS, min_frames=2):
        if size is None:
            original = (f.image.shape[1], f.image.shape[0])
            scale = working_scale(*original, max_size)
            size = _target(*original, scale)
            if min(size) < MIN_FLOW_SIDE:
                raise InputError(
                    f"{path}: frames of {original[0]}x{original[1]} ({size[0]}x{size[1]} at the working size) are "
                    f"too small to evaluate: optical flow needs at least {MIN_FLOW_SIDE} px a side"
                )
        elif (f.image.shape[1], f.image.shape[0]) != original:
            raise InputError(f"{path}: frame {f.index} changes size mid-clip")
        frames.append(resize_frame(f.image, size))
        if max_frames and len(frames) >= max_frames:
            break
    if len(frames) < 2:
        raise InputError(f"{path}: only {len(frames)} frame(s); at least 2 are needed")
    return EvalClip(
        name=name or path.stem,
        source=str(path),
        frames=frames,
        fps=float(fps or DEFAULT_FPS),
        meta={"original_size": list(original), "scale": scale},
    )


# ------------------------------------------------------------------------------------------------ discovery


def find_clips(inputs: Sequence[Path]) -> list[ClipRef]:
    """Clips under ``inputs``, as :func:`colonlight.discovery.discover_clips` finds and names them for
    ``colonlight enhance``: synthetic clip folders (by ``synth.json``: one clip each, with its ground truth; listed
    first), then every other clip. A path that does not exist is kept, to be reported when loaded.
    """
    refs: list[ClipRef] = []
    for inp in map(Path, inputs):
        if is_synthetic_folder(inp):
            refs.append(ClipRef(inp.name, inp, "synthetic"))
            continue
        jobs = discover_clips([inp], Path("."))
        folders = [synthetic_folder_of(job.source) for job in jobs]
        refs += [
            ClipRef(job.name, folder, "synthetic")
            for job, folder in zip(jobs, folders, strict=True)
            if folder is not None
        ]
        refs += [
            ClipRef(job.name, job.source, "video") for job, folder in zip(jobs, folders, strict=True) if folder is None
        ]
    return unique_clips(refs)


def unique_clips(refs: Sequence[ClipRef]) -> list[ClipRef]:
    """``refs`` with each clip once (the first time its path is named) and no two under one name (a later one
    gets ``-2``, ``-3``, ...). A clip named twice (``a.mp4 a.mp4``, a folder and a clip in it, a benchmark
    rendered inside an input folder) was evaluated once for each time, and weighed that many times in the
    summary; two files of one name (``x/a.mp4``, ``y/a.mp4``) were two rows the report could not tell apart."""
    out: list[ClipRef] = []
    seen: set[Path] = set()
    names: set[str] = set()
    for ref in refs:
        try:
            key = ref.path.resolve()
        except (OSError, RuntimeError):  # a link loop, a name too long: reported when the clip is loaded
            key = ref.path.absolute()
        if key in seen:
            continue
        seen.add(key)
        name, n = ref.name, 2
        while name in names:
            name, n = f"{ref.name}-{n}", n + 1
        names.add(name)
        out.append(ref if name == ref.name else ClipRef(name, ref.path, ref.kind))
    return out


# ---------------------------------------------------------------------------------------- synthetic benchmark


def benchmark_config(
    index: int, seed: int, frames: int, size: int, fps: float = DEFAULT_FPS, family: Split = "train"
) -> SynthConfig:
    """Clip ``index`` of the synthetic benchmark: every third clip (0, 3, 6, ...) has close-occluder moments, the
    others none; all start with two undisturbed frames so restoration can be scored against the clean frames.

    ``family="train"`` draws the generator's training ranges (only the seeds are unseen): inspection-speed
    camera motion (1.5-20 mm/s), which a tracker can follow at 18 fps. ``"heldout"`` pushes at least two knobs
    outside them (camera speed, flicker strength, geometry, optics; see ``PARAM_SPECS``).
    """
    return SynthConfig.sample(
        np.random.default_rng([seed, 1]),  # the held-out stream make_dataset uses
        split=family,
        width=size,
        height=size,
        n_frames=frames,
        fps=fps,
        close_occluder="force" if index % 3 == 0 else "forbid",
        undisturbed_seeds=True,
    )


def _is_complete(folder: Path, cfg: SynthConfig, seed: int) -> bool:
    try:
        meta = read_json(folder / SYNTH_MARKER)
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and bool(
        meta.get("seed") == seed and meta.get("config") == json.loads(json.dumps(cfg.to_dict()))
    )


def _render_job(args: tuple[Path, dict[str, Any], int]) -> Path:
    folder, cfg_dict, seed = args
    cv2.setNumThreads(1)
    return write_clip(folder, SynthConfig.from_dict(cfg_dict), seed, video=False)


def make_benchmark(
    out_dir: Path,
    n_clips: int,
    seed0: int = BENCHMARK_SEED0,
    frames: int = 72,
    size: int = 256,
    workers: int = 1,
    on_clip: Callable[[Path, bool], None] | None = None,
    family: Split = "train",
) -> list[ClipRef]:
    """Render (or reuse, when complete with the same config and seed) the benchmark clips (``family``: see
    :func:`benchmark_config`) into
    ``out_dir/clip_00000`` ...; clip ``i`` uses seed ``seed0 + i``. ``on_clip(folder, rendered)`` is called as
    each clip is ready (``rendered`` False when reused)."""
    out_dir = Path(out_dir)
    jobs, refs = [], []
    for i in range(n_clips):
        seed = seed0 + i
        cfg = benchmark_config(i, seed, frames, size, family=family)
        folder = out_dir / f"clip_{i:05d}"
        refs.append(ClipRef(folder.name, folder, "synthetic"))
        if _is_complete(folder, cfg, seed):
            if on_clip:
                on_clip(folder, False)
        else:
            jobs.append((folder, cfg.to_dict(), seed))
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            _render_job(job)
            if on_clip:
                on_clip(job[0], True)
    else:

        def sweep() -> None:  # the clip folders are this run's: what a killed worker was writing goes
            for job in jobs:
                remove_stale_temporaries(job[0])

        for folder in map_in_workers(_render_job, jobs, workers=workers, on_stop=sweep):
            if on_clip:
                on_clip(folder, True)
    return refs


__all__ = [
    "BENCHMARK_SEED0",
    "ClipRef",
    "EvalClip",
    "benchmark_config",
    "find_clips",
    "load_synthetic_clip",
    "load_user_clip",
    "make_benchmark",
    "resize_depth",
    "scale_intrinsics",
]
