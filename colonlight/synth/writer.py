"""Write synthetic clips to disk (video, frame folders, ground truth) and whole datasets in parallel.

Layout of one clip folder (every file written atomically; ``synth.json`` last, so its presence means
"complete")::

    clip.mp4              H.264 of the disturbed frames at cfg.fps (if video=True)
    frames/000000.png     disturbed RGB frames (if frames=True)
    clean/000000.png      the same frames at the clip's fixed exposure, no disturbance
    depth/000000.png      uint16 z-depth along the optical axis in units of 0.1 mm (value * 1e-4 = metres);
                          0 = no wall within reach (far lumen)
    poses.txt             TUM: "timestamp tx ty tz qx qy qz qw", camera-to-world, metres, OpenCV camera axes
    intrinsics.json       pinhole fx, fy, cx, cy, width, height (pixels)
    lighting.json         the disturbance model and per-frame ground truth (gain, contrast, exposure, ...)
    synth.json            config, seed, colonlight and generator versions, file formats
    content.png           only with an overlay (border, text): 255 where the scene shows, 0 on border and text
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..atomic import atomic_path, read_json, remove_stale_temporaries, write_bytes_atomic, write_json_atomic
from ..discovery import SYNTH_FRAMES, SYNTH_MARKER, SYNTH_VIDEO
from ..errors import InputError
from ..limits import DEFAULT_FPS
from ..video import VideoWriter
from ..worker_process import die_with_parent, map_in_workers
from .clip import SynthFrame, build_scene, render_frame
from .config import Split, SynthConfig
from .overlay import OverlaySpec, drawn_overlay

GENERATOR_VERSION = "1.0"
DEPTH_UNIT_M = 1e-4
LIGHTING_MODEL = (
    "image = clip(display_gain * y ** contrast), clean = clip(y), "
    "y = the clean frame in [0,1] before clipping; "
    "display_gain = gain * exposure ** (contrast / camera_gamma); "
    "exposure is linear and relative to clean_exposure"
)


def _colonlight_version() -> str:
    try:
        from .. import __version__

        return str(__version__)
    except ImportError:
        pass
    try:
        from importlib.metadata import version

        return version("colonlight")
    except Exception:  # noqa: BLE001 - not installed (running from a checkout)
        return "unknown"


def rotation_to_quaternion(r: np.ndarray) -> np.ndarray:
    """(qx, qy, qz, qw) with qw >= 0 of a 3x3 rotation matrix (Shepperd's method, stable for all angles)."""
    m = r
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def tum_line(time_s: float, pose: np.ndarray) -> str:
    """One TUM trajectory line for a 4x4 camera-to-world pose."""
    q = rotation_to_quaternion(pose[:3, :3])
    t = pose[:3, 3]
    return f"{time_s:.6f} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}"


def quaternion_to_rotation(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """3x3 rotation of a unit quaternion (normalised first); the inverse of :func:`rotation_to_quaternion`."""
    q = np.array([qw, qx, qy, qz], dtype=np.float64)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def read_tum(path: Path) -> list[np.ndarray]:
    """4x4 poses of a TUM file (``t tx ty tz qx qy qz qw`` per line; ``#`` comments skipped): reads what
    :func:`tum_line` writes."""
    poses = []
    for n, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8:
            raise InputError(f"{path}:{n}: expected 8 numbers (t tx ty tz qx qy qz qw), got {len(parts)}")
        v = [float(p) for p in parts]
        m = np.eye(4)
        m[:3, :3] = quaternion_to_rotation(*v[4:8])
        m[:3, 3] = v[1:4]
        poses.append(m)
    return poses


def encode_depth(depth_m: np.ndarray) -> np.ndarray:
    """Metres (inf = none) -> uint16 in 0.1 mm with 0 = none (or beyond 6.5 m)."""
    v = np.where(np.isfinite(depth_m), np.rint(depth_m / DEPTH_UNIT_M), 0)
    v = np.where(v > 65535, 0, v)
    return v.astype(np.uint16)


def decode_depth(png16: np.ndarray) -> np.ndarray:
    """Inverse of :func:`encode_depth`: float32 metres with inf where no wall."""
    d = png16.astype(np.float32) * np.float32(DEPTH_UNIT_M)
    return np.where(png16 == 0, np.float32(np.inf), d)


def _write_png(path: Path, img: np.ndarray) -> None:
    """PNG through cv2.imencode, renamed into place (no fsync per frame: thousands of small files)."""
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())


def _frame_name(i: int) -> str:
    return f"{i:06d}.png"


def write_clip(
    out_dir: Path,
    cfg: SynthConfig,
    seed: int,
    *,
    video: bool = True,
    frames: bool = True,
    clean: bool = True,
    depth: bool = True,
    crf: int = 18,
    overlay: OverlaySpec | None = None,
) -> Path:
    """Render clip ``(cfg, seed)`` into ``out_dir`` (see the module docstring for the layout); returns
    ``out_dir``. ``overlay`` draws a scope's border and on-screen text onto the frames and clean frames."""
    out_dir = Path(out_dir)
    overlay = drawn_overlay(overlay)
    out_dir.mkdir(parents=True, exist_ok=True)
    # a clip rendered here before (another config) stops being one now: interrupted, no marker says "complete"
    (out_dir / SYNTH_MARKER).unlink(missing_ok=True)
    # what a run killed mid-clip left (clip.mp4's temporary lives as long as the render): nothing renames it now
    remove_stale_temporaries(out_dir)
    try:
        _render_clip(out_dir, cfg, seed, video=video, frames=frames, clean=clean, depth=depth, crf=crf, overlay=overlay)
    except BaseException:
        # an interrupt (SIGTERM's exception) can land where no writer's own clean-up reaches (the video's
        # temporary is held by its writer across the render): the clip's folder is this run's alone, so every
        # temporary in it goes
        remove_stale_temporaries(out_dir)
        raise
    return out_dir


def _render_clip(
    out_dir: Path,
    cfg: SynthConfig,
    seed: int,
    *,
    video: bool,
    frames: bool,
    clean: bool,
    depth: bool,
    crf: int,
    overlay: OverlaySpec | None,
) -> None:
    """:func:`write_clip`'s rendering and writing, into a folder it has prepared."""
    scene = build_scene(cfg, seed)
    poses: list[str] = []
    per_frame: list[dict[str, Any]] = []
    writer = VideoWriter(out_dir / SYNTH_VIDEO, fps=cfg.fps, crf=crf) if video else None
    try:
        for i in range(cfg.n_frames):
            f: SynthFrame = render_frame(scene, i)
            if overlay is not None:
                f = dataclasses.replace(f, image=overlay.apply(f.image), clean=overlay.apply(f.clean))
            if writer is not None:
                writer.write(f.image)
            if frames:
                _write_png(out_dir / SYNTH_FRAMES / _frame_name(i), f.image)
            if clean:
                _write_png(out_dir / "clean" / _frame_name(i), f.clean)
            if depth:
                _write_png(out_dir / "depth" / _frame_name(i), encode_depth(f.depth))
            poses.append(tum_line(f.time_s, f.pose))
            per_frame.append({"index": i, "time_s": f.time_s, **f.lighting, "close_occluder": f.occluder})
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    if writer is not None:
        writer.close()
    write_bytes_atomic(out_dir / "poses.txt", ("\n".join(poses) + "\n").encode())
    write_json_atomic(out_dir / "intrinsics.json", scene.intrinsics.to_dict())
    lt = scene.lighting
    write_json_atomic(
        out_dir / "lighting.json",
        {
            "model": LIGHTING_MODEL,
            "camera_gamma": lt.camera_gamma,
            "clean_exposure": lt.clean_exposure,
            "steady": cfg.steady,
            "undisturbed_seeds": cfg.undisturbed_seeds,
            "events": lt.events,
            "frames": per_frame,
        },
    )
    manifest = _manifest(cfg, seed, video=video, frames=frames, clean=clean, depth=depth)
    if overlay is not None:
        fov, text = overlay.masks(cfg.height, cfg.width)
        _write_png(out_dir / "content.png", np.where(fov & ~text, 255, 0).astype(np.uint8))
        manifest["overlay"] = overlay.to_dict()
    _remove_stale(
        out_dir, cfg.n_frames, video=video, frames=frames, clean=clean, depth=depth, content=overlay is not None
    )
    write_json_atomic(out_dir / SYNTH_MARKER, manifest)


def _manifest(cfg: SynthConfig, seed: int, **written: bool) -> dict[str, Any]:
    return {
        "generator": "colonlight.synth",
        "generator_version": GENERATOR_VERSION,
        "colonlight_version": _colonlight_version(),
        "seed": int(seed),
        "config": cfg.to_dict(),
        "written": written,
        "formats": {
            "frames": "RGB PNG, 8 bit, disturbed (what the scope records)",
            "clean": "RGB PNG, 8 bit, same scene at the clip's fixed exposure without disturbance",
            "depth": {
                "encoding": "uint16 PNG",
                "unit_m": DEPTH_UNIT_M,
                "invalid": 0,
                "kind": "z-depth along the optical axis",
            },
            "poses": "TUM 'timestamp tx ty tz qx qy qz qw', camera-to-world, metres, "
            "OpenCV axes (x right, y down, z forward)",
            "lighting": LIGHTING_MODEL,
        },
    }


def _remove_stale(out_dir: Path, n_frames: int, **written: bool) -> None:
    """Delete what an earlier clip rendered into ``out_dir`` left and this one did not overwrite: frames past
    ``n_frames`` (a 3-frame clip over a 6-frame one kept frames 3..5, and readers of ``frames/`` took 6), and
    the outputs this one does not write (``clip.mp4`` of another clip). Only names the writer itself makes."""
    files = {SYNTH_VIDEO: "video", "content.png": "content"}
    for name, flag in files.items():
        if not written[flag]:
            (out_dir / name).unlink(missing_ok=True)
    for folder in (SYNTH_FRAMES, "clean", "depth"):
        keep = n_frames if written[folder] else 0
        for png in (out_dir / folder).glob("[0-9][0-9][0-9][0-9][0-9][0-9].png"):
            if int(png.stem) >= keep:
                png.unlink(missing_ok=True)


def clip_complete(
    out_dir: Path, cfg: SynthConfig, seed: int, overlay: OverlaySpec | None = None, **wanted: bool
) -> bool:
    """True if ``out_dir`` holds a finished clip of exactly this config, seed and overlay (resume support) with
    every output of ``wanted`` that is True (``video=True``: its ``clip.mp4``; one rendered without is not)."""
    try:
        meta = read_json(out_dir / SYNTH_MARKER)
    except (OSError, ValueError):
        return False
    if not isinstance(meta, dict):
        return False
    overlay = drawn_overlay(overlay)
    drawn = overlay.to_dict() if overlay is not None else None
    written = meta.get("written")
    if not isinstance(written, dict):
        written = {}
    return bool(
        meta.get("seed") == seed
        and meta.get("config") == json.loads(json.dumps(cfg.to_dict()))
        and meta.get("overlay") == drawn
        and all(written.get(name) for name, want in wanted.items() if want)
        and (not wanted.get("video") or (out_dir / SYNTH_VIDEO).is_file())
    )


def _dataset_job(args: tuple[Path, dict[str, Any], int, dict[str, Any]]) -> Path:
    out_dir, cfg_dict, seed, flags = args
    cfg = SynthConfig.from_dict(cfg_dict)
    if clip_complete(out_dir, cfg, seed, flags.get("overlay"), video=flags.get("video", True)):
        return out_dir  # (one rendered with --no-video is rendered again when its video is asked for)
    return write_clip(out_dir, cfg, seed, **flags)


def _init_worker(parent_pid: int) -> None:
    """A render worker: dies with the process rendering the dataset, one OpenCV thread (one process per core)."""
    die_with_parent(parent_pid)
    cv2.setNumThreads(1)


def make_dataset(
    out_dir: Path,
    n_clips: int,
    *,
    seed: int = 0,
    split: Split = "train",
    width: int = 256,
    height: int = 256,
    n_frames: int = 100,
    fps: float = DEFAULT_FPS,
    workers: int = 2,
    video: bool = False,
    steady_fraction: float = 0.0,
    occluder_fraction: float = 0.0,
    clean_seeds_fraction: float = 0.0,
    overlay: OverlaySpec | None = None,
    **overrides: Any,
) -> list[Path]:
    """Render ``n_clips`` clips into ``out_dir/clip_00000`` ...; clip i uses seed ``seed + i`` and a config
    drawn from ``split``'s ranges (``overrides``, e.g. steady=True, are passed to :meth:`SynthConfig.sample`).
    About ``steady_fraction`` of the clips (chosen by their seeds) have no lighting disturbance: a model trained
    on them sees that steady lighting, with the scene's own brightness changes, is to be left alone.
    About ``occluder_fraction`` of the clips (chosen by their seeds, independently) are forced to have a close
    occluder moment, the paper's failure case: a wall that is bright because it is near, not because the
    exposure jumped. About ``clean_seeds_fraction`` of the clips (chosen by their seeds, independently) start
    with two undisturbed frames, as the evaluation's clips do.

    ``overlay`` draws a scope's border and on-screen text onto every clip (:mod:`.overlay`).

    Finished clips with the same config and seed are kept (an interrupted run resumes). Use disjoint seed
    ranges for train and held-out sets.
    """
    out_dir = Path(out_dir)
    jobs = []
    for i in range(n_clips):
        s = seed + i
        rng = np.random.default_rng([s, 0 if split == "train" else 1])
        over = dict(overrides)
        if steady_fraction > 0 and np.random.default_rng([s, 2]).random() < steady_fraction:
            over.setdefault("steady", True)
        if occluder_fraction > 0 and np.random.default_rng([s, 3]).random() < occluder_fraction:
            over.setdefault("close_occluder", "force")
        if clean_seeds_fraction > 0 and np.random.default_rng([s, 4]).random() < clean_seeds_fraction:
            over.setdefault("undisturbed_seeds", True)
        cfg = SynthConfig.sample(rng, split=split, width=width, height=height, n_frames=n_frames, fps=fps, **over)
        flags: dict[str, Any] = {"video": video}
        if drawn_overlay(overlay) is not None:
            flags["overlay"] = overlay
        jobs.append((out_dir / f"clip_{i:05d}", cfg.to_dict(), s, flags))
    if workers <= 1 or len(jobs) <= 1:
        return [_dataset_job(j) for j in jobs]

    def sweep() -> None:  # the clip folders are this run's: what a killed worker was writing goes
        for job in jobs:
            remove_stale_temporaries(job[0])

    return list(map_in_workers(_dataset_job, jobs, workers=workers, initializer=_init_worker, on_stop=sweep))
