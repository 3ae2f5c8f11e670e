"""``deflicker`` held to FFmpeg's own ``deflicker`` filter (the imageio-ffmpeg binary) on small synthetic
clips."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from colonlight.methods import create_method
from colonlight.methods.deflicker import (
    MODES,
    DeflickerMethod,
    deflicker_factor,
    deflicker_planes,
    ffmpeg_luma,
    ffmpeg_median_slot,
)

H, W = 48, 64


@pytest.fixture(scope="module")
def ffmpeg() -> str:
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")  # only the FFmpeg comparisons need it
    exe = imageio_ffmpeg.get_ffmpeg_exe()
    filters = subprocess.run([exe, "-hide_banner", "-filters"], capture_output=True, text=True).stdout
    if " deflicker " not in filters:
        pytest.skip("this FFmpeg build has no deflicker filter")
    return exe


def _ffmpeg(exe: str, raw: bytes, in_fmt: str, size: tuple[int, int], vf: str, out_fmt: str) -> bytes:
    h, w = size
    cmd = [exe, "-v", "error", "-f", "rawvideo", "-pix_fmt", in_fmt, "-s", f"{w}x{h}", "-i", "-"]
    cmd += ["-vf", vf, "-f", "rawvideo", "-pix_fmt", out_fmt, "-"]
    return subprocess.run(cmd, input=raw, capture_output=True, check=True, timeout=60).stdout


def _yuv_clip(n: int, seed: int, base: float = 110, amp: float = 60) -> tuple[list[np.ndarray], np.ndarray]:
    """yuv420p frames: a fixed texture whose brightness flickers; random chroma."""
    rng = np.random.default_rng(seed)
    texture = rng.integers(0, 100, (H, W)) - 50.0
    ys = [
        np.clip(texture + base + amp * np.sin(1.3 * k) + rng.normal(0, 10), 16, 235).astype(np.uint8) for k in range(n)
    ]
    chroma = rng.integers(16, 241, (n, 2, H // 2, W // 2), dtype=np.uint8)
    return ys, chroma


def _ffmpeg_yuv(
    exe: str, ys: list[np.ndarray], chroma: np.ndarray, size: int, mode: str
) -> tuple[np.ndarray, np.ndarray]:
    raw = b"".join(y.tobytes() + c.tobytes() for y, c in zip(ys, chroma, strict=True))
    out = np.frombuffer(_ffmpeg(exe, raw, "yuv420p", (H, W), f"deflicker=size={size}:mode={mode}", "yuv420p"), np.uint8)
    out = out.reshape(-1, H * W * 3 // 2)
    return out[:, : H * W].reshape(-1, H, W), out[:, H * W :].reshape(-1, 2, H // 2, W // 2)


CASES = [
    ("am", 5),
    ("gm", 3),
    ("hm", 4),
    ("qm", 2),
    ("cm", 7),
    ("pm", 5),
    ("median", 5),
    ("median", 2),
    ("am", 9),
]


@pytest.mark.parametrize("mode,size", CASES)
def test_luma_planes_match_ffmpeg(ffmpeg: str, mode: str, size: int) -> None:
    ys, chroma = _yuv_clip(14, seed=size)
    ref_y, ref_c = _ffmpeg_yuv(ffmpeg, ys, chroma, size, mode)
    assert len(ref_y) == len(ys)  # one output per input, end padded
    np.testing.assert_array_equal(ref_c, chroma)  # FFmpeg copies chroma; so do we (RGB: see the end-to-end test)
    compat = np.stack([y for y, _ in deflicker_planes(ys, size, mode, ffmpeg_compatible=True)])
    np.testing.assert_array_equal(compat, ref_y)  # bit-exact, float32 emulation included
    fixed = np.stack([y for y, _ in deflicker_planes(ys, size, mode)])
    if mode != "median":
        assert np.abs(fixed.astype(int) - ref_y).max() <= 1  # float64 vs float32 at trunc boundaries only
    elif mode == "median" and size == 5:
        assert np.abs(fixed.astype(int) - ref_y).max() > 10  # FFmpeg's median is not a median


def test_median_defect_is_a_fixed_slot() -> None:
    assert [ffmpeg_median_slot(s) for s in range(2, 10)] == [1, 1, 1, 3, 3, 2, 2, 7]
    window = [100.0, 50.0, 200.0, 10.0, 120.0]
    assert deflicker_factor(window, "median", ffmpeg_compatible=True) == pytest.approx(10.0 / 100.0)
    assert deflicker_factor(window, "median") == pytest.approx(100.0 / 100.0)  # sorted[2] = 100


@pytest.mark.parametrize("mode,size", [("am", 5), ("gm", 7), ("hm", 4), ("median", 6)])
def test_short_clip_zero_slots_match_ffmpeg(ffmpeg: str, mode: str, size: int) -> None:
    ys, chroma = _yuv_clip(3, seed=1)
    ref_y, _ = _ffmpeg_yuv(ffmpeg, ys, chroma, size, mode)
    compat = np.stack([y for y, _ in deflicker_planes(ys, size, mode, ffmpeg_compatible=True)])
    np.testing.assert_array_equal(compat, ref_y)
    fixed = deflicker_planes(ys, size, mode)
    lum = [float(y.mean()) for y in ys]
    padded = lum + [lum[-1]] * size
    for k, (_, f) in enumerate(fixed):  # replication padding: the window is never emptied
        assert f == pytest.approx(deflicker_factor(padded[k : k + size], mode))


def test_float32_overflow_blackens_like_ffmpeg(ffmpeg: str) -> None:
    ys, chroma = _yuv_clip(20, seed=2, base=200, amp=5)  # L ~ 200, s = 17: 200**17 > 3.4e38
    ref_y, _ = _ffmpeg_yuv(ffmpeg, ys, chroma, 17, "gm")
    assert ref_y[:3].max() == 0
    compat = np.stack([y for y, _ in deflicker_planes(ys, 17, "gm", ffmpeg_compatible=True)])
    np.testing.assert_array_equal(compat, ref_y)
    fixed = np.stack([y for y, _ in deflicker_planes(ys, 17, "gm")])
    assert np.abs(fixed.astype(int) - np.stack(ys)).mean() < 8  # a gentle correction, not black


def test_ffmpeg_rgb_to_luma_is_bit_exact(ffmpeg: str) -> None:
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (128, 256, 3), dtype=np.uint8)
    rgb[0, :, :] = np.arange(256, dtype=np.uint8)[:, None]  # grays, incl. 0 and 255
    out = np.frombuffer(_ffmpeg(ffmpeg, rgb.tobytes(), "rgb24", rgb.shape[:2], "null", "yuv444p"), np.uint8)
    np.testing.assert_array_equal(ffmpeg_luma(rgb), out[: 128 * 256].reshape(128, 256))


@pytest.mark.parametrize("mode,size,compatible", [("am", 5, False), ("median", 5, True), ("pm", 3, True)])
def test_rgb_method_matches_ffmpeg_on_rgb_input(ffmpeg: str, mode: str, size: int, compatible: bool) -> None:
    """RGB in, FFmpeg's automatic conversion, deflicker; our RGB output converted the same way gives FFmpeg's
    Y."""
    h, w = 45, 67  # odd sizes
    rng = np.random.default_rng(5)
    base = rng.integers(40, 130, (h, w, 3)).astype(np.float64)
    frames = [np.clip(base * (0.6 + 0.5 * rng.random()), 0, 255).astype(np.uint8) for _ in range(9)]
    raw = b"".join(f.tobytes() for f in frames)

    def planes(data: bytes) -> np.ndarray:
        return np.frombuffer(data, np.uint8).reshape(-1, 3, h, w)

    ref = planes(_ffmpeg(ffmpeg, raw, "rgb24", (h, w), f"deflicker=size={size}:mode={mode}", "yuv444p"))
    source = planes(_ffmpeg(ffmpeg, raw, "rgb24", (h, w), "null", "yuv444p"))
    np.testing.assert_array_equal(ref[:, 1:], source[:, 1:])  # FFmpeg changes Y only
    stream = DeflickerMethod(size=size, mode=mode, ffmpeg_compatible=compatible).stream()
    results = [r for f in frames for r in stream.push(f)] + stream.flush()
    ours = np.stack([r.frame for r in results])
    our_yuv = planes(_ffmpeg(ffmpeg, ours.tobytes(), "rgb24", (h, w), "null", "yuv444p"))
    y_diff = np.abs(our_yuv[:, 0].astype(int) - ref[:, 0])
    assert y_diff.max() <= (0 if compatible else 1)
    assert np.abs(our_yuv[:, 1:].astype(int) - source[:, 1:]).max() <= 1  # chroma unchanged up to rounding
    lum = [r.info["luminance"] for r in results]
    assert lum == pytest.approx([float(ffmpeg_luma(f).mean()) for f in frames], rel=1e-6)


def test_streaming_latency_order_and_count() -> None:
    frames = [np.full((6, 8, 3), 40 + 10 * k, np.uint8) for k in range(8)]
    stream = DeflickerMethod(size=4).stream()
    counts = [len(stream.push(f)) for f in frames]
    assert counts == [0, 0, 0, 1, 1, 1, 1, 1]
    rest = stream.flush()
    assert len(rest) == 3
    stream = DeflickerMethod(size=4).stream()
    results = [r for f in frames for r in stream.push(f)] + stream.flush()
    lum = [r.info["luminance"] for r in results]
    assert lum == sorted(lum)  # in input order
    for r in results:
        assert r.gamma is None and r.frame.shape == (6, 8, 3) and r.frame.dtype == np.uint8
        assert r.info["new_luminance"] == pytest.approx(r.info["luminance"] * (1 + r.info["relative_change"]))


@pytest.mark.parametrize("compatible", [False, True])
@pytest.mark.parametrize("mode", MODES)
def test_edge_clips(mode: str, compatible: bool) -> None:
    method = DeflickerMethod(size=5, mode=mode, ffmpeg_compatible=compatible)

    def run(frames: list[np.ndarray]) -> list:  # noqa: ANN401
        stream = method.stream()
        return [r for f in frames for r in stream.push(f)] + stream.flush()

    gray = [np.full((7, 9, 3), 90, np.uint8)] * 7
    for r, f in zip(run(gray), gray, strict=True):
        np.testing.assert_array_equal(r.frame, f)  # constant clip: gain 1, frame untouched
    black = [np.zeros((7, 9, 3), np.uint8)] * 3
    for r in run(black):
        assert r.frame.max() == 0
        assert json.loads(json.dumps(r.info, allow_nan=False)) == r.info  # no NaN/inf in the metadata
    white = [np.full((7, 9, 3), 255, np.uint8)] * 6
    for r in run(white):
        assert r.frame.min() == 255
    (one,) = run([gray[0]])  # a one-frame clip: in compatible mode the empty slots count as 0
    if not compatible:
        np.testing.assert_array_equal(one.frame, gray[0])


def test_options_and_registry() -> None:
    m = create_method("deflicker", size=7, mode="cm", ffmpeg_compatible=True)
    assert m.parameters() == {"size": 7, "mode": "cm", "ffmpeg_compatible": True}
    assert DeflickerMethod().parameters() == {"size": 5, "mode": "am", "ffmpeg_compatible": False}
    assert m.model_info() is None
    for bad in ({"size": 1}, {"size": 130}, {"size": 2.5}, {"mode": "mean"}):
        with pytest.raises(ValueError):
            DeflickerMethod(**bad)


def test_held_frames_are_copies() -> None:
    buf = np.full((4, 4, 3), 100, np.uint8)
    stream = DeflickerMethod(size=3).stream()
    stream.push(buf)
    buf[:] = 0  # a caller reusing its decode buffer
    stream.push(np.full((4, 4, 3), 100, np.uint8))
    first = stream.flush()[0]
    assert first.frame.min() == 100
