"""A direct photometric tracker (DSO-style front end with known depth) to score enhanced colonoscopy video.

Why: photometric SLAM such as DSO assumes brightness constancy up to a per-frame affine change, and
colonoscopy lighting breaks it. ``colonlight evaluate`` tracks each method's enhanced frames with this
tracker on synthetic clips whose depth and poses are known, so the pose error measures what the lighting
does to tracking and nothing else (no mapping, no scale ambiguity).

Model
    Frames become grey float32 in [0, 255] (``cv2.COLOR_RGB2GRAY`` weights). Frame j is aligned to the
    current keyframe k by minimising over the keyframe's selected pixels p

        r_p = e^{-a} (I_j(pi(T_jk X_p)) - b) - I_k(p),      X_p = depth_k(p) K^{-1} (u_p, v_p, 1)

    i.e. DSO's per-frame affine brightness: frame j is modelled as I_j = e^{a} I_k + b, and e^{-a}(I_j - b)
    brings it back to the keyframe's scale, so r (and the Huber/outlier thresholds) are in keyframe grey
    levels. Unknowns: T_jk (keyframe camera -> frame camera, left-multiplied SE(3) increments) and (a, b),
    8 in all, with weak priors pulling a and b to 0 (``brightness="affine"``: DSO's ``mode=1``). With
    ``brightness="fixed"`` (DSO's ``mode=2``, "photometric mode with perfect images",
    ``setting_affineOptModeA/B = -1``, which RNNSLAM and so the paper's numbers used) a = b = 0 are not
    optimised and only the 6 pose unknowns are solved: every brightness change between keyframe and frame
    is then a residual, as it is for a tracker that trusts the images. Levenberg-Marquardt (Gauss-Newton with Marquardt
    damping) with Huber IRLS weights (threshold 9); residuals beyond 20 are outliers with a constant cost
    and no weight, and points leaving the image cost the same, so pushing points out of view never pays
    (the cutoff doubles while fewer than half the points are inliers, as in DSO). Coarse to fine over a
    2x2-block-average pyramid (4 levels, coarsest side >= 24 px), analytical Jacobians from
    central-difference gradients of the current frame, bilinear sampling in vectorised numpy. The start is
    the constant-motion prediction (last inter-frame motion repeated) and the last brightness change.
    (Extra DSO-style starts - zero motion, double motion, small rotations - chosen by coarse-level energy
    made results worse on synthetic clips: the coarse levels see mostly the light falloff, which moves
    with the camera, so their energy misranks starts. A zero-motion start run coarse to fine beside the
    constant-motion one, the lower finest-level energy kept, does too: on 24 validation clips the clean
    frames' tracked fraction falls from 0.803 to 0.775 with brightness fixed and from 0.812 to 0.802 fitted
    (README, the default model, session 34). DSO's re-track rule, other starts tried only when the finest RMSE
    exceeds 1.5x the last frame's, changes no tracked fraction by more than 0.003 and never fires on the clip
    that trap was found on (session 35).)

Points
    Per level, cells sized for about ``n_points / 4^level`` points (at least ``min_level_points``) each give
    their strongest-gradient pixel: first those above the median gradient of their 32x32 region plus 7
    (DSO's adaptive threshold, spreading points over the image), then, up to the target, the other cells'
    best pixels with a gradient above ``min_gradient``. Never used: depth inf, NaN or <= 0 (far lumen,
    unknown), saturated pixels and their neighbours (glints move with the light, not the wall), a 2 px
    border. Coarse depth is the 2x2 mean; blocks straddling a depth edge (max/min > 1.3) are dropped. No
    8-pixel pattern: with known depth, more single points do the same job more cheaply.

Keyframes (known depth)
    Frame 0 is the first keyframe. A tracked frame becomes the next keyframe after ``keyframe_interval`` (5)
    frames, when fewer than ``min_overlap`` (60 %) of the keyframe's points project into it, or when its
    estimated distance from the keyframe exceeds ``max_keyframe_baseline`` (5 %) of the keyframe's median
    depth (DSO's flow criterion: the co-located light makes shading change fast as the scope moves, so
    photometric error grows with baseline). A keyframe takes its own image, its ground-truth depth (known
    depth: no mapping) and its *estimated* pose, so pose errors accumulate as in visual odometry. A lost
    frame (below) keeps the previous pose and becomes a keyframe, so tracking restarts from it.

Errors and success
    With G the ground-truth and P the estimated camera-to-world poses (P_0 = G_0):
    ``translation_error_m`` / ``rotation_error_deg`` are the error of the pose relative to the keyframe the
    frame was tracked against, E = (G_k^-1 G_j)^-1 (P_k^-1 P_j): the part tracking is responsible for;
    ``drift_*`` is the absolute error G_j^-1 P_j. A frame fails when
        its translation error > max(2 mm, 25 % of the true keyframe-to-frame translation), or
        its rotation error > 3 degrees, or
        it is lost: non-finite estimate, fewer than 30 % (or 50) of the keyframe's points in view, or an
        estimate farther from the keyframe than its median depth (``max_jump``).
    Why: the colon radius is ~18 mm and the wall 5-40 mm away, so 2 mm of translation error or 3 degrees
    of rotation (~6 px at 256 px with a 95 degree field of view) misplaces the wall by several pixels: the
    track is lost, not merely noisy. The 25 % term keeps fast clips (several mm between keyframe and frame)
    from failing on a proportionally small error. A clip succeeds when no frame fails; ``failed_at`` is the
    first failing frame; later frames are still tracked and reported. Without ground truth only lost frames
    fail.

Sensitivity (128 px, 40-frame generator clips, seeds 10-19; success / median per-clip median error)
    train split, clean frames: 6/10, 0.21 mm / 0.42 deg; with the generator's own disturbances (gain
    jumps, lagging auto-exposure, contrast power curves): 6/10, 0.20 mm / 0.42 deg, because gain is affine
    and a power curve is nearly affine over one frame's intensities; alternating gamma e^{+-0.5}: 4/10,
    0.40 mm / 0.66 deg; a per-frame brightness gradient of +-15 % turning every frame: 0/10, 2.0 mm /
    5.7 deg. Held-out split: 3/10 clean and 3/10 disturbed. Clean failures are close-occluder moments (the
    tip swings ~15 deg per frame toward the wall) and out-of-range speeds (40-60 mm/s).

Speed
    Measured on one core (``OMP_NUM_THREADS=1``) of this project's shared 2-core VM: 5.5 ms/frame at
    256x256 on a typical steady synthetic clip (60 frames, 15 mm/s, a keyframe every 2-3 frames) and
    4 ms/frame at 128x128; 10-12 ms/frame at 256x256 on a fast clip (68 mm/s) where nearly every frame
    becomes a keyframe. Reproduce with
    ``OMP_NUM_THREADS=1 python -c "from colonlight.evaluation.tracker import benchmark; print(benchmark())"``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from . import se3

#: Per-frame affine brightness: "fixed" (a = b = 0, the paper's RNNSLAM setting) or "affine" (fitted).
BRIGHTNESS_MODES = ("fixed", "affine")


@dataclass(frozen=True)
class TrackerSettings:
    """Tracker knobs and the success thresholds (defaults are what ``colonlight evaluate`` uses).

    Intensities are grey levels in [0, 255]; lengths in metres.
    """

    levels: int = 4  # pyramid levels (fewer if the coarsest side would drop below min_level_size)
    min_level_size: int = 24
    n_points: int = 2000  # target points at full resolution (a quarter per coarser level)
    min_level_points: int = 250  # at least this many cells at coarse levels
    grad_threshold: float = 7.0  # added to the region's median gradient (DSO's 7): preferred points
    min_gradient: float = 1.0  # cells without a preferred point still give their best pixel above this
    region_size: int = 32  # px at full resolution, for the local median gradient
    depth_edge_ratio: float = 1.3  # coarse blocks whose depth max/min exceeds this are dropped
    huber: float = 9.0  # Huber threshold on the residual (DSO's 9)
    outlier_residual: float = 20.0  # |r| above this is an outlier: constant cost, no weight (DSO's 20);
    # points that leave the image cost the same, so pushing points out of view never pays
    prior_a: float = 1.0  # weak prior weights on (a, b) per point-averaged energy (data term ~ 1e4 * a^2)
    prior_b: float = 1e-3
    max_iterations: int = 12  # LM iterations per level
    step_tolerance: float = 5e-4  # stop when |dv|/median depth and |dw| (rad) fall below this
    energy_tolerance: float = 1e-3  # or when an accepted step lowers the energy by less than this fraction
    saturation: float = 250.0  # keyframe points avoid pixels this bright and their neighbours (glints)
    keyframe_interval: int = 5
    max_keyframe_baseline: float = 0.05  # new keyframe beyond this |t| / keyframe median depth
    min_overlap: float = 0.6  # new keyframe when fewer of its points stay in view
    min_valid_fraction: float = 0.3  # failure below this at full resolution
    min_points: int = 50
    max_jump: float = 1.0  # an estimate farther than this x median depth from its keyframe has diverged
    max_translation_error_m: float = 0.002
    relative_translation_error: float = 0.25
    max_rotation_error_deg: float = 3.0
    brightness: str = "affine"  # "affine": fit (a, b) per frame (DSO mode=1); "fixed": a = b = 0 (DSO mode=2)

    def __post_init__(self) -> None:
        if self.brightness not in BRIGHTNESS_MODES:
            raise ValueError(
                f"TrackerSettings.brightness must be one of {', '.join(BRIGHTNESS_MODES)}, got {self.brightness!r}"
            )
        positive = ("levels", "min_level_size", "n_points", "min_level_points", "region_size", "huber")
        for name in positive + ("max_iterations", "keyframe_interval", "min_points"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TrackerSettings.{name} must be > 0, got {getattr(self, name)}")
        for name in ("min_overlap", "min_valid_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"TrackerSettings.{name} must be in [0, 1], got {getattr(self, name)}")
        if self.depth_edge_ratio < 1.0:
            raise ValueError(f"TrackerSettings.depth_edge_ratio must be >= 1, got {self.depth_edge_ratio}")


#: Keyframe points keep this many pixels (full resolution) from the edge of the ``scene`` mask: the gradient and
#: the bilinear samples of a point there would reach into the border.
SCENE_MARGIN = 3


@dataclass(frozen=True)
class TrackResult:
    """What tracking a clip gave; per-frame arrays have one entry per frame (frame 0: the start).

    ``poses``: estimated camera-to-world 4x4 (metres, OpenCV axes), the first equal to the first
    ground-truth pose (identity without ground truth). ``affine``: (n, 2) per-frame (a, b) relative to frame
    0, I_j ~ e^a I_0 + b (chained through keyframes). ``residual``: final mean |r| (keyframe grey levels)
    over the points in view at full resolution (NaN when none is). ``converged``: the finest level's LM
    stopped on its step or energy tolerance, or at a minimum it could not leave, rather than on the
    iteration limit (False for lost frames). ``valid_fraction``: keyframe points that projected into the
    frame. ``keyframe_of``: the keyframe each frame was tracked against; ``keyframes``: the keyframe
    indices. Error arrays are None without ground truth; ``failure_reason`` says why ``failed_at`` failed
    (see the module docstring for both). ``frame_ok``: per frame, True unless it failed (lost, or over the
    error thresholds; frame 0 is True), so ``frame_ok[1:].mean()`` is the tracked fraction.
    """

    poses: list[np.ndarray]
    affine: np.ndarray
    residual: np.ndarray
    converged: np.ndarray
    valid_fraction: np.ndarray
    keyframe_of: np.ndarray
    keyframes: tuple[int, ...]
    translation_error_m: np.ndarray | None
    rotation_error_deg: np.ndarray | None
    drift_translation_m: np.ndarray | None
    drift_rotation_deg: np.ndarray | None
    success: bool
    failed_at: int | None
    failure_reason: str | None
    frame_ok: np.ndarray


# ----------------------------------------------------------------------------------------------- pyramid


@dataclass
class _Level:
    """One pyramid level of a frame: intrinsics, grey image, and [I, gx, gy] flattened for sampling."""

    K: np.ndarray
    image: np.ndarray
    grad: np.ndarray  # (h, w) gradient magnitude
    glare: np.ndarray  # (h, w) uint8, 1 at and next to saturated pixels (glints: they move with the light)
    stack: np.ndarray  # (h*w, 3) float32
    scene: np.ndarray | None = None  # (h, w) bool: where a point may be sampled (None: anywhere in the image)

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape


def _grey(frame: np.ndarray) -> np.ndarray:
    f = frame.astype(np.float32)
    return cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) if f.ndim == 3 else f


def _half(img: np.ndarray) -> np.ndarray:
    """2x2 block mean (odd last row/column dropped)."""
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    x = img[:h, :w]
    mean: np.ndarray = 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])
    return mean


def _half_depth(depth: np.ndarray, edge_ratio: float) -> np.ndarray:
    """2x2 mean depth; inf where any of the four is unknown or they straddle a depth edge."""
    h, w = depth.shape[0] // 2 * 2, depth.shape[1] // 2 * 2
    x = depth[:h, :w]
    q = np.stack([x[0::2, 0::2], x[1::2, 0::2], x[0::2, 1::2], x[1::2, 1::2]])
    lo, hi = q.min(axis=0), q.max(axis=0)
    out: np.ndarray = q.mean(axis=0)
    out[~np.isfinite(hi) | (hi > edge_ratio * lo)] = np.inf
    return out


def _half_K(K: np.ndarray) -> np.ndarray:
    """Intrinsics after 2x2 block averaging (pixel centres at integers at every level)."""
    out = K.copy()
    out[0, 0], out[1, 1] = K[0, 0] / 2, K[1, 1] / 2
    out[0, 2], out[1, 2] = (K[0, 2] + 0.5) / 2 - 0.5, (K[1, 2] + 0.5) / 2 - 0.5
    return out


def _n_levels(shape: tuple[int, int], s: TrackerSettings) -> int:
    small = min(shape)
    return max(1, min(s.levels, math.floor(math.log2(small / s.min_level_size)) + 1))


def _pyramid(
    frame: np.ndarray, K: np.ndarray, n_levels: int, saturation: float, scenes: Sequence[np.ndarray | None] = ()
) -> list[_Level]:
    """Grey image, gradients and glare mask per level; K follows the 2x2 block averaging. ``scenes``: per level,
    where samples may be taken (:func:`_scene_pyramid`; none: anywhere)."""
    img = _grey(frame)
    out = []
    for lvl in range(n_levels):
        gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=1, scale=0.5, borderType=cv2.BORDER_REPLICATE)
        gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=1, scale=0.5, borderType=cv2.BORDER_REPLICATE)
        stack = np.stack([img, gx, gy], axis=-1).reshape(-1, 3)
        glare = cv2.dilate((img >= saturation).astype(np.uint8), np.ones((3, 3), np.uint8))
        scene = scenes[lvl] if lvl < len(scenes) else None
        out.append(_Level(K, img, np.sqrt(gx * gx + gy * gy), glare, stack, scene))
        img, K = _half(img), _half_K(K)
    return out


def _scene_pyramid(scene: np.ndarray | None, n_levels: int) -> list[np.ndarray | None]:
    """Per level, the pixels whose samples read scene only: a sample at (u, v) reads the 2x2 pixels from
    (floor u, floor v) and their gradients one pixel on, so it needs them all inside; a coarse pixel is scene
    when its four fine ones are. A point that moves onto the border is out of view, as one that leaves the image."""
    if scene is None:
        return [None] * n_levels
    out: list[np.ndarray | None] = []
    m = scene
    for _ in range(n_levels):
        out.append(cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=2, borderValue=1).astype(bool))
        h, w = m.shape[0] // 2 * 2, m.shape[1] // 2 * 2
        m = m[:h:2, :w:2] & m[1:h:2, :w:2] & m[:h:2, 1:w:2] & m[1:h:2, 1:w:2]
    return out


def _depth_pyramid(depth: np.ndarray, n_levels: int, edge_ratio: float) -> list[np.ndarray]:
    d = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf).astype(np.float64)
    out = [d]
    for _ in range(n_levels - 1):
        out.append(_half_depth(out[-1], edge_ratio))
    return out


# ------------------------------------------------------------------------------------------------ points


@dataclass
class _Points:
    """Keyframe points of one level: 3D in the keyframe camera (metres) and their grey values."""

    X: np.ndarray  # (n, 3) float64
    intensity: np.ndarray  # (n,) float64
    median_depth: float


def _region_threshold(grad: np.ndarray, region: int, add: float) -> np.ndarray:
    """Per-pixel threshold: median gradient of the pixel's region + ``add`` (regions tile the image)."""
    h, w = grad.shape
    ry, rx = -(-h // region), -(-w // region)
    pad = np.full((ry * region, rx * region), np.nan, np.float32)
    pad[:h, :w] = grad
    blocks = pad.reshape(ry, region, rx, region).transpose(0, 2, 1, 3).reshape(ry, rx, -1)
    thr = np.nanmedian(blocks, axis=-1)
    return np.repeat(np.repeat(thr, region, axis=0), region, axis=1)[:h, :w] + add


def _select(level: _Level, depth: np.ndarray, target: int, region: int, s: TrackerSettings) -> _Points:
    """DSO-style spread selection: per cell, the strongest gradient above the local threshold."""
    h, w = level.shape
    cell = max(1, math.ceil(math.sqrt(h * w / target)))
    grad = level.grad.copy()
    margin = 2
    usable = np.isfinite(depth) & (level.glare == 0)
    usable[:margin], usable[-margin:], usable[:, :margin], usable[:, -margin:] = False, False, False, False
    score = np.where(usable, grad - _region_threshold(grad, region, s.grad_threshold), -np.inf)
    grad[~usable] = -np.inf
    ch, cw = h // cell, w // cell
    blocks: np.ndarray = score[: ch * cell, : cw * cell].reshape(ch, cell, cw, cell).transpose(0, 2, 1, 3)
    blocks = blocks.reshape(ch, cw, cell * cell)
    best = blocks.argmax(axis=-1)
    best_score = np.take_along_axis(blocks, best[..., None], axis=-1)[..., 0]
    rows = np.arange(ch)[:, None] * cell + best // cell
    cols = np.arange(cw)[None, :] * cell + best % cell
    keep = best_score > 0
    if keep.sum() < target:  # fill with the other cells' strongest pixels, strongest first
        g = np.where(keep, -np.inf, grad[rows, cols]).ravel()
        order = np.argsort(-g)[: target - int(keep.sum())]
        extra = np.zeros(keep.size, dtype=bool)
        extra[order] = g[order] > s.min_gradient
        keep |= extra.reshape(keep.shape)
    v, u = rows[keep].astype(np.float64), cols[keep].astype(np.float64)
    z = depth[rows[keep], cols[keep]]
    K = level.K
    X = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    intensity = level.image[rows[keep], cols[keep]].astype(np.float64)
    med = float(np.median(z)) if z.size else 1.0
    return _Points(X, intensity, med)


# ------------------------------------------------------------------------------------------ optimisation


@dataclass
class _Eval:
    """Energy (point-averaged Huber cost + priors), normal equations, and statistics at one estimate."""

    energy: float
    H: np.ndarray
    g: np.ndarray
    n_valid: int  # points in view
    n_inliers: int  # in view with |r| <= cutoff
    mean_abs: float


def _robust(r: np.ndarray, k: float, cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """IRLS weights and costs: Huber up to ``cutoff``, then a constant cost and no weight (DSO's outliers)."""
    a = np.abs(r)
    w = np.where(a <= k, 1.0, np.where(a <= cutoff, k / np.maximum(a, 1e-12), 0.0))
    cost = np.where(a <= k, 0.5 * r * r, k * (np.minimum(a, cutoff) - 0.5 * k))
    return w, cost


def _outlier_cost(k: float, cutoff: float) -> float:
    return k * (cutoff - 0.5 * k) if cutoff > k else 0.5 * cutoff * cutoff


def _evaluate(
    pts: _Points, level: _Level, T: np.ndarray, a: float, b: float, cutoff: float, s: TrackerSettings
) -> _Eval:
    """Residuals, Huber weights and the normal equations at (T, a, b) for one level: 8x8 when brightness is
    fitted, 6x6 (pose only) when it is fixed."""
    n = len(pts.intensity)
    h, w = level.shape
    K = level.K
    Q = pts.X @ T[:3, :3].T + T[:3, 3]
    z = Q[:, 2]
    front = z > 1e-6
    iz = np.where(front, 1.0 / np.where(front, z, 1.0), 0.0)
    x, y = Q[:, 0] * iz, Q[:, 1] * iz
    u, v = K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2]
    inside = front & (u >= 1.0) & (u < w - 2.0) & (v >= 1.0) & (v < h - 2.0)
    if level.scene is not None:  # a sample on a scope's border or text is out of view, as one off the image
        at = np.flatnonzero(inside)
        inside[at[~level.scene[np.floor(v[at]).astype(np.intp), np.floor(u[at]).astype(np.intp)]]] = False
    u, v, x, y, iz, ref = u[inside], v[inside], x[inside], y[inside], iz[inside], pts.intensity[inside]
    m = len(ref)
    out_cost = (n - m) * _outlier_cost(s.huber, cutoff)
    fit = s.brightness == "affine"
    nu = 8 if fit else 6
    prior = 0.5 * (s.prior_a * a * a + s.prior_b * b * b) if fit else 0.0
    Hp = np.diag([0, 0, 0, 0, 0, 0, s.prior_a, s.prior_b][:nu]).astype(np.float64)
    gp = np.array([0, 0, 0, 0, 0, 0, s.prior_a * a, s.prior_b * b][:nu], dtype=np.float64)
    if m == 0:
        return _Eval(out_cost / max(n, 1) + prior, Hp, gp, 0, 0, float("nan"))
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    idx = v0.astype(np.intp) * w + u0.astype(np.intp)
    st = level.stack
    top = st[idx] * (1 - fu) + st[idx + 1] * fu
    bot = st[idx + w] * (1 - fu) + st[idx + w + 1] * fu
    smp = top * (1 - fv) + bot * fv
    ea = math.exp(-a)
    cur = smp[:, 0] - b
    r = ea * cur - ref
    gu, gv = ea * K[0, 0] * smp[:, 1], ea * K[1, 1] * smp[:, 2]
    J = np.empty((m, nu))
    J[:, 0], J[:, 1] = gu * iz, gv * iz
    J[:, 2] = -(gu * x + gv * y) * iz
    J[:, 3] = -gu * x * y - gv * (1.0 + y * y)
    J[:, 4] = gu * (1.0 + x * x) + gv * x * y
    J[:, 5] = gv * x - gu * y
    if fit:
        J[:, 6] = -ea * cur
        J[:, 7] = -ea
    wts, cost = _robust(r, s.huber, cutoff)
    Jw = J * wts[:, None]
    H = (Jw.T @ J) / n + Hp
    g = (Jw.T @ r) / n + gp
    energy = (float(cost.sum()) + out_cost) / n + prior
    n_in = int(np.count_nonzero(np.abs(r) <= cutoff))
    return _Eval(energy, H, g, m, n_in, float(np.abs(r).mean()))


@dataclass
class _Estimate:
    T: np.ndarray  # keyframe camera -> frame camera
    a: float
    b: float


def _update(est: _Estimate, delta: np.ndarray) -> _Estimate:
    """Apply an LM step: 6 pose increments, and 2 brightness ones when brightness is fitted."""
    T = se3.orthonormalize(se3.exp(delta[:6]) @ est.T)
    if len(delta) < 8:
        return _Estimate(T, est.a, est.b)
    return _Estimate(T, est.a + float(delta[6]), est.b + float(delta[7]))


def _optimise(pts: _Points, level: _Level, est: _Estimate, s: TrackerSettings) -> tuple[_Estimate, _Eval, bool]:
    """Levenberg-Marquardt on one level; returns the estimate, its evaluation and whether it converged.

    As in DSO, the outlier cutoff is doubled (up to 3 times) while fewer than half the points are inliers,
    so a poor start at a coarse level still has residuals to pull on.
    """
    cutoff = s.outlier_residual
    cur = _evaluate(pts, level, est.T, est.a, est.b, cutoff, s)
    for _ in range(3):
        if cur.n_inliers >= 0.5 * len(pts.intensity):
            break
        cutoff *= 2.0
        cur = _evaluate(pts, level, est.T, est.a, est.b, cutoff, s)
    lam = 1e-3
    for _ in range(s.max_iterations):
        A = cur.H + lam * np.diag(np.diag(cur.H)) + 1e-12 * np.eye(len(cur.g))
        try:
            delta = -np.linalg.solve(A, cur.g)
        except np.linalg.LinAlgError:
            return est, cur, False
        if not np.all(np.isfinite(delta)):
            return est, cur, False
        trial = _update(est, delta)
        ev = _evaluate(pts, level, trial.T, trial.a, trial.b, cutoff, s)
        small = (
            np.linalg.norm(delta[:3]) / pts.median_depth < s.step_tolerance
            and np.linalg.norm(delta[3:6]) < s.step_tolerance
        )
        if ev.energy < cur.energy:
            gain = (cur.energy - ev.energy) / max(cur.energy, 1e-12)
            est, cur, lam = trial, ev, max(lam * 0.5, 1e-6)
            if small or gain < s.energy_tolerance:
                return est, cur, True
        else:
            lam *= 4.0
            if small or lam > 1e4:  # no decrease even for tiny or heavily damped steps: at a minimum
                return est, cur, True
    return est, cur, False


def _align(
    kf_pts: list[_Points], cur: list[_Level], init: _Estimate, s: TrackerSettings
) -> tuple[_Estimate, _Eval, bool]:
    """Coarse to fine from ``init``; the finest level's evaluation and convergence are returned."""
    est = init
    for lvl in range(len(cur) - 1, 0, -1):
        est, _, _ = _optimise(kf_pts[lvl], cur[lvl], est, s)
    return _optimise(kf_pts[0], cur[0], est, s)


# ---------------------------------------------------------------------------------------------- the clip


@dataclass
class _Keyframe:
    index: int
    pose: np.ndarray  # estimated camera-to-world
    affine: tuple[float, float]  # relative to frame 0
    points: list[_Points]


def _make_keyframe(
    index: int,
    pose: np.ndarray,
    affine: tuple[float, float],
    pyr: list[_Level],
    depth: np.ndarray,
    s: TrackerSettings,
) -> _Keyframe:
    depths = _depth_pyramid(depth, len(pyr), s.depth_edge_ratio)
    pts = [
        _select(
            pyr[lvl],
            depths[lvl],
            max(s.n_points >> (2 * lvl), s.min_level_points),
            max(4, s.region_size >> lvl),
            s,
        )
        for lvl in range(len(pyr))
    ]
    return _Keyframe(index, pose, affine, pts)


def _chain_affine(kf: tuple[float, float], rel: tuple[float, float]) -> tuple[float, float]:
    """I_k = e^{a_k} I_0 + b_k and I_j = e^{a} I_k + b  =>  I_j = e^{a_k + a} I_0 + (e^{a} b_k + b)."""
    return kf[0] + rel[0], math.exp(rel[0]) * kf[1] + rel[1]


def _validate(
    frames: Sequence[np.ndarray],
    depths: Sequence[np.ndarray],
    K: np.ndarray,
    gt_poses: Sequence[np.ndarray] | None,
) -> np.ndarray:
    n = len(frames)
    if n == 0:
        raise ValueError("no frames to track")
    if len(depths) != n:
        raise ValueError(f"got {n} frames but {len(depths)} depth maps")
    if gt_poses is not None and len(gt_poses) != n:
        raise ValueError(f"got {n} frames but {len(gt_poses)} ground-truth poses")
    shape = np.asarray(frames[0]).shape[:2]
    for i, (f, d) in enumerate(zip(frames, depths, strict=True)):
        f, d = np.asarray(f), np.asarray(d)
        if f.dtype != np.uint8 or not (f.ndim == 2 or (f.ndim == 3 and f.shape[2] == 3)):
            raise ValueError(f"frame {i}: expected uint8 (H, W, 3) RGB or (H, W) grey, got {f.dtype} {f.shape}")
        if f.shape[:2] != shape:
            raise ValueError(f"frame {i} is {f.shape[:2]}, frame 0 is {shape}: all frames must match")
        if d.shape != shape or not np.issubdtype(d.dtype, np.number):
            raise ValueError(f"depth {i} is {d.dtype} {d.shape}, expected numbers of shape {shape} (the frame's)")
        if gt_poses is not None:
            p = np.asarray(gt_poses[i], dtype=np.float64)
            if p.shape != (4, 4) or not np.all(np.isfinite(p)):
                raise ValueError(f"ground-truth pose {i} must be a finite 4x4 matrix, got shape {p.shape}")
    if min(shape) < 8:
        raise ValueError(f"frames of {shape} are too small to track (need at least 8x8)")
    Km = np.asarray(K, dtype=np.float64)
    if Km.shape != (3, 3):
        raise ValueError(f"K must be 3x3, got shape {Km.shape}")
    if not (np.all(np.isfinite(Km)) and Km[0, 0] > 0 and Km[1, 1] > 0):
        raise ValueError("K must be finite with positive focal lengths fx = K[0,0], fy = K[1,1]")
    return Km


def _errors(
    est: list[np.ndarray], gt: list[np.ndarray], ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Relative-to-keyframe and absolute errors, plus the true keyframe-to-frame translation."""
    n = len(est)
    t_rel, r_rel, t_abs, r_abs, step = (np.zeros(n) for _ in range(5))
    for j in range(n):
        k = int(ref[j])
        rel_gt = se3.inverse(gt[k]) @ gt[j]
        E = se3.inverse(rel_gt) @ (se3.inverse(est[k]) @ est[j])
        t_rel[j], r_rel[j] = np.linalg.norm(E[:3, 3]), se3.rotation_angle_deg(E[:3, :3])
        D = se3.inverse(gt[j]) @ est[j]
        t_abs[j], r_abs[j] = np.linalg.norm(D[:3, 3]), se3.rotation_angle_deg(D[:3, :3])
        step[j] = np.linalg.norm(rel_gt[:3, 3])
    return t_rel, r_rel, t_abs, r_abs, step


def track_clip(
    frames: Sequence[np.ndarray],
    depths: Sequence[np.ndarray],
    K: np.ndarray,
    gt_poses: Sequence[np.ndarray] | None = None,
    settings: TrackerSettings = TrackerSettings(),  # frozen, so one shared default is safe
    scene: np.ndarray | None = None,
) -> TrackResult:
    """Track ``frames`` (uint8 (H, W, 3) RGB or (H, W) grey) with known per-frame ``depths`` (z-depth in
    metres, inf/NaN/<= 0 = unknown).

    ``K``: 3x3 pinhole intrinsics of the frames, pixel centres at integer coordinates. ``gt_poses``:
    camera-to-world 4x4 (metres, OpenCV axes); when given, the first estimated pose is the first
    ground-truth one and errors and the success test use them. ``scene``: ``(H, W)`` bool, True where the frames
    show the scene (a scope's content area); keyframe points are chosen only inside it, ``SCENE_MARGIN`` pixels
    from its edge, as a SLAM system is given its camera's mask: a border and on-screen text do not move with the
    camera, and the field of view's edge is the strongest gradient in the picture. Inconsistent inputs raise
    ValueError.
    """
    Km = _validate(frames, depths, K, gt_poses)
    s = settings
    keep = _scene_points(scene, np.asarray(frames[0]).shape[:2])
    if keep is not None:
        depths = [np.where(keep, np.asarray(d, dtype=np.float64), np.inf) for d in depths]
    n = len(frames)
    gt = [np.asarray(p, dtype=np.float64) for p in gt_poses] if gt_poses is not None else None
    n_lv = _n_levels(np.asarray(frames[0]).shape[:2], s)
    scenes = _scene_pyramid(None if keep is None else np.asarray(scene), n_lv)
    poses = [gt[0].copy() if gt is not None else np.eye(4)]
    affine = np.zeros((n, 2))
    residual, valid = np.zeros(n), np.ones(n)
    converged = np.ones(n, dtype=bool)
    keyframe_of = np.zeros(n, dtype=int)
    lost: dict[int, str] = {}
    pyr = _pyramid(np.asarray(frames[0]), Km, n_lv, s.saturation, scenes)
    kf = _make_keyframe(0, poses[0], (0.0, 0.0), pyr, np.asarray(depths[0]), s)
    keyframes = [0]
    rel_affine = (0.0, 0.0)
    for j in range(1, n):
        pyr = _pyramid(np.asarray(frames[j]), Km, n_lv, s.saturation, scenes)
        est, ev, conv = _align(kf.points, pyr, _predict(poses, kf, rel_affine), s)
        frac = ev.n_valid / max(len(kf.points[0].intensity), 1)
        why = _lost_reason(est, ev, frac, kf, s)
        if why is not None:  # lost: hold the previous pose and restart from this frame as a keyframe
            lost[j] = why
            est = _Estimate(se3.inverse(poses[-1]) @ kf.pose, *rel_affine)
        pose = se3.orthonormalize(kf.pose @ se3.inverse(est.T))
        poses.append(pose)
        rel_affine = (est.a, est.b)
        affine[j] = _chain_affine(kf.affine, rel_affine)
        residual[j], valid[j], converged[j] = ev.mean_abs, frac, conv and why is None
        keyframe_of[j] = kf.index
        if why is not None or _needs_keyframe(j, kf, est, frac, s):
            kf = _make_keyframe(j, pose, (float(affine[j, 0]), float(affine[j, 1])), pyr, np.asarray(depths[j]), s)
            keyframes.append(j)
            rel_affine = (0.0, 0.0)
    return _result(poses, affine, residual, converged, valid, keyframe_of, keyframes, lost, gt, s)


def _scene_points(scene: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    """Where keyframe points may be chosen: ``scene`` less ``SCENE_MARGIN`` pixels along its edge (None: all)."""
    if scene is None:
        return None
    mask = np.asarray(scene)
    if mask.shape != shape or mask.dtype != bool:
        raise ValueError(f"scene must be a bool mask of the frames' shape {shape}, got {mask.dtype} {mask.shape}")
    if mask.all():
        return None
    inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=SCENE_MARGIN, borderValue=1)
    return inner.astype(bool)


def _needs_keyframe(j: int, kf: _Keyframe, est: _Estimate, frac: float, s: TrackerSettings) -> bool:
    """Keyframe policy: every ``keyframe_interval`` frames, on low overlap, or on a long baseline."""
    baseline = float(np.linalg.norm(est.T[:3, 3])) / kf.points[0].median_depth
    return j - kf.index >= s.keyframe_interval or frac < s.min_overlap or baseline > s.max_keyframe_baseline


def _lost_reason(est: _Estimate, ev: _Eval, frac: float, kf: _Keyframe, s: TrackerSettings) -> str | None:
    """Why the alignment cannot be trusted (None when it can)."""
    if not (np.all(np.isfinite(est.T)) and math.isfinite(est.a) and math.isfinite(est.b)):
        return "diverged (non-finite estimate)"
    if frac < s.min_valid_fraction or ev.n_valid < s.min_points:
        return f"lost: only {ev.n_valid} keyframe points ({frac:.0%}) in view"
    t = float(np.linalg.norm(est.T[:3, 3]))
    if t > s.max_jump * kf.points[0].median_depth:
        return f"diverged: {t * 1000:.1f} mm from the keyframe (> {s.max_jump:g} x its median depth)"
    return None


def _predict(poses: list[np.ndarray], kf: _Keyframe, rel_affine: tuple[float, float]) -> _Estimate:
    """Constant-motion start: the last inter-frame motion again, and the last brightness change."""
    prev = poses[-1]
    motion = se3.inverse(poses[-2]) @ prev if len(poses) >= 2 else np.eye(4)
    return _Estimate(se3.inverse(prev @ motion) @ kf.pose, *rel_affine)


def _result(
    poses: list[np.ndarray],
    affine: np.ndarray,
    residual: np.ndarray,
    converged: np.ndarray,
    valid: np.ndarray,
    keyframe_of: np.ndarray,
    keyframes: list[int],
    lost: dict[int, str],
    gt: list[np.ndarray] | None,
    s: TrackerSettings,
) -> TrackResult:
    failures = dict(lost)
    errs: tuple[np.ndarray, ...] | None = None
    if gt is not None:
        errs = _errors(poses, gt, keyframe_of)
        t_rel, r_rel, _, _, step = errs
        t_lim = np.maximum(s.max_translation_error_m, s.relative_translation_error * step)
        for j in np.flatnonzero((t_rel > t_lim) | (r_rel > s.max_rotation_error_deg)):
            failures.setdefault(int(j), f"pose error {t_rel[j] * 1000:.2f} mm / {r_rel[j]:.2f} deg over the threshold")
    failed_at = min(failures) if failures else None
    frame_ok = np.ones(len(poses), dtype=bool)
    frame_ok[list(failures)] = False
    return TrackResult(
        poses=poses,
        affine=affine,
        residual=residual,
        converged=converged,
        valid_fraction=valid,
        keyframe_of=keyframe_of,
        keyframes=tuple(keyframes),
        translation_error_m=errs[0] if errs else None,
        rotation_error_deg=errs[1] if errs else None,
        drift_translation_m=errs[2] if errs else None,
        drift_rotation_deg=errs[3] if errs else None,
        success=failed_at is None,
        failed_at=failed_at,
        failure_reason=failures[failed_at] if failed_at is not None else None,
        frame_ok=frame_ok,
    )


def benchmark(width: int = 256, n_frames: int = 60, seed: int = 1) -> float:
    """CPU milliseconds per tracked frame on a steady synthetic clip (train-split knobs, no occluder).

    The clip is generated first (not timed); run with ``OMP_NUM_THREADS=1`` for the one-core figure.
    """
    import time

    from colonlight.synth import SynthConfig, build_scene, generate_clip

    cfg = SynthConfig.sample(
        np.random.default_rng(seed),
        split="train",
        width=width,
        height=width,
        n_frames=n_frames,
        steady=True,
        close_occluder="forbid",
    )
    frames = list(generate_clip(cfg, seed))
    it = build_scene(cfg, seed).intrinsics
    K = np.array([[it.fx, 0.0, it.cx], [0.0, it.fy, it.cy], [0.0, 0.0, 1.0]])
    t0 = time.process_time()
    track_clip([f.clean for f in frames], [f.depth for f in frames], K, [f.pose for f in frames])
    return (time.process_time() - t0) * 1000.0 / max(n_frames - 1, 1)
