"""Lie-group helpers for rigid motions (SO(3), SE(3)) used by the photometric tracker.

Twists are ``xi = (v, w)``: translation part first, then the rotation vector (axis * angle, radians), as in
Sophus/DSO. ``exp`` maps a twist to a 4x4 rigid transform, ``log`` is its inverse for rotation angles below
pi. The rotations (SO(3): rotation vector <-> matrix, geodesic angle) are scipy's ``Rotation`` (the eval
extra); what scipy has no map for, the coupling of translation and rotation in SE(3) (the left Jacobian ``V``
and its inverse), is written here, with Taylor series near zero where the tracker's Gauss-Newton increments
live.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


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
    """Rotation matrix of the rotation vector ``w``."""
    matrix: np.ndarray = Rotation.from_rotvec(np.asarray(w, dtype=np.float64)).as_matrix()
    return matrix


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of ``R`` (angle in [0, pi]); robust near 0 and near pi."""
    rotvec: np.ndarray = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec()
    return rotvec


def exp(xi: np.ndarray) -> np.ndarray:
    """4x4 rigid transform of the twist ``xi = (v, w)``."""
    xi = np.asarray(xi, dtype=np.float64)
    if xi.shape != (6,):
        raise ValueError(f"a twist has 6 components, got shape {xi.shape}")
    v, w = xi[:3], xi[3:]
    theta = float(np.linalg.norm(w))
    _, b, c = _coefficients(theta)
    W = hat(w)
    W2 = W @ W
    T = np.eye(4)
    T[:3, :3] = so3_exp(w)
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
    return float(np.degrees(Rotation.from_matrix(np.asarray(R, dtype=np.float64)).magnitude()))


def orthonormalize(T: np.ndarray) -> np.ndarray:
    """``T`` with its rotation block projected back onto SO(3) (SVD), so long products cannot drift."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    out = T.copy()
    out[:3, :3] = R
    return out
