"""Oracle corrections: the best any method applying one global correction per frame could do.

Where a clip has clean frames (synthetic clips, or a user's own ground truth), each input frame is mapped to its
clean frame by the least-squares best

* ``oracle-gamma``: single gamma, applied as the product applies one (``round(255 * (v / 255) ** gamma)``
  through a 256-entry table, :func:`colonlight.curves.gamma_lut`), gamma within the product's clamp range
  ``[GAMMA_MIN, GAMMA_MAX]``;
* ``oracle-gain-gamma``: gain and gamma, ``round(255 * min(1, gain * (v / 255) ** gamma))`` as the gain-gamma
  head applies them (:func:`colonlight.curves.gain_gamma_lut`), within the product's clamp ranges: the ceiling
  of the shipped default's own family, between the other two;
* ``oracle-curve``: monotone non-decreasing tone curve, one 256-entry table for all three channels.

Each is fitted to every sample (all pixels, all channels) of the frame. They are ceilings, not methods: they
look at the answer. A method's share of the input -> ``oracle-curve`` gap in tracking says how much of what
a per-frame global correction can fix it fixes.

Why least squares over the 256 input levels: the cost of a table ``L`` is ``sum_v n_v L_v^2 - 2 L_v S_v + Q_v``
(``n_v`` samples of input value ``v``, ``S_v`` the sum of their clean values), so one histogram pass per frame
scores any table in 256 operations. The best curve is then the weighted isotonic regression of the mean clean
value per input level (weights ``n_v``; ``scipy.optimize.isotonic_regression``, pool-adjacent-violators), and the
best gamma a search over a log-spaced grid, refined around the best grid point (the rounded table makes the cost
piecewise constant in gamma, so a derivative-based search would stall on a plateau); the best gain and gamma the
same search over a log-spaced grid of both.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from ..curves import apply_lut, gain_gamma_lut, gamma_lut
from ..methods.rnn import GAIN_MAX, GAIN_MIN, GAMMA_MAX, GAMMA_MIN

#: Labels of the reference rows, in table order: the clean frames themselves, then the oracles, widest first.
CLEAN_LABEL, CURVE_LABEL, GAIN_GAMMA_LABEL, GAMMA_LABEL = "clean", "oracle-curve", "oracle-gain-gamma", "oracle-gamma"
REFERENCE_LABELS = (CLEAN_LABEL, CURVE_LABEL, GAIN_GAMMA_LABEL, GAMMA_LABEL)
_LEVELS = np.arange(256, dtype=np.float64)
_COARSE, _FINE = 513, 257  # grid points over the whole log-gamma range, then around the best one
_COARSE_2D, _FINE_2D = 65, 33  # the same per axis for gain and gamma together


@dataclass(frozen=True)
class LevelStats:
    """Per input level v: sample count, sum and sum of squares of the clean values at those samples."""

    count: np.ndarray  # (256,) float64
    total: np.ndarray
    squares: np.ndarray

    def cost(self, luts: np.ndarray) -> np.ndarray:
        """Mean squared error (grey levels^2) of each table in ``luts`` (..., 256) against the clean frame."""
        L = np.asarray(luts, dtype=np.float64)
        sse = (L * L) @ self.count - 2.0 * (L @ self.total) + self.squares.sum()
        mse: np.ndarray = sse / max(self.count.sum(), 1.0)
        return mse


def level_stats(frame: np.ndarray, clean: np.ndarray) -> LevelStats:
    """One pass over the samples of ``frame`` and ``clean`` (uint8, same shape)."""
    if frame.shape != clean.shape or frame.dtype != np.uint8 or clean.dtype != np.uint8:
        raise ValueError(
            f"frame and clean must be uint8 of one shape, got {frame.dtype} {frame.shape} and "
            f"{clean.dtype} {clean.shape}"
        )
    v = frame.ravel()
    c = clean.ravel().astype(np.float64)
    return LevelStats(
        np.bincount(v, minlength=256).astype(np.float64),
        np.bincount(v, weights=c, minlength=256),
        np.bincount(v, weights=c * c, minlength=256),
    )


def _log_axis(lo: float, hi: float, n: int) -> np.ndarray:
    return np.exp(np.linspace(np.log(lo), np.log(hi), n))


def _gamma_grid(lo: float, hi: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    gammas = _log_axis(lo, hi, n)
    luts = np.rint(255.0 * (_LEVELS / 255.0)[None, :] ** gammas[:, None])
    return gammas, luts


_GRID = _gamma_grid(GAMMA_MIN, GAMMA_MAX, _COARSE)


def oracle_gamma(frame: np.ndarray, clean: np.ndarray) -> float:
    """The gamma in ``[GAMMA_MIN, GAMMA_MAX]`` whose table maps ``frame`` closest to ``clean`` (least squares)."""
    stats = level_stats(frame, clean)
    gammas, luts = _GRID
    i = int(np.argmin(stats.cost(luts)))
    lo, hi = gammas[max(i - 1, 0)], gammas[min(i + 1, len(gammas) - 1)]
    fine, fine_luts = _gamma_grid(lo, hi, _FINE)
    cost = stats.cost(fine_luts)
    best = np.flatnonzero(cost <= cost.min() + 1e-9)
    return float(fine[best[len(best) // 2]])  # the middle of the best plateau


def _gain_gamma_tables(gains: np.ndarray, gammas: np.ndarray) -> np.ndarray:
    """``(len(gammas), len(gains), 256)`` tables of ``round(255 * min(1, gain * (v / 255) ** gamma))``."""
    powers = (_LEVELS / 255.0)[None, None, :] ** gammas[:, None, None]
    tables: np.ndarray = np.rint(255.0 * np.minimum(1.0, gains[None, :, None] * powers))
    return tables


@cache
def _gain_gamma_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gains, gammas = _log_axis(GAIN_MIN, GAIN_MAX, _COARSE_2D), _log_axis(GAMMA_MIN, GAMMA_MAX, _COARSE_2D)
    return gains, gammas, _gain_gamma_tables(gains, gammas)


def oracle_gain_gamma(frame: np.ndarray, clean: np.ndarray) -> tuple[float, float]:
    """The ``(gain, gamma)`` within the product's clamp ranges whose table maps ``frame`` closest to ``clean``
    (least squares): the best grid point of both, refined on a finer grid around it."""
    stats = level_stats(frame, clean)
    gains, gammas, tables = _gain_gamma_grid()
    i, j = (int(k) for k in np.unravel_index(int(np.argmin(stats.cost(tables))), tables.shape[:2]))
    last = _COARSE_2D - 1
    fine_gammas = _log_axis(gammas[max(i - 1, 0)], gammas[min(i + 1, last)], _FINE_2D)
    fine_gains = _log_axis(gains[max(j - 1, 0)], gains[min(j + 1, last)], _FINE_2D)
    cost = stats.cost(_gain_gamma_tables(fine_gains, fine_gammas))
    i, j = (int(k) for k in np.unravel_index(int(np.argmin(cost)), cost.shape))
    return float(fine_gains[j]), float(fine_gammas[i])


def oracle_curve(frame: np.ndarray, clean: np.ndarray) -> np.ndarray:
    """The monotone non-decreasing 256-entry uint8 table mapping ``frame`` closest to ``clean`` (least squares).

    Levels the frame does not use are interpolated between their used neighbours (held flat beyond the ends):
    they cost nothing here, and interpolation keeps the table monotone."""
    from scipy.optimize import isotonic_regression

    stats = level_stats(frame, clean)
    seen = np.flatnonzero(stats.count > 0)
    if seen.size == 0:
        return np.arange(256, dtype=np.uint8)
    means = stats.total[seen] / stats.count[seen]
    fitted = isotonic_regression(means, weights=stats.count[seen], increasing=True).x
    table = np.interp(_LEVELS, seen.astype(np.float64), fitted)
    return np.clip(np.rint(table), 0, 255).astype(np.uint8)


def oracle_frames(
    frames: list[np.ndarray], clean: list[np.ndarray], kind: str
) -> tuple[list[np.ndarray], list[float | None]]:
    """Every frame corrected by its own oracle (``kind``: one of the oracle labels), and the gamma per frame
    (``None`` for curves)."""
    if len(frames) != len(clean):
        raise ValueError(f"{len(frames)} frames but {len(clean)} clean frames")
    out: list[np.ndarray] = []
    gammas: list[float | None] = []
    for f, c in zip(frames, clean, strict=True):
        if kind == GAMMA_LABEL:
            g = oracle_gamma(f, c)
            out.append(apply_lut(f, gamma_lut(g)))
            gammas.append(g)
        elif kind == GAIN_GAMMA_LABEL:
            gain, g = oracle_gain_gamma(f, c)
            out.append(apply_lut(f, gain_gamma_lut(gain, g)))
            gammas.append(g)
        elif kind == CURVE_LABEL:
            out.append(apply_lut(f, oracle_curve(f, c)))
            gammas.append(None)
        else:
            raise ValueError(f"unknown oracle {kind!r}; choose from {', '.join(REFERENCE_LABELS[1:])}")
    return out, gammas


__all__ = [
    "CLEAN_LABEL",
    "CURVE_LABEL",
    "GAIN_GAMMA_LABEL",
    "GAMMA_LABEL",
    "REFERENCE_LABELS",
    "LevelStats",
    "level_stats",
    "oracle_curve",
    "oracle_frames",
    "oracle_gain_gamma",
    "oracle_gamma",
]
