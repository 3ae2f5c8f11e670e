"""Ray casting into the tube: where each pixel's ray meets the wall (vectorised over all rays of a frame).

Steps are the larger of two: the table bound of ``Tube.safe`` (guaranteed not to cross the wall) and, near the
wall, a Newton step along the ray ``F / -dF/dt`` (never shorter than the sphere step ``F / |grad F|``, never
longer than ``Tube.fold_free`` so no fold is jumped over). A ray stops when it is within a fraction of its
pixel footprint of the wall (cone-tracing epsilon; then two bounded Newton steps put it on the wall) or when F
changes sign (then the bracket is refined by false position). Finished rays are dropped from the working
arrays now and then, so late iterations only touch the few rays still travelling down the lumen.
"""

from __future__ import annotations

import numpy as np

from .geometry import DR, DZ, Tube


def march(
    tube: Tube, o: np.ndarray, d: np.ndarray, t_max: float, pixel_angle: float = 0.0, max_iter: int = 160
) -> tuple[np.ndarray, np.ndarray]:
    """Distance ``t`` (mm) along unit rays ``d`` (N,3) from ``o`` ((3,) or per ray (N,3)) to the wall, and a
    hit mask.

    ``pixel_angle`` (rad, ~ half a pixel) sets the hit tolerance, which grows with distance.
    Rays leaving the tabulated tube or longer than ``t_max`` do not hit (t = inf).
    """
    n = len(d)
    nz, nr = tube.safe.shape
    safe_flat = tube.safe.reshape(-1)
    inv_dz = np.float32(1.0 / DZ)
    inv_dr = np.float32(1.0 / DR)
    z0 = np.float32(tube.z0)
    o_all = np.broadcast_to(np.asarray(o, np.float32), (n, 3))
    ox, oy, oz = (np.ascontiguousarray(o_all[:, k]) for k in range(3))
    pix = np.float32(pixel_angle)
    t_hit = np.full(n, np.inf, np.float32)
    # state of the rays still marching; finished rays are flagged dead and squeezed out now and then
    act = np.arange(n)
    dx, dy, dz = (np.ascontiguousarray(d[:, k], dtype=np.float32) for k in range(3))
    at = np.full(n, 0.05, np.float32)
    a_tin = np.zeros(n, np.float32)  # last t known to be inside, and F there (nan: not evaluated)
    a_fin = np.full(n, np.nan, np.float32)
    live = np.ones(n, bool)
    n_live = n
    brackets: list[tuple[np.ndarray, ...]] = []
    for _ in range(max_iter):
        if n_live == 0:
            break
        if n_live < 0.7 * len(act):
            marching: tuple[np.ndarray, ...] = (act, ox, oy, oz, dx, dy, dz, at, a_tin, a_fin)
            act, ox, oy, oz, dx, dy, dz, at, a_tin, a_fin = (a[live] for a in marching)
            live = np.ones(len(act), bool)
        fz = (oz + at * dz - z0) * inv_dz
        out = (fz < -0.5) | (fz > nz - 1.5) | (at > t_max)
        iz = np.clip(fz + 0.5, 0, nz - 1).astype(np.int32)
        c = tube.centre_xy[iz]
        qx = ox + at * dx - c[:, 0]
        qy = oy + at * dy - c[:, 1]
        ir = np.sqrt(qx * qx + qy * qy)
        ir *= inv_dr
        ir = np.minimum(np.ceil(ir), nr - 1).astype(np.int32)
        ir += iz * nr
        step = safe_flat[ir]
        # near the wall the table bound is loose: evaluate F and take the larger of bound and Newton step
        near = (step < 1.0) & live & ~out
        n_near = int(np.count_nonzero(near))
        f_new = np.full(len(act), np.nan, np.float32)
        fin = out & live
        if n_near:
            sub = n_near < 0.6 * len(act)
            sel = np.nonzero(near)[0] if sub else slice(None)
            ds = np.stack([dx[sel], dy[sel], dz[sel]], axis=1)
            p = np.stack([ox[sel], oy[sel], oz[sel]], axis=1) + at[sel][:, None] * ds
            F, gn, dfdt = tube.evaluate_fast(p, ds)
            # Newton along the ray (fast on oblique walls; an overshoot is caught as a sign change), never
            # shorter than the sphere step F/|grad F|, never longer than a fold can hide in
            sphere = 0.9 * F / np.maximum(gn, 1.0)
            along = np.where(dfdt < -1e-3, F / np.maximum(-dfdt, np.float32(1e-3)), np.float32(1e3))
            newton = np.clip(np.maximum(sphere, along), 0.04, tube.fold_free[iz[sel]])
            if sub:
                f_new[sel] = F
                step[sel] = np.maximum(step[sel], newton)
            else:
                f_new = np.where(near, F, np.float32(np.nan))
                step = np.where(near, np.maximum(step, newton), step)
            # within a fraction of its pixel footprint of the wall a ray has hit it (cone-tracing epsilon):
            # rays grazing a fold crest would otherwise creep along it in tiny steps
            hit = (f_new < np.maximum(np.float32(0.01), pix * at)) & (f_new >= 0)  # nan -> False
            neg = f_new < 0
            if neg.any():
                brackets.append((act[neg], dx[neg], dy[neg], dz[neg], a_tin[neg], a_fin[neg], at[neg], f_new[neg]))
            if hit.any():
                t_hit[act[hit]] = at[hit]
            fin |= hit | neg
        if fin.any():
            live &= ~fin
            n_live = int(np.count_nonzero(live))
            step[~live] = 0
        a_tin = at
        a_fin = f_new
        at = at + step
    if n_live:  # still marching after max_iter: grazing a wall; take where they are
        t_hit[act[live]] = at[live]
    # rays stopped by the cone epsilon sit up to half a pixel footprint before the wall: two Newton steps
    # along the ray put their depth on it (bounded, so grazing rays cannot run off)
    near_hits = np.nonzero(np.isfinite(t_hit))[0]
    if near_hits.size:
        on = o_all[near_hits]
        dn = np.ascontiguousarray(d[near_hits], dtype=np.float32)
        th = t_hit[near_hits]
        lim = np.maximum(np.float32(0.02), 2 * pix * th)
        for _ in range(2):
            F, _, dfdt = tube.evaluate_fast(on + th[:, None] * dn, dn)
            dt = np.where(dfdt < -0.05, -F / np.minimum(dfdt, -0.05), 0.0)
            th = th + np.clip(dt, -lim, lim).astype(np.float32)
        t_hit[near_hits] = th
    if brackets:
        bi, bx, by, bz, lo, flo, hi, fhi = (np.concatenate(x) for x in zip(*brackets, strict=True))
        t_hit[bi] = _refine(tube, o_all[bi], np.stack([bx, by, bz], axis=1), lo, flo, hi, fhi)
    return t_hit, np.isfinite(t_hit)


def _refine(
    tube: Tube,
    o: np.ndarray,
    d: np.ndarray,
    lo: np.ndarray,
    f_lo: np.ndarray,
    hi: np.ndarray,
    f_hi: np.ndarray,
    iters: int = 5,
) -> np.ndarray:
    """Root of F in each bracket [lo, hi] (F(lo) > 0 > F(hi)) by false position with the Illinois fix
    (bisection where F(lo) is unknown)."""
    f_lo = f_lo.copy()
    for _ in range(iters):
        known = np.isfinite(f_lo)
        frac = np.where(known, f_lo / np.where(known, f_lo - f_hi, 1.0), 0.5)
        mid = lo + np.clip(frac, 0.02, 0.98) * (hi - lo)
        F, _, _ = tube.evaluate_fast(o + mid[:, None] * d)
        ins = F > 0
        # Illinois: halve the stale end's F so the bracket shrinks from both sides
        f_hi = np.where(ins, f_hi * 0.5, F)
        f_lo = np.where(ins, F, f_lo * 0.5)
        lo = np.where(ins, mid, lo)
        hi = np.where(ins, hi, mid)
    known = np.isfinite(f_lo)
    frac = np.where(known, f_lo / np.where(known, f_lo - f_hi, 1.0), 0.5)
    t: np.ndarray = lo + np.clip(frac, 0.0, 1.0) * (hi - lo)
    return t
