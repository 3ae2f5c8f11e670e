"""Lie-group helpers for rigid motions (SO(3), SE(3)) used by the photometric tracker.

Twists are ``xi = (v, w)``: translation part first, then the rotation vector (axis * angle, radians), as in
Sophus/DSO. ``exp`` maps a twist to a 4x4 rigid transform, ``log`` is its inverse for rotation angles below
pi. Small-angle branches use Taylor series so both stay accurate (and differentiable in spirit) near zero,
where the tracker's Gauss-Newton increments live.
"""

from __future__ import annotations

import numpy as np

_SMALL = 1e-8


def hat(w: np.ndarray) -> np.ndarray:
    """The skew-symmetric matrix [w]x, so that hat(w) @ p == cross(w, p)."""
    x, y, z = (float(c) for c in w)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _coefficients(theta: float) -> tuple[float, float, float]:
    """A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3, with series near t = 0."""
    t2 = theta * theta
    if theta < 1e-4:
        return 1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0
    return np.sin(theta) / theta, (1.0 - np.cos(theta)) / t2, (theta - np.sin(theta)) / (t2 * theta)


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (Rodrigues)."""
    theta = float(np.linalg.norm(w))
    a, b, _ = _coefficients(theta)
    W = hat(w)
    return np.eye(3) + a * W + b * (W @ W)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of ``R`` (angle in [0, pi]); robust near 0 and near pi."""
    cos_t = float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    theta = float(np.arccos(cos_t))
    v = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # sin(t) * axis
    if theta < 1e-4:
        return v * (1.0 + theta * theta / 6.0)
    if theta < np.pi - 1e-3:
        return v * (theta / np.sin(theta))
    # Near pi sin(t) vanishes: read the axis from the symmetric part, cos(t) I + (1 - cos(t)) aa^T.
    S = ((R + R.T) / 2.0 - cos_t * np.eye(3)) / (1.0 - cos_t)
    k = int(np.argmax(np.diag(S)))
    axis = S[:, k] / np.sqrt(max(S[k, k], _SMALL))
    axis /= np.linalg.norm(axis)
    if axis @ v < 0:
        axis = -axis
    return axis * theta


def exp(xi: np.ndarray) -> np.ndarray:
    """4x4 rigid transform of the twist ``xi = (v, w)``."""
    xi = np.asarray(xi, dtype=np.float64)
    if xi.shape != (6,):
        raise ValueError(f"a twist has 6 components, got shape {xi.shape}")
    v, w = xi[:3], xi[3:]
    theta = float(np.linalg.norm(w))
    a, b, c = _coefficients(theta)
    W = hat(w)
    W2 = W @ W
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + a * W + b * W2
    T[:3, 3] = (np.eye(3) + b * W + c * W2) @ v
    return T


def log(T: np.ndarray) -> np.ndarray:
    """Twist ``(v, w)`` of the 4x4 rigid transform ``T`` (inverse of :func:`exp` for angles < pi)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"a rigid transform is 4x4, got shape {T.shape}")
    w = so3_log(T[:3, :3])
    theta = float(np.linalg.norm(w))
    W = hat(w)
    if theta < 1e-4:
        v_inv = np.eye(3) - 0.5 * W + (1.0 / 12.0 + theta * theta / 720.0) * (W @ W)
    else:
        a, b, _ = _coefficients(theta)
        v_inv = np.eye(3) - 0.5 * W + (1.0 - a / (2.0 * b)) / (theta * theta) * (W @ W)
    return np.concatenate([v_inv @ T[:3, 3], w])


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform without a general matrix inverse (exact orthogonality assumed)."""
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def rotation_angle_deg(R: np.ndarray) -> float:
    """Geodesic angle of a rotation matrix, in degrees (numerically safe for tiny angles)."""
    return float(np.degrees(np.linalg.norm(so3_log(R))))


def orthonormalize(T: np.ndarray) -> np.ndarray:
    """``T`` with its rotation block projected back onto SO(3) (SVD), so long products cannot drift."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    out = T.copy()
    out[:3, :3] = R
    return out
