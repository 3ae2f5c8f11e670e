"""Structure from motion on a clip's frames (COLMAP through pycolmap), and absolute trajectory error (evo).

Why COLMAP: it is the feature-based reconstruction the paper runs on enhanced frames; pycolmap ships it as a
wheel, so no binary and no GPU are needed. Settings keep one run to seconds at the working size: SIFT on the
CPU (at most ``max_features`` per frame), sequential matching (each frame against the next ``overlap``), one
incremental mapping with a fixed random seed and ``num_threads`` threads, stopped after ``max_seconds``. With
known intrinsics (synthetic clips) the camera is a fixed PINHOLE (focal length, principal point and no
distortion never refined); otherwise COLMAP estimates a SIMPLE_RADIAL camera shared by all frames.

Scores: the fraction of the clip's frames registered in the largest model (COLMAP failing to initialise is
0 registered, not an error) and, with ground truth, the absolute trajectory error of the registered camera
centres after a Sim(3) Umeyama alignment (monocular: scale is unknown), computed by evo as the paper's
Table 1 does: RMSE, mean, median, std, min and max of the translation error, in metres.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..frames import encode_image
from ..limits import DEFAULT_FPS

APE_STATS = ("rmse", "mean", "median", "std", "min", "max")
#: Fewer registered frames than this give no ATE: a similarity fitted to 2 points leaves rotation free.
MIN_ATE_POSES = 3


@dataclass(frozen=True)
class ColmapSettings:
    """Bounds on one COLMAP run (defaults: ~5-15 s for 72 frames at 256 px on one core)."""

    max_features: int = 2048
    overlap: int = 10
    num_threads: int = 1
    max_seconds: float = 120.0
    min_model_size: int = 3
    seed: int = 0


@dataclass
class ColmapResult:
    """Outcome of one run: ``poses`` maps frame index -> camera-to-world 4x4 (the largest model's frame)."""

    total: int
    registered: int = 0
    models: int = 0
    seconds: float = 0.0
    ate: dict[str, float] | None = None
    error: str | None = None
    poses: dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def fraction(self) -> float:
        return self.registered / self.total if self.total else 0.0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("poses")
        d["fraction"] = self.fraction
        d["registered_frames"] = sorted(self.poses)
        return d


def _options(settings: ColmapSettings, K: np.ndarray | None) -> tuple[Any, Any, Any, Any, Any]:
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    if K is not None:  # COLMAP puts pixel centres at +0.5
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{K[0, 0]:.6f},{K[1, 1]:.6f},{K[0, 2] + 0.5:.6f},{K[1, 2] + 0.5:.6f}"
    else:
        reader.camera_model = "SIMPLE_RADIAL"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = settings.num_threads
    extraction.sift.max_num_features = settings.max_features
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = settings.num_threads
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = settings.overlap
    pairing.quadratic_overlap = False
    pairing.num_threads = settings.num_threads
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = settings.num_threads
    mapping.random_seed = settings.seed
    mapping.min_model_size = settings.min_model_size
    mapping.max_runtime_seconds = int(max(1, settings.max_seconds))
    if K is not None:
        mapping.ba_refine_focal_length = False
        mapping.ba_refine_principal_point = False
        mapping.ba_refine_extra_params = False
        mapping.mapper.abs_pose_refine_focal_length = False
        mapping.mapper.abs_pose_refine_extra_params = False
    return reader, extraction, matching, pairing, mapping


def run_colmap(
    frames: Sequence[np.ndarray],
    K: np.ndarray | None = None,
    gt_poses: Sequence[np.ndarray] | None = None,
    fps: float = DEFAULT_FPS,
    settings: ColmapSettings = ColmapSettings(),
) -> ColmapResult:
    """Reconstruct ``frames`` (RGB uint8, in order) with COLMAP; ATE against ``gt_poses`` when given.

    ``K``: pinhole intrinsics with pixel centres at integer coordinates (fixed), or ``None`` (estimated).
    ``gt_poses``: camera-to-world 4x4 per frame. Work files live in a temporary folder, removed afterwards.
    """
    import pycolmap

    t0 = time.perf_counter()
    level = pycolmap.logging.minloglevel
    # COLMAP logs every step, and "failed to create any sparse model" as an error: both are results here
    pycolmap.logging.minloglevel = 3
    try:
        return _run(frames, K, gt_poses, fps, settings, t0)
    finally:
        pycolmap.logging.minloglevel = level


def _run(
    frames: Sequence[np.ndarray],
    K: np.ndarray | None,
    gt_poses: Sequence[np.ndarray] | None,
    fps: float,
    settings: ColmapSettings,
    t0: float,
) -> ColmapResult:
    import pycolmap

    result = ColmapResult(total=len(frames))
    reader, extraction, matching, pairing, mapping = _options(settings, K)
    with tempfile.TemporaryDirectory(prefix="colonlight-colmap-") as tmp:
        work = Path(tmp)
        images = work / "images"
        images.mkdir()
        for i, f in enumerate(frames):
            (images / f"{i:06d}.png").write_bytes(encode_image(f, "png"))
        db = work / "database.db"
        try:
            pycolmap.extract_features(
                db,
                images,
                camera_mode=pycolmap.CameraMode.SINGLE,
                reader_options=reader,
                extraction_options=extraction,
                device=pycolmap.Device.cpu,
            )
            pycolmap.match_sequential(
                db, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu
            )
            (work / "sparse").mkdir()
            models = pycolmap.incremental_mapping(db, images, work / "sparse", options=mapping)
        except Exception as exc:  # noqa: BLE001 - COLMAP's own failures are a result (0 registered), not a crash
            result.error = f"{type(exc).__name__}: {exc}".splitlines()[0]
            models = {}
        result.models = len(models)
        if models:
            best = max(models.values(), key=lambda r: r.num_reg_images())
            for image in best.images.values():
                if image.has_pose:
                    cam_from_world = np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]])
                    result.poses[int(Path(image.name).stem)] = np.linalg.inv(cam_from_world)
            result.registered = len(result.poses)
    if gt_poses is not None and len(result.poses) >= MIN_ATE_POSES:
        try:
            result.ate = ate_statistics(result.poses, gt_poses, fps)
        except ValueError as exc:  # e.g. every registered frame taken while the scope stood still
            result.error = f"ATE not computable: {exc}"
    result.seconds = time.perf_counter() - t0
    return result


def ate_statistics(
    estimated: dict[int, np.ndarray], ground_truth: Sequence[np.ndarray], fps: float = DEFAULT_FPS
) -> dict[str, float]:
    """Absolute trajectory error (translation, metres) of ``estimated`` frame poses against ``ground_truth``.

    Both are camera-to-world 4x4; frames are associated by index (as timestamps ``index / fps``), the estimate
    is aligned to the ground truth with a Sim(3) Umeyama fit (rotation, translation, scale), then evo's APE on
    the translation part gives rmse, mean, median, std, min and max.
    """
    from evo.core import metrics, sync
    from evo.core.geometry import GeometryException
    from evo.core.trajectory import PoseTrajectory3D

    index = sorted(i for i in estimated if 0 <= i < len(ground_truth))
    if len(index) < MIN_ATE_POSES:
        raise ValueError(f"ATE needs at least {MIN_ATE_POSES} poses, got {len(index)}")
    stamps = np.array(index, dtype=np.float64) / fps
    ref = PoseTrajectory3D(poses_se3=[np.asarray(ground_truth[i], np.float64) for i in index], timestamps=stamps)
    est = PoseTrajectory3D(poses_se3=[np.asarray(estimated[i], np.float64) for i in index], timestamps=stamps)
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.25 / fps)
    try:
        est.align(ref, correct_scale=True)
    except GeometryException as exc:
        raise ValueError(f"Sim(3) alignment impossible ({exc}): positions coincide or lie on a line") from exc
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    stats = ape.get_all_statistics()
    return {k: float(stats[k]) for k in APE_STATS}


__all__ = ["APE_STATS", "ColmapResult", "ColmapSettings", "ate_statistics", "run_colmap"]
