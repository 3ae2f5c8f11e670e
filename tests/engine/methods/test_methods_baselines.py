"""The stateless classical baselines (gamma, he, clahe, agcwd): references, edge cases, interface."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from colonlight.curves import apply_gamma
from colonlight.methods import create_method
from colonlight.methods.agcwd import AgcwdMethod, agcwd_lut
from colonlight.methods.fixed_gamma import FixedGammaMethod
from colonlight.methods.histogram import ClaheMethod, HistogramEqualizationMethod, scale_value

STATELESS = [
    ("gamma", {}),
    ("gamma", {"gamma": 1.6}),
    ("he", {}),
    ("clahe", {}),
    ("clahe", {"clip_limit": 40.0, "tile_grid": (3, 5), "space": "hsv"}),
    ("agcwd", {}),
    ("agcwd", {"alpha": 0.75}),
]
SIZES = [(1, 1), (3, 5), (37, 53), (64, 48)]


def _natural(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A smooth, reddish, dim test frame with some texture (not saturated)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    light = 40 + 80 * np.exp(-(((yy - h / 2) / (h / 2 + 1)) ** 2 + ((xx - w / 3) / (w / 2 + 1)) ** 2))
    rgb = np.stack([light * 1.5, light * 0.8, light * 0.6], -1) + rng.normal(0, 6, (h, w, 3))
    return np.clip(rgb, 0, 255).astype(np.uint8)


def _run(method, frames):  # noqa: ANN001, ANN202
    stream = method.stream()
    out = [r for f in frames for r in stream.push(f)]
    return out + stream.flush()


# ---------- references written from the spec (OpenCV's algorithms, restated) ----------


def _equalize_ref(img: np.ndarray) -> np.ndarray:
    hist = np.bincount(img.ravel(), minlength=256)
    i0 = int(np.flatnonzero(hist)[0])
    if hist[i0] == img.size:
        return np.full_like(img, i0)
    scale = 255.0 / (img.size - hist[i0])
    lut = np.zeros(256)
    lut[i0 + 1 :] = np.rint(scale * np.cumsum(hist[i0 + 1 :]))
    return lut.astype(np.uint8)[img]


def _clahe_ref(img: np.ndarray, clip: float, grid: tuple[int, int]) -> np.ndarray:
    """OpenCV's 8-bit CLAHE: reflect-101 padding (of both sides when either is not divisible), clipped tile
    histograms with the remainder spread at a stride, float32 tables and float32 bilinear blending."""
    f32 = np.float32
    gx, gy = grid
    h, w = img.shape
    src = img
    if h % gy or w % gx:
        src = cv2.copyMakeBorder(img, 0, gy - h % gy, 0, gx - w % gx, cv2.BORDER_REFLECT_101)
    th, tw = src.shape[0] // gy, src.shape[1] // gx
    area = th * tw
    luts = np.zeros((gy, gx, 256), f32)
    for ty in range(gy):
        for tx in range(gx):
            hist = np.bincount(src[ty * th : (ty + 1) * th, tx * tw : (tx + 1) * tw].ravel(), minlength=256)
            if clip > 0:
                limit = max(1, int(clip * area / 256))
                excess = int(np.maximum(hist - limit, 0).sum())
                hist = np.minimum(hist, limit) + excess // 256
                r = excess % 256
                for i in range(0, 256, max(256 // r, 1) if r else 256):
                    if r <= 0:
                        break
                    hist[i] += 1
                    r -= 1
            luts[ty, tx] = np.clip(np.rint(np.cumsum(hist).astype(f32) * f32(255.0 / area)), 0, 255)
    ys = np.arange(h, dtype=f32) * f32(1.0 / th) - f32(0.5)
    xs = np.arange(w, dtype=f32) * f32(1.0 / tw) - f32(0.5)
    y1, x1 = np.floor(ys).astype(int), np.floor(xs).astype(int)
    ya, xa = (ys - y1).astype(f32), (xs - x1).astype(f32)
    y2, x2 = np.clip(y1 + 1, 0, gy - 1), np.clip(x1 + 1, 0, gx - 1)
    y1, x1 = np.clip(y1, 0, gy - 1), np.clip(x1, 0, gx - 1)
    out = np.empty_like(img)
    for i in range(h):
        v = img[i]
        top = luts[y1[i], x1, v] * (f32(1) - xa) + luts[y1[i], x2, v] * xa
        bot = luts[y2[i], x1, v] * (f32(1) - xa) + luts[y2[i], x2, v] * xa
        out[i] = np.clip(np.rint(top * (f32(1) - ya[i]) + bot * ya[i]), 0, 255)
    return out


@pytest.mark.parametrize("shape", [(64, 48), (37, 53), (135, 240), (5, 7)])
@pytest.mark.parametrize("clip,grid", [(2.0, (8, 8)), (40.0, (3, 5)), (0.0, (8, 8))])
def test_opencv_clahe_matches_the_spec_algorithm(shape: tuple[int, int], clip: float, grid: tuple[int, int]) -> None:
    h, w = shape
    img = cv2.cvtColor(_natural(h, w), cv2.COLOR_RGB2GRAY)
    got = cv2.createCLAHE(clipLimit=clip, tileGridSize=grid).apply(img)
    np.testing.assert_array_equal(got, _clahe_ref(img, clip, grid))


@pytest.mark.parametrize("kind", ["natural", "constant", "two-level", "black"])
def test_opencv_equalize_hist_matches_the_spec_algorithm(kind: str) -> None:
    img = {
        "natural": cv2.cvtColor(_natural(40, 30), cv2.COLOR_RGB2GRAY),
        "constant": np.full((9, 7), 77, np.uint8),
        "two-level": np.array([[10, 10, 200, 200, 200]], np.uint8),
        "black": np.zeros((4, 4), np.uint8),
    }[kind]
    np.testing.assert_array_equal(cv2.equalizeHist(img), _equalize_ref(img))


# ---------- each method against its reference ----------


def test_fixed_gamma_is_the_lookup_table_and_reports_gamma() -> None:
    frame = _natural(37, 53)
    (res,) = _run(FixedGammaMethod(gamma=0.5), [frame])
    np.testing.assert_array_equal(res.frame, apply_gamma(frame, 0.5))
    assert res.gamma == 0.5
    assert FixedGammaMethod().gamma == 0.7
    (same,) = _run(FixedGammaMethod(gamma=1.0), [frame])
    np.testing.assert_array_equal(same.frame, frame)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            FixedGammaMethod(gamma=bad)


def test_he_is_equalize_hist_on_y_of_ycrcb() -> None:
    frame = _natural(37, 53)
    ycc = cv2.cvtColor(frame, cv2.COLOR_RGB2YCrCb)
    ycc[..., 0] = cv2.equalizeHist(np.ascontiguousarray(ycc[..., 0]))
    (res,) = _run(HistogramEqualizationMethod(), [frame])
    np.testing.assert_array_equal(res.frame, cv2.cvtColor(ycc, cv2.COLOR_YCrCb2RGB))
    assert res.gamma is None
    y_in = cv2.cvtColor(frame, cv2.COLOR_RGB2YCrCb)[..., 0]
    y_out = cv2.cvtColor(res.frame, cv2.COLOR_RGB2YCrCb)[..., 0]
    assert np.ptp(y_out) > np.ptp(y_in) + 100  # stretched towards the full range


def test_clahe_lab_is_opencv_clahe_on_l() -> None:
    frame = _natural(67, 45)
    lab = cv2.cvtColor(frame, cv2.COLOR_RGB2Lab)
    lab[..., 0] = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8)).apply(np.ascontiguousarray(lab[..., 0]))
    (res,) = _run(ClaheMethod(), [frame])
    np.testing.assert_array_equal(res.frame, cv2.cvtColor(lab, cv2.COLOR_Lab2RGB))


def test_clahe_hsv_sets_v_exactly_and_keeps_hue() -> None:
    frame = _natural(67, 45)
    v = frame.max(axis=2)
    want_v = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(4, 4)).apply(v)
    (res,) = _run(ClaheMethod(clip_limit=3.0, tile_grid=(4, 4), space="hsv"), [frame])
    np.testing.assert_array_equal(res.frame.max(axis=2), want_v)
    # Same as OpenCV's 8-bit HSV round trip up to its hue quantisation (2 degrees).
    hsv = cv2.cvtColor(frame, cv2.COLOR_RGB2HSV)
    hsv[..., 2] = want_v
    via_cv = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB).astype(int)
    assert np.abs(via_cv - res.frame).max() <= 4
    assert np.abs(via_cv - res.frame).mean() < 0.5


def test_scale_value_of_black_pixels_is_gray() -> None:
    frame = np.zeros((2, 2, 3), np.uint8)
    out = scale_value(frame, np.full((2, 2), 9, np.uint8))
    np.testing.assert_array_equal(out, np.full((2, 2, 3), 9, np.uint8))


def test_agcwd_lut_follows_the_formula() -> None:
    rng = np.random.default_rng(3)
    v = np.clip(rng.normal(70, 25, (50, 40)), 0, 255).astype(np.uint8)
    alpha = 0.5
    pdf = np.bincount(v.ravel(), minlength=256) / v.size
    pdf_w = pdf.max() * ((pdf - pdf.min()) / (pdf.max() - pdf.min())) ** alpha
    cdf_w = np.cumsum(pdf_w) / pdf_w.sum()
    levels = np.arange(256)
    want = np.rint(255 * (levels / 255) ** (1 - cdf_w))
    want[0] = 0
    lut = agcwd_lut(v, alpha)
    np.testing.assert_array_equal(lut, np.clip(want, 0, 255).astype(np.uint8))
    assert np.all(np.diff(lut.astype(int)) >= 0)  # monotone: no tone reversal
    assert lut[70] > 70  # a dim frame's common levels are brightened


def test_agcwd_changes_v_through_its_table() -> None:
    frame = _natural(37, 53)
    v = frame.max(axis=2)
    (res,) = _run(AgcwdMethod(), [frame])
    np.testing.assert_array_equal(res.frame.max(axis=2), agcwd_lut(v, 0.5)[v])
    assert res.gamma is None


def test_agcwd_degenerate_frames() -> None:
    black = np.zeros((8, 8, 3), np.uint8)
    (res,) = _run(AgcwdMethod(), [black])
    np.testing.assert_array_equal(res.frame, black)  # 0 ** 0 would otherwise turn it white
    gray = np.full((8, 8, 3), 100, np.uint8)
    (res,) = _run(AgcwdMethod(), [gray])
    np.testing.assert_array_equal(res.frame, np.full_like(gray, 255))  # the top level always maps to 255
    ramp = np.repeat(np.arange(256, dtype=np.uint8)[None, :, None], 3, axis=2)  # flat histogram
    (res,) = _run(AgcwdMethod(), [ramp])
    assert np.all(np.diff(res.frame[0, :, 0].astype(int)) >= 0)


# ---------- interface and edge cases common to all ----------


@pytest.mark.parametrize("name,options", STATELESS)
def test_registry_parameters_and_model_info(name: str, options: dict) -> None:
    method = create_method(name, **options)
    params = method.parameters()
    assert json.loads(json.dumps(params)) == params
    for key, value in options.items():
        assert params[key] == (list(value) if isinstance(value, tuple) else value)
    assert method.model_info() is None
    assert type(create_method(name, **params)) is type(method)  # parameters() round-trips


@pytest.mark.parametrize("name,options", STATELESS)
@pytest.mark.parametrize("shape", SIZES)
def test_shape_dtype_and_one_result_per_frame(name: str, options: dict, shape: tuple[int, int]) -> None:
    frames = [_natural(*shape, seed=s) for s in range(3)]
    results = _run(create_method(name, **options), frames)
    assert len(results) == 3
    for r in results:
        assert r.frame.shape == (*shape, 3) and r.frame.dtype == np.uint8


@pytest.mark.parametrize("name,options", STATELESS)
@pytest.mark.parametrize("value", [0, 255, 128])
def test_constant_frames(name: str, options: dict, value: int) -> None:
    frame = np.full((24, 40, 3), value, np.uint8)
    (res,) = _run(create_method(name, **options), [frame])
    out = res.frame.astype(int)
    assert np.ptp(out) <= 2  # stays (almost) uniform: no tile seams, no noise
    if value == 0 and name != "clahe":  # CLAHE spreads the clipped excess over all bins, so black is lifted
        assert out.max() <= 1
    if value == 255:
        assert out.min() >= 253


@pytest.mark.parametrize("name,options", STATELESS)
def test_rejects_bad_frames(name: str, options: dict) -> None:
    stream = create_method(name, **options).stream()
    with pytest.raises(ValueError):
        stream.push(np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError):
        stream.push(np.zeros((4, 4), np.uint8))


def test_rejects_bad_options() -> None:
    with pytest.raises(ValueError):
        ClaheMethod(space="rgb")
    with pytest.raises(ValueError):
        ClaheMethod(tile_grid=(0, 8))
    with pytest.raises(ValueError):
        ClaheMethod(clip_limit=-1)
    with pytest.raises(ValueError):
        AgcwdMethod(alpha=0)
