"""`colonlight evaluate`'s parts on cases with known answers: flicker of a gain jump, exposure fractions,
motion-compensated SSIM of a scene with known geometry and motion, ATE of a trajectory with a known error,
COLMAP on a textured clip, the tracker through the runner, every method through the runner, the report."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from colonlight.checkpoint import load_weights
from colonlight.evaluation.clips import (
    EvalClip,
    benchmark_config,
    find_clips,
    load_synthetic_clip,
    make_benchmark,
    scale_intrinsics,
)
from colonlight.evaluation.colmap import ate_statistics, run_colmap
from colonlight.evaluation.consistency import (
    Correspondence,
    depth_correspondences,
    exposure_fractions,
    flow_correspondences,
    motion_compensated_ssim,
)
from colonlight.evaluation.report import write_report
from colonlight.evaluation.runner import EvalMethod, evaluate_clip, evaluate_clips, method_list, summarize
from colonlight.methods import available_methods
from colonlight.metrics import content_masks

from ...conftest import AUTHORS_CKPT
from ...outputs import tree_bytes

# ------------------------------------------------------------------------------------ a scene we know exactly

# A box seen from inside: planes n.X = c (metres), each with two in-plane texture axes. Scaled to colon size
# (walls 20-40 mm from the camera) so the tracker's thresholds (2 mm, 3 degrees) mean what they mean there.
_PLANES = [
    ((0, 0, 1.0), 0.036, (1.0, 0, 0), (0, 1.0, 0)),  # back wall
    ((0, 1.0, 0), 0.0105, (1.0, 0, 0), (0, 0, 1.0)),  # floor
    ((1.0, 0, 0), -0.015, (0, 0, 1.0), (0, 1.0, 0)),  # left wall
]
_TEXEL_M = 2e-4  # texture detail well above the pixel size at 20-36 mm, so resampling costs little


def _texture(seed: int = 0, size: int = 512) -> np.ndarray:
    """Smooth random texture in [0, 1] (three octaves of blurred noise): SIFT and gradients find plenty."""
    rng = np.random.default_rng(seed)
    t = np.zeros((size, size), np.float32)
    for sigma, weight in ((1.5, 0.5), (4.0, 0.8), (12.0, 1.0)):
        n = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), sigma)
        t += weight * n / n.std()
    return (t - t.min()) / (t.max() - t.min())


def _render(pose: np.ndarray, K: np.ndarray, w: int, h: int, tex: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RGB uint8 frame and z-depth (metres) of the box from camera-to-world ``pose`` (ray casting)."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ pose[:3, :3].T
    centre = pose[:3, 3]
    depth = np.full((h, w), np.inf)
    grey = np.zeros((h, w), np.float32)
    size = tex.shape[0]
    for k, (n, c, e1, e2) in enumerate(_PLANES):
        n, e1, e2 = np.array(n), np.array(e1), np.array(e2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (c - centre @ n) / (rays @ n)
        hit = (t > 0) & (t < depth)
        p = centre + t[..., None] * rays
        a = ((p @ e1) / _TEXEL_M + size / 2 + 100 * k) % size
        b = ((p @ e2) / _TEXEL_M + size / 2) % size
        val = cv2.remap(tex, a.astype(np.float32), b.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        grey = np.where(hit, val, grey)
        depth = np.where(hit, t, depth)  # rays have z = 1 in the camera: t is the z-depth
    rgb = np.stack([grey * 200 + 30, grey * 150 + 40, grey * 120 + 30], -1)
    return np.clip(rgb, 0, 255).astype(np.uint8), depth.astype(np.float32)


def _rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    a, b = np.deg2rad(yaw_deg), np.deg2rad(pitch_deg)
    ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return ry @ rx


def box_clip(n: int = 12, w: int = 160, h: int = 120) -> EvalClip:
    """The camera slides sideways (0.9 mm/frame), forward and down along a curve, turning 1 degree per frame."""
    K = np.array([[0.8 * w, 0, (w - 1) / 2], [0, 0.8 * w, (h - 1) / 2], [0, 0, 1.0]])
    tex = _texture()
    frames, depths, poses = [], [], []
    for i in range(n):
        pose = np.eye(4)
        pose[:3, :3] = _rotation(-8 + i, 5)
        pose[:3, 3] = np.array([0.03 * i, 0.002 * i * i, 0.02 * i]) * 0.03
        f, d = _render(pose, K, w, h, tex)
        frames.append(f)
        depths.append(d)
        poses.append(pose)
    return EvalClip("box", "analytic", frames, 18.0, depths=depths, poses=poses, K=K)


@pytest.fixture(scope="module")
def box() -> EvalClip:
    return box_clip()


# ------------------------------------------------------------------------------------------------- flicker


def test_flicker_of_a_known_gain_jump() -> None:
    """Grey 100 for 5 frames, then 150: one jump of 50/255 over 9 consecutive pairs. A fixed gamma maps both
    levels through its lookup table, so its flicker is the jump between the two mapped levels."""
    frames = [np.full((32, 48, 3), 100 if i < 5 else 150, np.uint8) for i in range(10)]
    clip = EvalClip("jump", "constructed", frames)
    methods = [(EvalMethod.of("none", "none"), EvalMethod.of("none", "none").build())]
    gamma = EvalMethod.of("gamma 2", "gamma", gamma=2.0)
    methods.append((gamma, gamma.build()))
    record, _ = evaluate_clip(clip, methods, colmap=False, tracker=False)
    none, g2 = record.results["none"], record.results["gamma 2"]
    assert none.flicker_in == pytest.approx(50 / 255 / 9, abs=1e-6)
    assert none.flicker_out == pytest.approx(none.flicker_in, abs=1e-9)
    lo, hi = (round(255 * (x / 255) ** 2.0) for x in (100, 150))
    assert g2.flicker_out == pytest.approx((hi - lo) / 255 / 9, abs=1e-6)
    assert none.luma_out[:5] == pytest.approx([100 / 255] * 5, abs=1e-6)
    assert none.luma_out[5:] == pytest.approx([150 / 255] * 5, abs=1e-6)


def test_methods_are_scored_on_what_enhance_writes_inside_a_border() -> None:
    """A round field of view on black: `evaluate` shows the methods the content area, as `colonlight enhance` does
    (``content="auto"``, the default), so a clip's scores are those of the frames `enhance` writes; ``full``
    scores the method seeing the whole frame, and the choice is recorded."""
    from colonlight import enhance_frames
    from colonlight.metrics import mean_luma

    rng = np.random.default_rng(3)
    disc = np.zeros((96, 128), np.uint8)
    cv2.circle(disc, (64, 48), 44, 1, -1)
    frames = [
        (np.clip(rng.normal(90 + 5 * i, 30, (96, 128, 1)), 0, 255) * [1.0, 0.6, 0.5] * disc[..., None]).astype(np.uint8)
        for i in range(20)
    ]
    clip = EvalClip("disc", "constructed", frames)
    masks = content_masks(frames)
    luma: dict[str, list[float]] = {}
    for content in ("auto", "full"):
        result = evaluate_clips([clip], method_list(["rnn"]), colmap=False, tracker=False, content=content)
        assert result.settings["content"] == content
        luma[content] = result.clips[0].results["rnn (ours)"].luma_out
        written = [r.frame for r in enhance_frames(frames, "rnn", content=content, device="cpu")]
        assert luma[content] == pytest.approx([float(x) for x in mean_luma(written, masks)], abs=1e-9)
    # seen whole, the border drives the network towards brightening (session 26)
    assert np.mean(luma["full"]) > np.mean(luma["auto"]) + 0.05, (np.mean(luma["full"]), np.mean(luma["auto"]))


def test_exposure_fractions_on_constructed_frames() -> None:
    """A quarter of the content dark (12/255) in the input; the output lifts it to 60 and blows a quarter of
    the image to 250 (content: input luma <= 0.7, so the input's mid-grey counts and nothing is border)."""
    inp = np.full((40, 40, 3), 128, np.uint8)
    inp[:10] = 12
    out = inp.copy()
    out[:10] = 60
    out[10:20] = 250
    masks = content_masks([inp, inp])
    assert masks[0].all()
    assert exposure_fractions([inp, inp], masks) == pytest.approx((0.25, 0.0))
    assert exposure_fractions([out, out], masks) == pytest.approx((0.0, 0.25))
    speck = inp.copy()
    speck[30:] = 240  # specular in the input: not content, so not counted as over-exposure introduced
    m = content_masks([speck])
    assert exposure_fractions([speck], m)[1] == 0.0
    assert m[0].sum() == 30 * 40


# ------------------------------------------------------------------------------- motion-compensated SSIM


def _identity(h: int, w: int) -> Correspondence:
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return Correspondence(u, v, np.ones((h, w), bool))


def test_depth_warp_of_known_motion_gives_ssim_one(box: EvalClip) -> None:
    frames = box.frames[:4]
    assert box.depths is not None and box.poses is not None and box.K is not None
    corrs = depth_correspondences(box.depths[:4], box.poses[:4], box.K)
    masks = content_masks(frames)
    assert all(c.valid.mean() > 0.8 for c in corrs)
    warped = motion_compensated_ssim(frames, corrs, masks)
    raw = motion_compensated_ssim(frames, [_identity(*frames[0].shape[:2])] * 3, masks)
    assert np.all(warped > 0.98), warped  # equal up to bilinear resampling and 8-bit rounding
    assert np.all(raw < 0.8), raw  # without motion compensation the texture does not line up
    dimmed = [frames[0], (frames[1] * 0.6).astype(np.uint8), frames[2], frames[3]]
    lit = motion_compensated_ssim(dimmed, corrs, masks)
    assert lit[0] < warped[0] - 0.1 and lit[1] < warped[1] - 0.1  # the change enters and leaves
    assert lit[2] == pytest.approx(warped[2])


def test_flow_correspondence_compensates_known_motion(box: EvalClip) -> None:
    frames = box.frames[:3]
    masks = content_masks(frames)
    corrs = flow_correspondences(frames)
    assert all(c.valid.mean() > 0.7 for c in corrs)
    flow = motion_compensated_ssim(frames, corrs, masks)
    assert np.all(flow > 0.9), flow
    gained = [frames[0], np.clip(frames[1] * 1.4, 0, 255).astype(np.uint8), frames[2]]
    # the flow is computed on equalised input, so a global gain barely moves it ...
    moved = flow_correspondences(gained)
    assert np.median(np.hypot(moved[0].map_x - corrs[0].map_x, moved[0].map_y - corrs[0].map_y)) < 0.3
    # ... and the gain itself lowers the score
    assert motion_compensated_ssim(gained, corrs, masks)[0] < flow[0] - 0.05


# ---------------------------------------------------------------------------------------- synthetic clips


def test_synthetic_clip_loads_at_working_size(tmp_path: Path) -> None:
    from colonlight.synth import SynthConfig, write_clip

    cfg = SynthConfig.sample(np.random.default_rng(3), split="heldout", width=96, height=72, n_frames=5, steady=True)
    folder = write_clip(tmp_path / "s", cfg, 3, video=False)
    full = load_synthetic_clip(folder, max_size=None)
    half = load_synthetic_clip(folder, max_size=48)
    assert full.frames[0].shape == (72, 96, 3) and half.frames[0].shape == (36, 48, 3)
    assert half.depths is not None and half.depths[0].shape == (36, 48) and len(half.poses or []) == 5
    assert half.K is not None and full.K is not None
    assert half.K[0, 0] == pytest.approx(full.K[0, 0] / 2) and half.K[0, 2] == pytest.approx((full.K[0, 2] - 0.5) / 2)
    assert half.meta["scale"] == 0.5 and half.meta["original_size"] == [96, 72]
    assert half.clean is not None and len(half.clean) == 5
    # the lighting ground truth comes along (the failure breakdown reads it)
    assert half.lighting is not None and len(half.lighting) == 5
    assert {"gain", "contrast", "exposure", "close_occluder"} <= set(half.lighting[0])
    assert half.meta["camera_gamma"] > 0
    # motion compensation stays exact at the working size: steady lighting, so MC-SSIM is high
    corrs = depth_correspondences(half.depths, half.poses or [], half.K)
    ssim = motion_compensated_ssim(half.frames, corrs, content_masks(half.frames))
    raw = motion_compensated_ssim(half.frames, [_identity(36, 48)] * 4, content_masks(half.frames))
    assert np.nanmean(ssim) > np.nanmean(raw)


def test_scale_intrinsics_keeps_pixel_centres() -> None:
    K = np.array([[100.0, 0, 63.5], [0, 100.0, 47.5], [0, 0, 1]])
    k2 = scale_intrinsics(K, 0.5, 0.5)
    assert k2[0, 2] == pytest.approx(31.5) and k2[1, 2] == pytest.approx(23.5) and k2[0, 0] == 50.0


def test_find_clips_takes_a_synthetic_folder_as_one_clip(tmp_path: Path) -> None:
    from colonlight.video import VideoWriter

    refs = make_benchmark(tmp_path / "bench", 1, seed0=800_000, frames=4, size=48)
    with VideoWriter(tmp_path / "bench" / "user.mp4", fps=18) as w:
        for i in range(4):
            w.write(np.full((32, 32, 3), 40 * i, np.uint8))
    found = find_clips([tmp_path / "bench"])
    assert sorted((r.name, r.kind) for r in found) == [("clip_00000", "synthetic"), ("user", "video")]
    assert refs[0].path == found[0].path


def test_benchmark_plan_and_reuse(tmp_path: Path) -> None:
    cfgs = [benchmark_config(i, 800_000 + i, 60, 64, family="heldout") for i in range(6)]
    assert [c.close_occluder for c in cfgs] == ["force", "forbid", "forbid"] * 2
    assert all(c.split == "heldout" and c.fps == 18 and c.n_frames == 60 for c in cfgs)
    default = benchmark_config(0, 800_000, 60, 64)
    assert default.split == "train" and default.heldout_params == ()
    seen: list[tuple[str, bool]] = []
    make_benchmark(tmp_path, 2, frames=3, size=32, on_clip=lambda p, new: seen.append((p.name, new)))
    make_benchmark(tmp_path, 2, frames=3, size=32, on_clip=lambda p, new: seen.append((p.name, new)))
    assert seen == [("clip_00000", True), ("clip_00001", True), ("clip_00000", False), ("clip_00001", False)]
    meta = json.loads((tmp_path / "clip_00001" / "synth.json").read_text())
    assert meta["seed"] == 800_001 and meta["config"]["undisturbed_seeds"] is True
    # two render workers give the same clips, in the same order
    seen.clear()
    make_benchmark(
        tmp_path / "pool", 2, frames=3, size=32, workers=2, on_clip=lambda p, new: seen.append((p.name, new))
    )
    assert seen == [("clip_00000", True), ("clip_00001", True)]
    assert tree_bytes(tmp_path / "pool") == {k: v for k, v in tree_bytes(tmp_path).items() if not k.startswith("pool/")}


# ------------------------------------------------------------------------------------------ ATE and COLMAP


def _circle(n: int = 8, r: float = 0.1) -> list[np.ndarray]:
    poses = []
    for k in range(n):
        a = 2 * np.pi * k / n
        p = np.eye(4)
        p[:3, :3] = _rotation(np.rad2deg(a), 0)
        p[:3, 3] = [r * np.cos(a), r * np.sin(a), 0.0]
        poses.append(p)
    return poses


def _similarity(poses: list[np.ndarray], scale: float) -> list[np.ndarray]:
    s = np.eye(4)
    s[:3, :3] = _rotation(30, 20)
    s[:3, 3] = [1.0, -2.0, 0.5]
    out = []
    for p in poses:
        q = s @ p
        q[:3, 3] = s[:3, :3] @ (scale * p[:3, 3]) + s[:3, 3]
        out.append(q)
    return out


def test_ate_of_a_known_error() -> None:
    """Ground truth on a circle of radius r in z = 0; the estimate alternates +-d along z (uncorrelated with
    the circle, so no similarity explains it) and is then moved, turned and scaled by 2.5. After Sim(3)
    alignment every error has length sqrt(((1-c) r)^2 + (c d)^2), c = r^2 / (r^2 + d^2): all statistics equal
    that (~d) and the std is 0."""
    gt, r, d = _circle(8, 0.1), 0.1, 0.001
    est = []
    for k, p in enumerate(gt):
        q = p.copy()
        q[2, 3] += d if k % 2 == 0 else -d
        est.append(q)
    stats = ate_statistics(dict(enumerate(_similarity(est, 2.5))), gt)
    c = r**2 / (r**2 + d**2)
    expected = math.hypot((1 - c) * r, c * d)
    for key in ("rmse", "mean", "median", "min", "max"):
        assert stats[key] == pytest.approx(expected, rel=1e-6), key
    assert stats["std"] == pytest.approx(0.0, abs=1e-9)
    exact = ate_statistics(dict(enumerate(_similarity(gt, 0.3))), gt)
    assert exact["max"] < 1e-9  # a pure similarity is aligned away entirely


def test_ate_needs_three_non_collinear_poses() -> None:
    gt = _circle(8)
    with pytest.raises(ValueError, match="at least 3"):
        ate_statistics({0: gt[0], 1: gt[1]}, gt)
    line = [np.eye(4) for _ in range(4)]
    for i, p in enumerate(line):
        p[0, 3] = i
    with pytest.raises(ValueError, match="line"):
        ate_statistics(dict(enumerate(line)), line)


def test_colmap_registers_a_textured_clip(box: EvalClip) -> None:
    """COLMAP through pycolmap on 12 frames (160x120) of the textured box: (nearly) all registered, and the
    ATE a small fraction of the 14 mm the camera travels."""
    result = run_colmap(box.frames, box.K, box.poses, box.fps)
    assert result.error is None
    assert result.registered >= 10 and result.fraction >= 10 / 12
    assert result.ate is not None and result.ate["rmse"] < 2e-4  # metres; the camera moves ~1.5 mm
    d = result.to_dict()
    assert d["fraction"] == result.fraction and "poses" not in d and len(d["registered_frames"]) == result.registered


def test_colmap_failing_to_initialise_is_zero_registered() -> None:
    flat = [np.full((64, 64, 3), 90, np.uint8)] * 4
    result = run_colmap(flat, None, None)
    assert result.registered == 0 and result.fraction == 0.0 and result.ate is None


# -------------------------------------------------------------------------------------- tracker and runner


def _gain_jump(box: EvalClip, gain: float = 0.7, start: int = 6) -> EvalClip:
    """The box clip darkened by ``gain`` from frame ``start`` on, with the box itself as its clean frames and the
    jump recorded as lighting ground truth (as a synthetic clip's lighting.json records it)."""
    gains = [1.0 if i < start else gain for i in range(len(box.frames))]
    return EvalClip(
        "box-jump", "analytic", [np.rint(f * g).astype(np.uint8) for f, g in zip(box.frames, gains, strict=True)],
        depths=box.depths, poses=box.poses, K=box.K, clean=box.frames,
        lighting=[{"gain": g, "contrast": 1.0, "exposure": 1.0, "close_occluder": False} for g in gains],
    )  # fmt: skip


def test_tracker_through_the_runner_on_known_motion(box: EvalClip) -> None:
    """The photometric tracker follows the box's known motion under the success threshold in both brightness
    settings; after a gain jump in the middle of the clip only fitted brightness (affine) absorbs it."""
    jump = _gain_jump(box)
    jump.clean = None
    none = EvalMethod.of("none", "none")
    for clip in (box, jump):
        record, _ = evaluate_clip(clip, [(none, none.build())], colmap=False, tracker=True)
        tracking = record.results["none"].tracking
        assert tracking is not None and set(tracking) == {"fixed", "affine"}
        for mode, t in tracking.items():
            assert t["applicable"] and t["brightness"] == mode
            if clip is jump and mode == "fixed":
                assert not t["success"] and t["failed_at"] == 6 and t["tracked_fraction"] < 0.6
                continue
            assert t["success"] and t["failed_at"] is None and t["tracked_fraction"] == 1.0, (mode, t)
            assert max(t["translation_error_m"]) < 0.002 and max(t["rotation_error_deg"]) < 3.0
        assert record.correspondence == "depth+pose"
        assert set(record.results) == {"none"} and record.input_failures == []  # no clean frames: no oracles
    record, _ = evaluate_clip(box, [(none, none.build())], colmap=False, brightness=["fixed"])
    assert set(record.results["none"].tracking or {}) == {"fixed"}
    user = EvalClip("user", "video", box.frames[:4])
    record, _ = evaluate_clip(user, [(none, none.build())], colmap=False, tracker=True)
    reason = {"applicable": False, "reason": "no depth: tracking needs a synthetic clip's known depth"}
    assert record.results["none"].tracking == {"fixed": reason, "affine": reason}
    assert record.correspondence == "optical flow"


def test_oracles_gap_closed_and_failure_breakdown_on_a_known_gain_jump(box: EvalClip) -> None:
    """Known answers: with brightness fixed the input fails from the jump on (frame 6: a gain jump; the frames
    after it follow a failure), the clean frames and both oracles track every frame and rescue all of those, a
    fixed gamma of 0.7 rescues the last two; with brightness fitted nothing fails. The gap closed is
    (method - input) / (oracle-curve - input): 0 for the input, 1 for the oracle."""
    clip = _gain_jump(box)
    specs = [EvalMethod.of("none", "none"), EvalMethod.of("gamma", "gamma", gamma=0.7)]
    result = evaluate_clips([clip], specs, colmap=False)
    assert result.labels == ["clean", "oracle-curve", "oracle-gain-gamma", "oracle-gamma", "none", "gamma"]
    (record,) = result.clips
    for label in ("clean", "oracle-curve", "oracle-gain-gamma", "oracle-gamma"):
        t = record.results[label].tracking or {}
        assert t["fixed"]["success"] and t["affine"]["success"], label
    gammas = record.results["oracle-gamma"].gammas or []
    assert gammas[:6] == pytest.approx([1.0] * 6, abs=0.01) and gammas[6:] == pytest.approx([0.7] * 6, abs=0.02)
    # a pure gain jump: the gain-gamma oracle undoes it with the gain and keeps gamma 1
    assert record.results["oracle-gain-gamma"].gammas == pytest.approx([1.0] * 12, abs=0.02)
    failures = record.input_failures
    assert [f["frame"] for f in failures] == list(range(6, 12))
    assert all(f["brightness"] == "fixed" for f in failures)  # affine: the input tracks every frame
    first = failures[0]
    assert first["cause"] == "gain jump" and first["changes"]["gain_ratio"] == pytest.approx(0.7)
    assert [f["cause"] for f in failures[1:]] == ["after a failure"] * 5
    assert all({"oracle-curve", "oracle-gain-gamma", "oracle-gamma"} <= set(f["rescued_by"]) for f in failures)
    assert [f["frame"] for f in failures if "gamma" in f["rescued_by"]] == [10, 11]

    rows = {r["method"]: r for r in summarize(result)}
    none, gamma, curve = rows["none"], rows["gamma"], rows["oracle-curve"]
    assert none["tracked_fraction_fixed"] == pytest.approx(5 / 11) and none["track_success_fixed"] == 0
    assert none["tracked_fraction_affine"] == 1.0 and none["track_success_affine"] == 1
    assert curve["tracked_fraction_fixed"] == 1.0 and curve["track_success_rate_fixed"] == 1.0
    assert none["gap_closed_tracked_fixed"] == 0.0 and curve["gap_closed_tracked_fixed"] == 1.0
    assert gamma["gap_closed_tracked_fixed"] == pytest.approx((7 / 11 - 5 / 11) / (1 - 5 / 11))
    assert gamma["gap_closed_success_fixed"] == 0.0 and curve["gap_closed_success_fixed"] == 1.0
    assert none["gap_closed_tracked_affine"] is None  # the input already tracks every frame: no gap
    assert gamma["rescued_fixed"] == 2 and gamma["rescue_rate_fixed"] == pytest.approx(2 / 6)
    assert curve["rescue_rate_fixed"] == 1.0 and curve["rescue_rate_affine"] is None
    fb = result.to_dict()["failure_breakdown"]
    assert fb["fixed"]["failures"] == 6 and fb["affine"]["failures"] == 0
    assert fb["fixed"]["causes"]["gain jump"] == 1 and fb["fixed"]["causes"]["after a failure"] == 5
    assert fb["fixed"]["rescue"]["gamma"]["by_cause"]["after a failure"] == pytest.approx(2 / 5)


def test_reference_rows_are_skipped_with_a_reason_without_clean_frames(box: EvalClip) -> None:
    result = evaluate_clips([box], [EvalMethod.of("none", "none")], colmap=False, brightness="fixed")
    assert result.labels == ["none"] and result.settings["brightness"] == ["fixed"]
    assert set(result.skipped_methods) == {"clean", "oracle-curve", "oracle-gain-gamma", "oracle-gamma"}
    assert "clean frames" in result.skipped_methods["clean"]
    (row,) = summarize(result)
    assert row["track_success_fixed"] == 1 and row["track_success_affine"] is None
    assert row["gap_closed_tracked_fixed"] is None  # no oracle to measure the gap against
    with pytest.raises(ValueError, match="brightness"):
        evaluate_clips([box], [EvalMethod.of("none", "none")], colmap=False, brightness="mode2")


def test_failure_causes_from_lighting_ground_truth() -> None:
    from colonlight.evaluation.breakdown import classify

    steady = {"gain": 1.0, "contrast": 1.0, "exposure": 1.0}
    assert classify(steady, {**steady, "gain": 1.6}, 0.0)["cause"] == "gain jump"
    assert classify(steady, {**steady, "contrast": 1.3}, 0.0)["cause"] == "tone-curve change"
    # exposure counts through exposure ** (contrast / camera_gamma): x2 at gamma 2.2 is x1.37 in display
    lag = classify(steady, {**steady, "exposure": 2.0}, 0.0, camera_gamma=2.2)
    assert lag["cause"] == "exposure lag" and lag["changes"]["exposure_ratio"] == pytest.approx(2 ** (1 / 2.2))
    assert classify(steady, {**steady, "gain": 1.05}, 0.0)["cause"] == "other"  # below the 10 % threshold
    assert classify(steady, steady, 0.0, after_failure=True)["cause"] == "after a failure"
    both = classify(steady, {**steady, "gain": 1.2, "contrast": 1.5}, 0.2)
    assert both["cause"] == "saturation" and both["causes"] == [
        "saturation",
        "tone-curve change",
        "gain jump",
    ]
    near = classify({**steady, "close_occluder": True}, {**steady, "gain": 2.0}, 0.0)
    assert near["cause"] == "close occluder" and "gain jump" in near["causes"]


@pytest.fixture(scope="module")
def all_methods_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[object, Path]:
    """Every available method (and the authors' checkpoint when present) on one small held-out clip."""
    root = tmp_path_factory.mktemp("bench")
    refs = make_benchmark(root / "clips", 1, seed0=800_000, frames=10, size=80)
    refs.append(find_clips([root / "missing.mp4"])[0])  # a clip that fails to load
    names = available_methods()
    methods = method_list(names, AUTHORS_CKPT if AUTHORS_CKPT.is_file() else None)
    methods.append(EvalMethod.of("rnn (absent checkpoint)", "rnn", weights=str(root / "nope.pth")))
    result = evaluate_clips(refs, methods, colmap=False, tracker=True)
    return result, root


def test_every_method_through_the_runner(all_methods_run: tuple) -> None:
    result, _ = all_methods_run
    assert [f["clip"] for f in result.failures] == ["missing"]
    assert "missing.mp4" in result.failures[0]["error"]
    assert "rnn (absent checkpoint)" in result.skipped_methods
    from colonlight.methods.zerodce import DEFAULT_WEIGHTS

    for name in ("zerodce", "zerodce++"):  # not shipped unless trained: a one-line reason, no traceback
        if not DEFAULT_WEIGHTS[name].is_file():
            assert "weights are missing" in result.skipped_methods[name]
            assert "\n" not in result.skipped_methods[name]
    (clip,) = result.clips
    assert set(clip.results) == set(result.labels)
    assert result.labels[:4] == ["clean", "oracle-curve", "oracle-gain-gamma", "oracle-gamma"]  # it has clean frames
    assert {"none", "he", "clahe", "agcwd", "deflicker", "gamma", "rnn (ours)"} <= set(result.labels)
    for label, r in clip.results.items():
        assert r.error is None, (label, r.error)
        assert r.frames == 10 and len(r.luma_out) == 10 and len(r.ssim_series) == 9
        for v in (r.flicker_out, r.ssim_out, r.dark_out, r.bright_out, r.ms_per_frame):
            assert math.isfinite(v), label
        assert r.tracking is not None and set(r.tracking) == {"fixed", "affine"}
        for t in r.tracking.values():
            assert t["applicable"] and isinstance(t["success"], bool) and 0.0 <= t["tracked_fraction"] <= 1.0
    none = clip.results["none"]
    assert none.flicker_out == none.flicker_in and none.ssim_out == none.ssim_in and none.dark_out == none.dark_in
    rnn = clip.results["rnn (ours)"]
    seeds = _shipped_seed_frames()  # written unchanged (gamma 1): 2 for the paper's head, 0 for a restoring model
    assert rnn.gammas is not None and len(rnn.gammas) == 10 and rnn.gammas[:seeds] == [1.0] * seeds
    assert clip.results["he"].gammas is None
    rows = {r["method"]: r for r in summarize(result)}
    assert rows["none"]["tracked"] == 1 and rows["none"]["colmap_clips"] == 0 and rows["none"]["clips"] == 1
    assert result.failed  # a clip could not be loaded


def test_report_files_are_complete_and_self_contained(all_methods_run: tuple) -> None:
    result, root = all_methods_run
    paths = write_report(result, root / "report", command="colonlight evaluate --synthetic 1")
    for p in paths.values():
        assert p.is_file() and p.stat().st_size > 0
    assert not list((root / "report").glob(".*"))  # no temporaries left
    record = json.loads(paths["json"].read_text(), parse_constant=lambda c: pytest.fail(f"non-JSON {c}"))
    prov = record["provenance"]
    assert prov["command"] == "colonlight evaluate --synthetic 1" and prov["colonlight_version"]
    assert {"pycolmap", "evo", "scikit-image"} <= set(prov["versions"])
    rnn = next(m for m in record["methods"] if m["label"] == "rnn (ours)")
    assert len(rnn["model"]["sha256"]) == 64 and rnn["parameters"]["model_size"] == load_weights().input_size
    seeds = _shipped_seed_frames()
    assert record["clips"][0]["results"]["rnn (ours)"]["gammas"][:seeds] == [1.0] * seeds
    md = paths["markdown"].read_text()
    for label in result.labels:
        assert f"| {label} |" in md
    assert "Definitions" in md and "missing" in md
    header = paths["csv"].read_text().splitlines()[0].split(",")
    assert header[:3] == ["method", "clips", "frames"] and "ate_rmse_m" in header
    assert len(paths["csv"].read_text().splitlines()) == 1 + len(result.labels)
    page = paths["html"].read_text()
    assert page.count("data:image/png;base64,") >= 2  # success bars + the clip's luminance/gamma plot
    # before/after strips: the input, the clean frames, then each method but `none` (the input itself) and the
    # oracles
    assert page.count("data:image/jpeg;base64,") == 1 + 1 + len(result.labels) - 5
    assert "<h2>Tracking</h2>" in page and "## Tracking" in md
    for text in ("fixed: gap closed", "affine: tracked", "DSO with mode=2"):
        assert text in page and text in md
    assert md.index("fixed: success") < md.index("affine: success")  # the paper's setting leads
    assert "gap_closed_tracked_fixed" in header and "tracked_fraction_affine" in header
    assert not re.search(r"https?://|<script|<link|src=\"(?!data:)", page)


def test_an_interrupt_between_the_reports_renames_leaves_no_temporary(
    all_methods_run: tuple, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The interrupt lands as the second rename is entered: the first file is in place, the others' temporaries
    are deleted, none is left under a hidden name."""
    import colonlight.evaluation.report as report

    result, root = all_methods_run
    out = root / "interrupted-report"
    calls: list[Path] = []

    def publish_then_interrupt(tmp: Path, dest: Path) -> None:
        calls.append(dest)
        if len(calls) == 2:
            raise KeyboardInterrupt
        os.replace(tmp, dest)

    monkeypatch.setattr(report, "publish", publish_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        write_report(result, out, command="colonlight evaluate --synthetic 1")
    assert [p.name for p in out.iterdir()] == [calls[0].name]


def _shipped_seed_frames() -> int:
    """How many leading frames the shipped model passes through unchanged (its card, else the release's 2)."""
    from colonlight.checkpoint import load_weights
    from colonlight.methods.rnn import SEED_FRAMES

    seeds = load_weights().seed_frames
    return SEED_FRAMES if seeds is None else seeds
