"""Binary registration (Stegagno 2012 section 6.1): hand-derived cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization.mutual.registration import _fit, register_pair, registration_covariance
from localization.mutual.se2 import compose, inverse_compose, points_from_frame, points_to_frame

# An irregular scene (no rotational symmetry), observer at the origin.
SCENE = np.array([[0.0, 0.0], [1.2, 0.1], [0.4, 1.1], [-0.7, 0.6], [1.5, 1.4], [-0.3, -0.9]])


def _observation(scene: np.ndarray, pose: np.ndarray, own: int) -> np.ndarray:
    """What the robot at ``scene[own]`` with heading ``pose[2]`` sees: its origin first."""
    others = np.delete(scene, own, axis=0)
    return np.vstack([[0.0, 0.0], points_to_frame(others, pose)])


def test_pose_algebra_round_trips():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-2, 2, (2, 50, 3))
    back = compose(b, inverse_compose(a, b))  # b (+) (a (-) b) = a
    np.testing.assert_allclose(back[:, :2], a[:, :2], atol=1e-12)
    np.testing.assert_allclose(np.cos(back[:, 2] - a[:, 2]), 1.0, atol=1e-12)
    z = rng.uniform(-2, 2, (50, 4, 2))
    np.testing.assert_allclose(points_to_frame(points_from_frame(a, z), a), z, atol=1e-12)
    # Hand case: frame at (1, 0) facing +y; the point (1, 1) is 1 m straight ahead of it.
    np.testing.assert_allclose(
        points_to_frame(np.array([[1.0, 1.0]]), np.array([1.0, 0.0, math.pi / 2])),
        [[1.0, 0.0]],
        atol=1e-12,
    )


def test_known_rigid_transform_is_recovered_exactly():
    truth = np.array([1.2, 0.1, 2.0])  # robot 1's pose in the observer's frame
    source = _observation(SCENE, truth, own=1)
    target = SCENE  # the observer's own observation: its origin is SCENE[0]
    regs = register_pair(target, np.array([0] + [-1] * 5), source, np.array([1] + [-1] * 5))
    assert len(regs) == 1
    np.testing.assert_allclose(regs[0].pose, truth, atol=1e-9)
    assert regs[0].n_inliers == 6 and regs[0].rms_m < 1e-9
    cov = regs[0].covariance
    np.testing.assert_allclose(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > 0


def test_ransac_rejects_outliers():
    rng = np.random.default_rng(3)
    truth = np.array([0.4, 1.1, -2.5])
    source = _observation(SCENE, truth, own=2) + rng.normal(0, 0.01, (6, 2))
    source[0] = 0.0  # the origin is exact
    src_out = rng.uniform(-3, 3, (4, 2))  # false positives of the teammate
    tgt_out = rng.uniform(-3, 3, (3, 2))  # and of the observer
    target = np.vstack([SCENE + np.r_[[[0, 0]], rng.normal(0, 0.01, (5, 2))], tgt_out])
    source = np.vstack([source, src_out])
    regs = register_pair(
        target, np.array([0] + [-1] * 8), source, np.array([2] + [-1] * 9), gate_m=0.05
    )
    assert len(regs) == 1
    reg = regs[0]
    assert np.hypot(*(reg.pose[:2] - truth[:2])) < 0.02
    assert abs(math.remainder(reg.pose[2] - truth[2], 2 * math.pi)) < math.radians(1.0)
    assert reg.n_inliers == 6
    assert (reg.pairs[:, 0] < 6).all() and (reg.pairs[:, 1] < 6).all()  # no outlier paired


def test_labels_forbid_putting_a_robot_on_another_robots_origin():
    sq = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    pose = np.array([1.0, 0.0, math.pi / 2])
    source = _observation(sq, pose, own=1)
    free = register_pair(sq, np.array([0, -1, -1, -1]), source, np.array([1, -1, -1, -1]))
    assert len(free) == 3  # the square: robot 1 fits on any of the three other corners
    # Once robot 3 is known to sit at (0, 1), robot 1 can only be at (1, 0) or (1, 1).
    taken = register_pair(sq, np.array([0, -1, -1, 3]), source, np.array([1, -1, -1, -1]))
    assert len(taken) == 2
    assert all(np.hypot(*(r.pose[:2] - [0.0, 1.0])) > 0.5 for r in taken)


def test_covariance_matches_monte_carlo():
    """The hand-derived covariance of the least-squares pose against 3000 noisy Kabsch fits
    (the refinement step of every registration)."""
    rng = np.random.default_rng(7)
    truth = np.array([1.5, 1.4, 0.7])
    clean = _observation(SCENE, truth, own=4)
    pairs = np.column_stack([np.arange(6), [4, 0, 1, 2, 3, 5]])
    sigma = 0.01
    poses = np.array(
        [
            _fit(
                clean + rng.normal(0, sigma, clean.shape),
                SCENE + rng.normal(0, sigma, SCENE.shape),
                pairs,
            )
            for _ in range(3000)
        ]
    )
    emp = np.cov(poses.T)
    pred = registration_covariance(clean, pairs, truth[2], sigma)
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(pred)), rtol=0.1)
    corr = lambda c: c[0, 2] / math.sqrt(c[0, 0] * c[2, 2])  # noqa: E731
    assert abs(corr(emp) - corr(pred)) < 0.1
    # register_pair reports that covariance for its refined pose.
    labels = np.array([0, -1, -1, -1, -1, -1])
    reg = register_pair(SCENE, labels, clean, np.where(labels == 0, 4, -1), sigma_m=sigma)[0]
    np.testing.assert_allclose(reg.covariance, pred, rtol=1e-6, atol=1e-12)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="labels"):
        register_pair(SCENE, np.zeros(2), SCENE, np.zeros(6))
    with pytest.raises(ValueError, match="gate_m"):
        register_pair(SCENE, np.zeros(6), SCENE, np.zeros(6), gate_m=0.0)
    with pytest.raises(ValueError, match="min_inliers"):
        register_pair(SCENE, np.zeros(6), SCENE, np.zeros(6), min_inliers=1)
