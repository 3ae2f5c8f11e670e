"""``colonlight.evaluation.se3``: the tracker's Lie-group maths, checked against the hand-written Rodrigues
formulas it used before it called scipy's ``Rotation`` (results equal within float tolerance), against scipy,
and against its own inverses, near 0 and near pi included."""

from __future__ import annotations

import numpy as np
import pytest

from colonlight.evaluation import se3

Rotation = pytest.importorskip("scipy.spatial.transform", reason="scipy comes with the eval extra").Rotation

RNG = np.random.default_rng(15)
AXES = [v / np.linalg.norm(v) for v in RNG.normal(size=(8, 3))]
ANGLES = (1e-9, 1e-5, 1e-3, 0.3, 1.0, 2.5, np.pi - 1e-4, np.pi - 1e-6)
ROTVECS = [axis * angle for axis, angle in zip(AXES, ANGLES, strict=True)]


def rodrigues(w: np.ndarray) -> np.ndarray:
    """The rotation matrix of ``w`` as se3 computed it by hand (Rodrigues, series below 1e-4 rad)."""
    theta = float(np.linalg.norm(w))
    if theta < 1e-4:
        a, b = 1.0 - theta * theta / 6.0, 0.5 - theta * theta / 24.0
    else:
        a, b = np.sin(theta) / theta, (1.0 - np.cos(theta)) / theta**2
    W = se3.hat(w)
    return np.eye(3) + a * W + b * (W @ W)


@pytest.mark.parametrize("w", ROTVECS, ids=lambda w: f"{np.linalg.norm(w):.1e}")
def test_so3_matches_rodrigues_and_scipy(w: np.ndarray) -> None:
    R = se3.so3_exp(w)
    np.testing.assert_allclose(R, rodrigues(w), atol=1e-12)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(se3.so3_log(rodrigues(w)), w, atol=1e-7)
    assert se3.rotation_angle_deg(R) == pytest.approx(np.degrees(np.linalg.norm(w)), abs=1e-6)


@pytest.mark.parametrize("scale", [1e-9, 1e-4, 0.1, 1.0, 3.0])
def test_se3_exp_log_round_trip_and_group_laws(scale: float) -> None:
    xi = RNG.normal(size=6) * scale
    xi[3:] *= min(1.0, 3.0 / max(np.linalg.norm(xi[3:]), 1e-30))  # angles below pi
    T = se3.exp(xi)
    np.testing.assert_allclose(T[:3, :3], Rotation.from_rotvec(xi[3:]).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])
    np.testing.assert_allclose(se3.log(T), xi, atol=1e-9 * max(1.0, scale))
    np.testing.assert_allclose(se3.inverse(T) @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(se3.exp(-xi), se3.inverse(T), atol=1e-12)


def test_pure_translation_and_hat() -> None:
    T = se3.exp(np.array([1.0, -2.0, 3.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(T[:3, 3], [1.0, -2.0, 3.0])
    np.testing.assert_allclose(T[:3, :3], np.eye(3))
    w, p = np.array([0.1, 0.2, 0.3]), np.array([-1.0, 0.5, 2.0])
    np.testing.assert_allclose(se3.hat(w) @ p, np.cross(w, p))


def test_orthonormalize_removes_drift() -> None:
    T = se3.exp(np.array([0.1, 0.2, 0.3, 0.4, -0.2, 0.1]))
    drifted = T.copy()
    drifted[:3, :3] *= 1.001
    drifted[0, 1] += 1e-3
    fixed = se3.orthonormalize(drifted)
    R = fixed[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R, T[:3, :3], atol=2e-3)
    np.testing.assert_array_equal(fixed[:3, 3], T[:3, 3])


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="6 components"):
        se3.exp(np.zeros(5))
    with pytest.raises(ValueError, match="4x4"):
        se3.log(np.eye(3))
