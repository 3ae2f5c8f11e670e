"""Tests of the synthetic colonoscopy generator (colonlight.synth): determinism, ground-truth files, the
disturbance model, close occluders and a "looks like colonoscopy" sanity check. Small frames keep it quick."""

from __future__ import annotations

import json
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from colonlight.synth import (
    PARAM_SPECS,
    SynthConfig,
    SynthFrame,
    build_scene,
    decode_depth,
    encode_depth,
    generate_clip,
    make_dataset,
    write_clip,
)
from colonlight.synth.writer import read_tum, rotation_to_quaternion, tum_line

from ..faults import interrupt_after_creating

W = 64


def _cfg(seed: int, **kw: object) -> SynthConfig:
    kw.setdefault("width", W)
    kw.setdefault("height", W)
    kw.setdefault("n_frames", 10)
    return SynthConfig.sample(np.random.default_rng(seed), **kw)  # type: ignore[arg-type]


def _clip(cfg: SynthConfig, seed: int) -> list[SynthFrame]:
    return list(generate_clip(cfg, seed))


def _quat_to_rot(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# ------------------------------------------------------------------------------------------------ config


def test_heldout_ranges_are_disjoint_from_train() -> None:
    for name, spec in PARAM_SPECS.items():
        lo, hi = spec.train
        for a, b in spec.heldout:
            assert b <= lo or a >= hi, name


def test_sample_respects_split_ranges() -> None:
    for s in range(20):
        tr = SynthConfig.sample(np.random.default_rng(s), split="train")
        assert tr.heldout_params == ()
        for name, spec in PARAM_SPECS.items():
            v = getattr(tr, name)
            assert v == 0.0 or spec.train[0] - 1e-9 <= v <= spec.train[1] + 1e-9, name
        ho = SynthConfig.sample(np.random.default_rng(s), split="heldout")
        assert len(ho.heldout_params) >= 2
        for name in ho.heldout_params:
            v = getattr(ho, name)
            assert any(a - 1e-9 <= v <= b + 1e-9 for a, b in PARAM_SPECS[name].heldout), name


def test_config_roundtrip_and_validation() -> None:
    cfg = _cfg(3, close_occluder=True)
    assert cfg.close_occluder == "force"
    assert SynthConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ValueError):
        SynthConfig(close_occluder="sometimes")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        SynthConfig.from_dict({"no_such_field": 1})


# ------------------------------------------------------------------------------------------------ determinism


def test_same_seed_same_bytes_different_seed_differs() -> None:
    cfg = _cfg(1, n_frames=4)
    a, b = _clip(cfg, 7), _clip(cfg, 7)
    for fa, fb in zip(a, b, strict=True):
        assert fa.image.tobytes() == fb.image.tobytes()
        assert fa.clean.tobytes() == fb.clean.tobytes()
        assert fa.depth.tobytes() == fb.depth.tobytes()
        assert np.array_equal(fa.pose, fb.pose)
        assert fa.lighting == fb.lighting
    c = _clip(cfg, 8)
    assert not np.array_equal(a[0].clean, c[0].clean)


def test_frame_types_and_pose_validity() -> None:
    cfg = _cfg(2, n_frames=5, fps=25.0)
    for i, f in enumerate(generate_clip(cfg, 2)):
        assert f.image.shape == (W, W, 3) and f.image.dtype == np.uint8
        assert f.clean.shape == (W, W, 3) and f.clean.dtype == np.uint8
        assert f.depth.shape == (W, W) and f.depth.dtype == np.float32
        assert np.all((f.depth > 0) | ~np.isfinite(f.depth))
        r = f.pose[:3, :3]
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(r), 1.0)
        assert f.time_s == pytest.approx(i / 25.0)
        assert set(f.lighting) >= {"gain", "contrast", "exposure", "disturbed"}


def test_depth_is_on_the_wall() -> None:
    """Back-projected depth lands on the tube wall (depth is z-depth in metres, pose camera-to-world)."""
    cfg = _cfg(4, n_frames=3)
    scene = build_scene(cfg, 4)
    f = next(generate_clip(cfg, 4))
    intr = scene.intrinsics
    v, u = np.mgrid[0:W:7, 0:W:7]
    z = f.depth[v, u]
    ok = np.isfinite(z)
    x = (u - intr.cx) / intr.fx * z
    y = (v - intr.cy) / intr.fy * z
    pc = np.stack([x[ok], y[ok], z[ok]], axis=1)
    pw_mm = (pc @ f.pose[:3, :3].T + f.pose[:3, 3]) * 1000.0
    (F,) = scene.tube.evaluate(pw_mm.astype(np.float32))
    assert ok.mean() > 0.5
    assert np.median(np.abs(F)) < 0.1 and np.percentile(np.abs(F), 95) < 0.6


# ------------------------------------------------------------------------------------------------ files


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SynthConfig, list[SynthFrame]]:
    cfg = _cfg(5, n_frames=12, fps=18.0, undisturbed_seeds=True)
    out = write_clip(tmp_path_factory.mktemp("clip") / "c", cfg, 5, video=True, frames=True)
    return out, cfg, _clip(cfg, 5)


def test_written_files_are_consistent(written: tuple[Path, SynthConfig, list[SynthFrame]]) -> None:
    out, cfg, frames = written
    n = cfg.n_frames
    for sub in ("frames", "clean", "depth"):
        assert sorted(p.name for p in (out / sub).iterdir()) == [f"{i:06d}.png" for i in range(n)]
    lines = (out / "poses.txt").read_text().splitlines()
    assert len(lines) == n
    for i, line in enumerate(lines):
        vals = np.array([float(x) for x in line.split()])
        assert len(vals) == 8
        assert vals[0] == pytest.approx(i / cfg.fps, abs=1e-6)
        q = vals[4:]
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-6)
        assert np.allclose(_quat_to_rot(q), frames[i].pose[:3, :3], atol=1e-6)
        assert np.allclose(vals[1:4], frames[i].pose[:3, 3], atol=1e-8)
    intr = json.loads((out / "intrinsics.json").read_text())
    assert {"fx", "fy", "cx", "cy", "width", "height"} <= set(intr) and intr["width"] == W
    light = json.loads((out / "lighting.json").read_text())
    assert len(light["frames"]) == n
    meta = json.loads((out / "synth.json").read_text())
    assert meta["seed"] == 5 and meta["config"] == json.loads(json.dumps(cfg.to_dict()))
    assert meta["generator_version"] and "colonlight_version" in meta
    # the PNGs hold exactly what the iterator yields
    for i in (0, n - 1):
        img = cv2.cvtColor(cv2.imread(str(out / "frames" / f"{i:06d}.png")), cv2.COLOR_BGR2RGB)
        assert np.array_equal(img, frames[i].image)
        dep = decode_depth(cv2.imread(str(out / "depth" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED))
        fin = np.isfinite(frames[i].depth)
        assert np.array_equal(np.isfinite(dep), fin)
        assert np.allclose(dep[fin], frames[i].depth[fin], atol=1e-4)


def test_video_decodes_to_all_frames(written: tuple[Path, SynthConfig, list[SynthFrame]]) -> None:
    out, cfg, frames = written
    with av.open(str(out / "clip.mp4")) as c:
        dec = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(dec) == cfg.n_frames
    assert np.abs(dec[3].astype(int) - frames[3].image.astype(int)).mean() < 8  # lossy, but the same picture


def test_undisturbed_seeds(written: tuple[Path, SynthConfig, list[SynthFrame]]) -> None:
    _, _, frames = written
    for f in frames[:2]:
        assert np.array_equal(f.image, f.clean)
        assert f.lighting == {**f.lighting, "gain": 1.0, "contrast": 1.0, "exposure": 1.0, "disturbed": False}
    assert any(f.lighting["disturbed"] for f in frames[2:])


def test_make_dataset_parallel_and_resume(tmp_path: Path) -> None:
    dirs = make_dataset(tmp_path, 2, seed=11, split="heldout", width=32, height=32, n_frames=3, workers=2)
    assert [d.name for d in dirs] == ["clip_00000", "clip_00001"]
    metas = [json.loads((d / "synth.json").read_text()) for d in dirs]
    assert [m["seed"] for m in metas] == [11, 12]
    assert all(m["config"]["split"] == "heldout" for m in metas)
    # a worker process renders the same bytes as this process
    cfg = SynthConfig.from_dict(metas[1]["config"])
    last = _clip(cfg, 12)[-1]
    img = cv2.cvtColor(cv2.imread(str(dirs[1] / "frames" / "000002.png")), cv2.COLOR_BGR2RGB)
    assert np.array_equal(img, last.image)
    stamp = (dirs[0] / "synth.json").stat().st_mtime_ns
    make_dataset(tmp_path, 1, seed=11, split="heldout", width=32, height=32, n_frames=3, workers=1)
    assert (dirs[0] / "synth.json").stat().st_mtime_ns == stamp  # complete clip kept


def test_make_dataset_mixes_in_steady_clips_by_seed(tmp_path: Path) -> None:
    def steady(fraction: float, where: Path, n: int = 6) -> list[bool]:
        dirs = make_dataset(where, n, seed=40, width=32, height=32, n_frames=3, workers=1, steady_fraction=fraction)
        return [json.loads((d / "synth.json").read_text())["config"]["steady"] for d in dirs]

    mixed = steady(0.5, tmp_path / "a")
    assert 0 < sum(mixed) < 6 and steady(0.5, tmp_path / "b") == mixed  # chosen by the seeds
    assert not any(steady(0.0, tmp_path / "c", 3)) and all(steady(1.0, tmp_path / "d", 3))


def test_make_dataset_forces_close_occluders_by_seed(tmp_path: Path) -> None:
    def modes(fraction: float, where: Path, n: int = 6) -> list[str]:
        dirs = make_dataset(
            where,
            n,
            seed=40,
            width=32,
            height=32,
            n_frames=3,
            workers=1,
            steady_fraction=0.5,
            occluder_fraction=fraction,
        )
        return [json.loads((d / "synth.json").read_text())["config"]["close_occluder"] for d in dirs]

    mixed = modes(0.5, tmp_path / "a")
    assert 0 < mixed.count("force") < 6 and modes(0.5, tmp_path / "b") == mixed  # chosen by the seeds
    assert set(modes(0.0, tmp_path / "c", 3)) == {"random"} and set(modes(1.0, tmp_path / "d", 3)) == {"force"}


def test_quaternion_and_depth_encoding() -> None:
    rng = np.random.default_rng(0)
    mats = [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]), np.eye(3)]
    for _ in range(20):
        q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        mats.append(q * np.sign(np.linalg.det(q)))
    for m in mats:
        assert np.allclose(_quat_to_rot(rotation_to_quaternion(m)), m, atol=1e-9)
    d = np.array([[0.0123, np.inf], [1.5, 7.0]], np.float32)
    back = decode_depth(encode_depth(d))
    assert back[0, 0] == pytest.approx(0.0123, abs=1e-4) and back[1, 0] == pytest.approx(1.5, abs=1e-4)
    assert np.isinf(back[0, 1]) and np.isinf(back[1, 1])  # beyond the 16-bit range -> no value


# ------------------------------------------------------------------------------------------------ lighting


def test_steady_clip_is_clean() -> None:
    for f in generate_clip(_cfg(6, steady=True, n_frames=6), 6):
        assert np.array_equal(f.image, f.clean)
        assert not f.lighting["disturbed"]


def test_disturbed_frames_differ_and_gain_matches_brightness() -> None:
    # contrast events off so image = clip(display_gain * clean): the ratio on unsaturated pixels is the gain
    cfg = _cfg(7, n_frames=24, gain_rate_hz=2.0, contrast_rate_hz=0.0, flicker_contrast=0.0, ae_strength=0.8)
    frames = _clip(cfg, 7)
    checked = 0
    for f in frames:
        g = f.lighting["display_gain"]
        if not f.lighting["disturbed"]:
            assert np.array_equal(f.image, f.clean)
            continue
        assert f.lighting["contrast"] == 1.0
        if abs(g - 1) > 0.05:
            assert np.abs(f.image.astype(int) - f.clean.astype(int)).mean() > 1.0
        c = f.clean.astype(float)
        im = f.image.astype(float)
        ok = (c > 25) & (c < 230) & (im > 5) & (im < 250)
        if ok.sum() > 200:
            assert np.median(im[ok] / c[ok]) == pytest.approx(g, rel=0.05)
            checked += 1
    assert checked >= 5


def test_frame_to_frame_flicker_has_the_configured_spread_and_spares_the_seeds() -> None:
    from colonlight.synth.disturb import plan_lighting

    n = 400
    cfg = _cfg(
        9,
        n_frames=n,
        gain_rate_hz=0.0,
        contrast_rate_hz=0.0,
        ae_strength=0.0,
        flicker_gain=0.1,
        flicker_contrast=0.05,
        flicker_corr=0.5,
        undisturbed_seeds=True,
    )
    sched = plan_lighting(cfg, np.random.default_rng(0), np.full(n, 0.2), np.full(n, 0.5))
    assert np.all(sched.gain[:2] == 1.0) and np.all(sched.contrast[:2] == 1.0)
    lg, lk = np.log(sched.gain[2:]), np.log(sched.contrast[2:])
    assert np.std(lg) == pytest.approx(0.1, rel=0.2) and np.std(lk) == pytest.approx(0.05, rel=0.2)
    assert np.corrcoef(lg[:-1], lg[1:])[0, 1] == pytest.approx(0.5, abs=0.15)
    assert any(e["type"] == "flicker" for e in sched.events)


def test_fast_heavily_damped_auto_exposure_stays_stable() -> None:
    from colonlight.synth.disturb import plan_lighting

    n = 200
    cfg = _cfg(
        10,
        n_frames=n,
        gain_rate_hz=0.0,
        contrast_rate_hz=0.0,
        flicker_gain=0.0,
        flicker_contrast=0.0,
        ae_strength=1.0,
        ae_speed=0.9,
        ae_damping=1.2,
    )
    mean = np.where(np.arange(n) < 100, 0.1, 0.3)  # a step in scene brightness
    sched = plan_lighting(cfg, np.random.default_rng(0), mean, mean * 2)
    le = np.log(sched.exposure)
    assert np.abs(np.diff(le[150:])).max() < 1e-3  # settled, not ringing from frame to frame
    assert le[-1] == pytest.approx(np.mean(np.log(mean)) - np.log(0.3), abs=1e-3)


def test_contrast_changes_follow_power_curve() -> None:
    cfg = _cfg(8, n_frames=30, gain_rate_hz=0.0, contrast_rate_hz=3.0, ae_strength=0.0)
    seen = 0
    for f in generate_clip(cfg, 8):
        k, g = f.lighting["contrast"], f.lighting["display_gain"]
        assert 0.6 - 1e-9 <= k <= 1.6 + 1e-9
        if abs(k - 1) > 0.1:
            c = f.clean.astype(float) / 255
            ok = (c > 0.1) & (c < 0.9)
            pred = np.clip(g * c[ok] ** k, 0, 1) * 255
            assert np.abs(pred - f.image[ok]).mean() < 1.5
            seen += 1
    assert seen > 0


# ------------------------------------------------------------------------------------------------ appearance


def test_close_occluder_forced_and_forbidden() -> None:
    for seed in (0, 2):
        frames = _clip(_cfg(seed, n_frames=12, close_occluder="force", steady=True), seed)
        occ = [f for f in frames if f.occluder]
        assert occ
        for f in occ:
            y = np.sort(f.clean.astype(float).mean(axis=2).ravel())
            assert y[len(y) // 2 :].mean() > 2.0 * max(y[: len(y) // 4].mean(), 1.0)
    assert not any(f.occluder for f in generate_clip(_cfg(0, close_occluder="forbid"), 0))


def test_looks_like_colonoscopy() -> None:
    lumen_in_view = 0
    for seed in range(20, 32):
        cfg = _cfg(seed, n_frames=3, steady=True, close_occluder="forbid")
        f = _clip(cfg, seed)[-1]
        m = f.clean.reshape(-1, 3).astype(float).mean(axis=0)
        assert m[0] > m[1] and m[0] > m[2], m  # pink-red wall
        y = f.clean.astype(float).mean(axis=2)
        lumen_in_view += np.percentile(y, 5) < 0.35 * np.percentile(y, 95)  # a dark lumen beside bright walls
        assert np.isinf(f.depth).any() or np.nanmax(f.depth[np.isfinite(f.depth)]) > 0.05  # it looks far
    # the camera looks around and drifts sideways, so some frames face a wall: most, not all, show the lumen
    assert lumen_in_view >= 7, lumen_in_view


def test_read_tum_reads_what_tum_line_writes(tmp_path: Path) -> None:
    """The evaluation reads poses.txt with read_tum: it must give back the generator's poses."""
    rng = np.random.default_rng(3)
    poses = []
    for _ in range(5):
        m = np.eye(4)
        m[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
        m[:3, 3] = rng.normal(size=3)
        poses.append(m)
    lines = ["# t tx ty tz qx qy qz qw", *(tum_line(i / 18, p) for i, p in enumerate(poses))]
    (tmp_path / "poses.txt").write_text("\n".join(lines) + "\n")
    for got, want in zip(read_tum(tmp_path / "poses.txt"), poses, strict=True):
        assert np.allclose(got, want, atol=1e-8)


def test_every_randomised_knob_has_held_out_values() -> None:
    """Issue 12: the held-out family must reach values training never draws, for every randomised setting."""
    assert all(spec.heldout for spec in PARAM_SPECS.values()), [n for n, s in PARAM_SPECS.items() if not s.heldout]
    tight = [SynthConfig.sample(np.random.default_rng(s), split="heldout").mask_radius for s in range(60)]
    assert any(0.8 <= r < 1.0 for r in tight)  # a tighter black field stop than training draws
    train = [SynthConfig.sample(np.random.default_rng(s), split="train").mask_radius for s in range(60)]
    assert all(r == 0.0 or r >= 1.0 for r in train)


def test_response_shoulder_is_a_monotone_curve_through_black_and_white() -> None:
    from colonlight.synth.render import response

    y = np.linspace(0, 1, 101, dtype=np.float32)
    assert np.array_equal(response(y, 0.0), y)
    for s in (0.3, 1.2):
        f = response(y, s)
        assert f[0] == 0 and f[-1] == pytest.approx(1.0) and np.all(np.diff(f) > 0)
        assert f[10] > y[10]  # shadows lifted, highlights compressed


def test_exposure_goes_in_before_the_shoulder() -> None:
    """With a shoulder, a lagging auto-exposure is not a pure display gain: it acts on linear light."""
    from colonlight.synth.disturb import LightingSchedule
    from colonlight.synth.render import response

    sched = LightingSchedule(2.2, 1.0, np.array([1.0]), np.array([1.0]), np.array([2.0]))
    y = np.linspace(0.05, 0.9, 20, dtype=np.float32)
    want = response(y * np.float32(2.0 ** (1 / 2.2)), 0.8)
    assert np.allclose(sched.apply(0, y, 0.8), want)
    assert np.allclose(sched.apply(0, y, 0.0), y * np.float32(2.0 ** (1 / 2.2)))


def test_an_interrupt_as_a_temporary_is_made_leaves_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGTERM's exception can land just after a temporary's file is made (CI caught one such PNG temporary,
    when ``tempfile.mkstemp`` made them). Injected there on the third temporary of a real render: the interrupt
    propagates, the clip's folder keeps no temporary and no completion marker."""
    made = interrupt_after_creating(monkeypatch, 3)
    out = tmp_path / "clip"
    with pytest.raises(KeyboardInterrupt):
        write_clip(out, _cfg(3, n_frames=4), 3, video=False)
    assert len(made) == 3 and not Path(made[2]).exists()
    assert not [p for p in out.rglob("*") if "colonlight-tmp" in p.name], sorted(out.rglob("*"))
    assert not (out / "synth.json").exists()
