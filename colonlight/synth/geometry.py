"""The colon as an implicit tube: shape, evaluation and the tables the ray marcher needs.

The wall is ``F(p) = r(z, theta) - rho = 0`` (F > 0 inside), with ``rho`` and ``theta`` the polar coordinates
of ``p`` around a bending centre line ``c(z)`` in the slice of constant ``z`` (the tube runs along +z; bends
are gentle, so slices stand in for true cross-sections). The radius

    r = R(z) * (1 + tau cos 3(theta - phi(z)) + eps cos 2(theta - phi2)) - D(z_f) * W(theta, z)

has a rounded triangular section (``tau``, corners = taeniae), a slow twist ``phi(z)``, haustral folds ``D``
(ridges of depth d_k, width s_k and profile exp(-|u/s|^p), read at ``z_f = z + T(z).(cos, sin)`` so rings are
oblique and wavy), deepest between the taeniae and lopsided per fold (``W``). Every z-dependence is tabulated
on a 0.25 mm grid; cos 3theta etc. come from polynomials in cos theta, sin theta (no trigonometric calls).

For marching (``raymarch``): ``safe`` is a (z, rho) table of a lower bound of the distance to the wall (from
the smallest radius over z windows of 0.5..128 mm), ``fold_free`` the longest step that cannot pass through a
fold, and a (angle, z) table of r, r_z, r_theta gives F and its gradient with one bilinear lookup. All lengths
in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .config import SynthConfig

DZ = 0.25  # mm, z grid of the tables
DR = 0.25  # mm, rho grid of the distance-bound table
_LEVELS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0)  # mm half-windows of the distance bound

# columns of Tube.rows
_CX, _CY, _DCX, _DCY, _R, _DR, _TAU, _C3, _S3, _EPS, _C2, _S2, _TX, _TY, _AC, _AS = range(16)
_N_ANG = 384  # angle samples of the marching table


@dataclass
class Tube:
    """Tabulated tube: ``rows[i]`` holds the z-dependent values at ``z0 + i*DZ``, ``fold[i]`` = (D, D')."""

    z0: float
    rows: np.ndarray  # (Nz, 16) float32
    fold: np.ndarray  # (Nz, 2) float32
    arc: np.ndarray  # (Nz,) float64, texture coordinate along the tube (mm of unrolled wall)
    safe: np.ndarray  # (Nz, Nr) float32, lower bound of the distance to the wall
    fold_free: np.ndarray  # (Nz,) float32, longest step (mm) that cannot jump over a fold
    fold_z: np.ndarray  # heights (mm) of the crests of the clearly visible folds
    taenia: float  # fold weight reduction at the taeniae (0 = full rings)
    radius_mm: float  # nominal radius

    # ---------------------------------------------------------------- construction
    @classmethod
    def build(cls, cfg: SynthConfig, rng: np.random.Generator, z_lo: float, z_hi: float) -> Tube:
        """Draw the tube's shape (from ``cfg`` and ``rng``) over ``z_lo..z_hi`` mm."""
        z0 = float(np.floor(z_lo / DZ) * DZ) - 2.0
        nz = int(np.ceil((z_hi - z0) / DZ)) + 2
        z = z0 + DZ * np.arange(nz)
        R0 = cfg.radius_mm
        rows = np.zeros((nz, 16), np.float64)

        # centre line: two sinusoids per axis (gentle bends)
        cx = np.zeros(nz)
        cy = np.zeros(nz)
        dcx = np.zeros(nz)
        dcy = np.zeros(nz)
        for amp_f, wl_f in ((1.0, 1.0), (0.4, float(rng.uniform(0.35, 0.7)))):
            amp = cfg.bend_amp_mm * amp_f
            w = 2 * np.pi / (cfg.bend_wavelength_mm * wl_f)
            for arr, darr in ((cx, dcx), (cy, dcy)):
                ph = rng.uniform(0, 2 * np.pi)
                a = amp * rng.uniform(0.3, 1.0)
                arr += a * np.sin(w * z + ph)
                darr += a * w * np.cos(w * z + ph)
        rows[:, _CX], rows[:, _CY], rows[:, _DCX], rows[:, _DCY] = cx, cy, dcx, dcy

        # radius with slow variation
        rv = _smooth_table(rng, nz, corr_mm=60.0) * cfg.radius_var
        R = R0 * np.exp(rv)
        rows[:, _R] = R
        rows[:, _DR] = np.gradient(R, DZ)

        # triangular section with twist, ellipticity
        phi = rng.uniform(0, 2 * np.pi) + np.deg2rad(cfg.twist_deg_per_100mm) * (z - z0) / 100.0
        phi += 0.15 * _smooth_table(rng, nz, corr_mm=80.0)
        tau = np.clip(cfg.triangularity * (1 + 0.25 * _smooth_table(rng, nz, corr_mm=100.0)), 0, 0.3)
        rows[:, _TAU], rows[:, _C3], rows[:, _S3] = tau, np.cos(3 * phi), np.sin(3 * phi)
        phi2 = rng.uniform(0, 2 * np.pi) + 0.3 * _smooth_table(rng, nz, corr_mm=120.0)
        rows[:, _EPS], rows[:, _C2], rows[:, _S2] = cfg.ellipticity, np.cos(2 * phi2), np.sin(2 * phi2)

        # oblique, wavy rings: fold profile read at z + T.(cos, sin)
        tilt = cfg.fold_tilt * R0
        rows[:, _TX] = tilt * _smooth_table(rng, nz, corr_mm=40.0) / np.sqrt(2)
        rows[:, _TY] = tilt * _smooth_table(rng, nz, corr_mm=40.0) / np.sqrt(2)
        tmax = float(np.max(np.hypot(rows[:, _TX], rows[:, _TY]))) + DZ

        # haustral folds
        D = np.zeros(nz)
        dD = np.zeros(nz)
        owner = np.full(nz, -1)
        best = np.full(nz, np.inf)
        fwhm_min = np.inf
        centres = []
        depths = []
        zc = z0 - rng.uniform(0, cfg.fold_spacing_mm)
        while zc < z[-1] + cfg.fold_spacing_mm:
            centres.append(zc)
            zc += cfg.fold_spacing_mm * (1 + cfg.fold_spacing_jitter * rng.uniform(-1, 1))
        asym_c = np.zeros(len(centres))
        asym_s = np.zeros(len(centres))
        for k, zk in enumerate(centres):
            depth = cfg.fold_depth * R0 * max(0.0, 1 + cfg.fold_depth_var * rng.standard_normal())
            if rng.random() < cfg.fold_gap_prob:
                depth *= 0.15
            depths.append(depth)
            s = cfg.fold_width_mm * rng.uniform(0.8, 1.25)
            p = cfg.fold_sharpness
            fwhm_min = min(fwhm_min, 2 * s * np.log(2) ** (1 / p))
            u = (z - zk) / s
            au = np.abs(u)
            b = np.exp(-(au**p))
            D += depth * b
            # d/dz exp(-|u|^p) = -p |u|^(p-1) sign(u) b / s
            dD += depth * (-p * np.power(np.maximum(au, 1e-9), p - 1) * np.sign(u) * b / s)
            a = cfg.fold_asym * rng.uniform(0, 1)
            ang = rng.uniform(0, 2 * np.pi)
            asym_c[k], asym_s[k] = a * np.cos(ang), a * np.sin(ang)
            closer = np.abs(z - zk) < best
            best[closer] = np.abs(z - zk)[closer]
            owner[closer] = k
        # never let folds (with their lopsidedness) close the lumen: soft-limit the summed depth
        d_cap = (
            0.7 * R0 * (1 - cfg.triangularity - cfg.ellipticity) * np.exp(-2.5 * cfg.radius_var) / (1 + cfg.fold_asym)
        )
        th = np.tanh(D / d_cap)
        dD = dD * (1 - th**2)
        D = d_cap * th
        rows[:, _AC] = asym_c[owner]
        rows[:, _AS] = asym_s[owner]
        asym_max = np.hypot(rows[:, _AC], rows[:, _AS])

        # texture coordinate along the tube: unrolled length of the mean wall profile
        slope = np.hypot(dD * (1 - cfg.fold_taenia / 2), rows[:, _DR])
        arc = np.concatenate(
            [[0.0], np.cumsum(0.5 * (np.sqrt(1 + slope[1:] ** 2) + np.sqrt(1 + slope[:-1] ** 2)) * DZ)]
        )

        # smallest radius of each slice (over theta, and over the fold shift T), then the distance-bound table
        # the fold is read at z + T.(cos, sin): take the deepest fold within the local |T| of each slice
        tlen = np.hypot(rows[:, _TX], rows[:, _TY])
        dw = D * (1 + asym_max)
        d_shift = dw.copy()
        n_t = int(np.ceil(tmax / DZ))
        for k in range(1, n_t + 1, max(1, n_t // 12)):
            m = _window_max(dw, k)
            sel = tlen > (k - max(1, n_t // 12)) * DZ
            d_shift[sel] = np.maximum(d_shift[sel], m[sel])
        d_shift = np.maximum(d_shift, _window_max(dw, 0))
        rmin = R * (1 - tau - cfg.ellipticity) - d_shift
        # distance (mm) from each slice to the nearest fold (where its profile is not negligible), minus tilt
        present = np.nonzero(D > 0.05)[0]
        if present.size:
            pos = np.searchsorted(present, np.arange(nz))
            left = present[np.clip(pos - 1, 0, present.size - 1)]
            right = present[np.clip(pos, 0, present.size - 1)]
            gap = np.minimum(np.abs(np.arange(nz) - left), np.abs(right - np.arange(nz))) * DZ
            fold_free = np.maximum(gap - _window_max(tlen, n_t) - DZ, 0.0)
        else:
            fold_free = np.full(nz, 1e3)
        rmax_all = float(np.max(R * (1 + tau + cfg.ellipticity))) + 1.0
        nr = int(np.ceil(rmax_all / DR)) + 2
        rho = DR * np.arange(nr)
        safe = np.zeros((nz, nr), np.float32)
        for h in _LEVELS:
            n_w = int(np.ceil((h + DZ) / DZ))  # half-window in samples, + one sample for nearest-index lookups
            lo = _window_min(rmin, n_w)
            # centre-line excursion within the window (a neighbouring slice's wall is measured from its own c)
            ex = np.hypot(_window_max(cx, n_w) - _window_min(cx, n_w), _window_max(cy, n_w) - _window_min(cy, n_w))
            r_lo = lo - ex
            lvl = np.minimum(h, r_lo[:, None] - rho[None, :])
            np.maximum(safe, lvl.astype(np.float32), out=safe)
        safe -= 0.02  # float32 round-off margin
        np.maximum(safe, 0, out=safe)
        return cls(
            z0=z0,
            rows=rows.astype(np.float32),
            fold=np.stack([D, dD], axis=1).astype(np.float32),
            # a step shorter than ~half a fold's width cannot pass through its core
            fold_free=np.maximum(fold_free, max(0.5, 0.6 * fwhm_min)).astype(np.float32),
            fold_z=np.array(centres)[np.array(depths) > 0.25 * cfg.fold_depth * R0],
            arc=arc,
            safe=safe,
            taenia=float(cfg.fold_taenia),
            radius_mm=float(R0),
        )

    # ---------------------------------------------------------------- evaluation
    def __post_init__(self) -> None:
        # value and forward difference side by side: one gather per lookup, then a multiply-add
        self._rows2 = _pairs(self.rows)
        self._fold2 = _pairs(self.fold)
        self.centre_xy = np.ascontiguousarray(self.rows[:, [_CX, _CY]])  # nearest-sample centre line
        self._build_fast()

    def _lerp_rows(self, table2: np.ndarray, z: np.ndarray) -> np.ndarray:
        k = table2.shape[1] // 2
        f = (z - self.z0) * np.float32(1.0 / DZ)
        i = np.clip(f.astype(np.int32), 0, len(table2) - 1)
        w = np.clip(f - i, 0.0, 1.0).astype(np.float32)[:, None]
        g = table2[i]
        return g[:, :k] + g[:, k:] * w

    def _radius(
        self, row: np.ndarray, z: np.ndarray, c: np.ndarray, s: np.ndarray, grad: bool
    ) -> tuple[np.ndarray, ...]:
        """Wall radius r at heights ``z`` and directions (c, s) = (cos, sin) theta; with ``grad``: r_z,
        r_theta."""
        c2t = c * c - s * s
        s2t = 2 * c * s
        c3t = c * (4 * c * c - 3)
        s3t = s * (3 - 4 * s * s)
        cos3 = c3t * row[:, _C3] + s3t * row[:, _S3]  # cos 3(theta - phi)
        cos2 = c2t * row[:, _C2] + s2t * row[:, _S2]
        cos1 = c * row[:, _AC] + s * row[:, _AS]  # a_k cos(theta - psi_k)
        zf = z + c * row[:, _TX] + s * row[:, _TY]
        fd = self._lerp_rows(self._fold2, zf)
        D, dD = fd[:, 0], fd[:, 1]
        tae = 1 - self.taenia * 0.5 * (1 + cos3)
        W = tae * (1 + cos1)
        shape = 1 + row[:, _TAU] * cos3 + row[:, _EPS] * cos2
        R = row[:, _R]
        r = R * shape - D * W
        if not grad:
            return (r,)
        sin3 = s3t * row[:, _C3] - c3t * row[:, _S3]  # sin 3(theta - phi)
        sin2 = s2t * row[:, _C2] - c2t * row[:, _S2]
        sin1 = s * row[:, _AC] - c * row[:, _AS]
        dtae = self.taenia * 0.5 * 3 * sin3
        dW = dtae * (1 + cos1) + tae * (-sin1)
        dzf_dth = -s * row[:, _TX] + c * row[:, _TY]
        r_th = R * (-3 * row[:, _TAU] * sin3 - 2 * row[:, _EPS] * sin2) - D * dW - dD * W * dzf_dth
        r_z = row[:, _DR] * shape - dD * W
        return r, r_z, r_th

    def evaluate(self, p: np.ndarray, grad: bool = False) -> tuple[np.ndarray, ...]:
        """F at points ``p`` (N,3) mm; with ``grad``: also grad F (N,3) and cos/sin theta (exact, for
        shading).

        F > 0 inside. grad F points into the lumen (it is the unnormalised surface normal facing the camera).
        """
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        row = self._lerp_rows(self._rows2, z)
        qx = x - row[:, _CX]
        qy = y - row[:, _CY]
        rho = np.sqrt(qx * qx + qy * qy)
        inv = 1.0 / np.maximum(rho, 1e-6)
        c = qx * inv
        s = qy * inv
        if not grad:
            (r,) = self._radius(row, z, c, s, False)
            return (r - rho,)
        r, r_z, r_th = self._radius(row, z, c, s, True)
        g = _grad(r_z, r_th * inv, c, s, row[:, _DCX], row[:, _DCY])
        return r - rho, np.stack(g, axis=1), c, s

    def _build_fast(self) -> None:
        """Tabulate r, r_z, r_theta over (diamond angle, z): the marcher then needs one bilinear lookup."""
        nz = len(self.rows)
        da = np.arange(_N_ANG, dtype=np.float64) * (4.0 / _N_ANG)
        cs = _from_diamond(da)
        tab = np.empty((_N_ANG, nz, 3), np.float32)
        zg = (self.z0 + DZ * np.arange(nz)).astype(np.float32)
        for i in range(_N_ANG):
            c = np.full(nz, cs[i, 0], np.float32)
            s = np.full(nz, cs[i, 1], np.float32)
            r, r_z, r_th = self._radius(self.rows, zg, c, s, True)
            tab[i, :, 0], tab[i, :, 1], tab[i, :, 2] = r, r_z, r_th
        self._rtab = tab
        self._line = np.ascontiguousarray(self.rows[None, :, [_CX, _CY, _DCX, _DCY]], dtype=np.float32)

    def evaluate_fast(self, p: np.ndarray, d: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """F, |grad F| and (with ray directions ``d``) dF/dt = grad F . d at points ``p``, from bilinear
        tables (for marching; ~3x cheaper than :meth:`evaluate`, within ~0.05 mm of it)."""
        z = p[:, 2]
        mx = (z - np.float32(self.z0)) * np.float32(1.0 / DZ)
        row = _remap_points(self._line, mx, np.zeros_like(mx))
        qx = p[:, 0] - row[:, 0]
        qy = p[:, 1] - row[:, 1]
        rho = np.sqrt(qx * qx + qy * qy)
        inv = 1.0 / np.maximum(rho, np.float32(1e-6))
        c = qx * inv
        s = qy * inv
        my = _to_diamond(c, s) * np.float32(_N_ANG / 4.0)
        v = _remap_points(self._rtab, mx, my)
        k = v[:, 2] * inv
        gz = k * (s * row[:, 2] - c * row[:, 3]) + v[:, 1] + (c * row[:, 2] + s * row[:, 3])
        gn = np.sqrt(1 + k * k + gz * gz)
        if d is None:
            return v[:, 0] - rho, gn, gn
        dfdt = (-k * s - c) * d[:, 0] + (k * c - s) * d[:, 1] + gz * d[:, 2]
        return v[:, 0] - rho, gn, dfdt

    def centre(self, z: np.ndarray) -> np.ndarray:
        """Centre line points (N,3) at heights ``z``."""
        row = self._lerp_rows(self._rows2, np.asarray(z, np.float32))
        return np.stack([row[:, _CX], row[:, _CY], np.asarray(z, np.float32)], axis=1)

    def tangent(self, z: np.ndarray) -> np.ndarray:
        """Unit centre-line tangents (N,3)."""
        row = self._lerp_rows(self._rows2, np.asarray(z, np.float32))
        t = np.stack([row[:, _DCX], row[:, _DCY], np.ones(len(row), np.float32)], axis=1).astype(np.float64)
        unit: np.ndarray = t / np.linalg.norm(t, axis=1, keepdims=True)
        return unit

    def min_radius(self, z: np.ndarray) -> np.ndarray:
        """A conservative free radius around the centre line at ``z`` (for placing the camera)."""
        iz = np.clip(np.rint((np.asarray(z) - self.z0) / DZ).astype(np.int64), 0, len(self.safe) - 1)
        free = self.safe[iz] > 0
        radius: np.ndarray = DR * free.sum(axis=1).astype(np.float64)
        return radius

    def arc_at(self, z: np.ndarray) -> np.ndarray:
        """Texture coordinate along the tube (mm) at heights ``z``."""
        arc: np.ndarray = np.interp(z, self.z0 + DZ * np.arange(len(self.arc)), self.arc)
        return arc


def _grad(
    r_z: np.ndarray, k: np.ndarray, c: np.ndarray, s: np.ndarray, dcx: np.ndarray, dcy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """grad F = r_theta grad theta + r_z e_z - grad rho, with k = r_theta / rho,
    grad rho = (c, s, -(c dcx + s dcy)) and grad theta = (-s, c, s dcx - c dcy) / rho."""
    gx = -k * s - c
    gy = k * c - s
    gz = k * (s * dcx - c * dcy) + r_z + (c * dcx + s * dcy)
    return gx, gy, gz


def _to_diamond(c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """A cheap monotonic stand-in for the angle (0..4 for 0..2pi) without arctan2."""
    a = np.abs(c) + np.abs(s)
    u = c / a
    v = s / a
    p: np.ndarray = np.where(s >= 0, np.where(c >= 0, v, 1 - u), np.where(c < 0, 2 - v, 3 + u))
    return p


def _from_diamond(p: np.ndarray) -> np.ndarray:
    """Unit (cos, sin) for diamond angles ``p`` in [0, 4)."""
    x = np.where(p < 1, 1 - p, np.where(p < 2, 1 - p, np.where(p < 3, p - 3, p - 3)))
    y = np.where(p < 1, p, np.where(p < 2, 2 - p, np.where(p < 3, 2 - p, p - 4)))
    v = np.stack([x, y], axis=1)
    unit: np.ndarray = v / np.linalg.norm(v, axis=1, keepdims=True)
    return unit


def _remap_points(table: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``table`` (rows x cols x ch) at column ``mx``, row ``my`` (rows wrap), as (N, ch).

    cv2.remap limits map sides to < 32767, so longer point lists are laid out in rows of 4096."""
    n = len(mx)
    mx = mx.astype(np.float32, copy=False)
    my = my.astype(np.float32, copy=False)
    if n < 32767:
        out = cv2.remap(table, mx.reshape(1, n), my.reshape(1, n), cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return out.reshape(n, -1)
    w = 4096
    m = -(-n // w)
    ax = np.zeros(m * w, np.float32)
    ay = np.zeros(m * w, np.float32)
    ax[:n] = mx
    ay[:n] = my
    out = cv2.remap(table, ax.reshape(m, w), ay.reshape(m, w), cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    return out.reshape(m * w, -1)[:n]


def _pairs(table: np.ndarray) -> np.ndarray:
    """(N, K) -> (N, 2K): each row followed by its forward difference (zero at the end)."""
    diff = np.zeros_like(table)
    diff[:-1] = table[1:] - table[:-1]
    return np.ascontiguousarray(np.concatenate([table, diff], axis=1), dtype=np.float32)


def _smooth_table(rng: np.random.Generator, n: int, corr_mm: float) -> np.ndarray:
    """Unit-std smooth noise along the z grid with ~``corr_mm`` correlation length."""
    from .noise import smooth_series

    # draw on a coarse grid (1 sample per mm) and interpolate: cheap and smooth
    n_c = int(np.ceil(n * DZ)) + 2
    coarse = smooth_series(rng, n_c, corr_mm)
    table: np.ndarray = np.interp(np.arange(n) * DZ, np.arange(n_c), coarse)
    return table


def _window_min(a: np.ndarray, half: int) -> np.ndarray:
    """Minimum over a sliding window of +-``half`` samples (edges: window clipped)."""
    if half <= 0:
        return a.copy()
    k = 2 * half + 1
    src = np.pad(a.astype(np.float32), (half, half), mode="edge")[None, :]
    return cv2.erode(src, np.ones((1, k), np.uint8), borderType=cv2.BORDER_REPLICATE)[0, half:-half].astype(np.float64)


def _window_max(a: np.ndarray, half: int) -> np.ndarray:
    """Maximum over a sliding window of +-``half`` samples."""
    return -_window_min(-a, half)
