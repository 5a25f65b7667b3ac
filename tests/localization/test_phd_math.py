"""Hand-derived checks of the single-target math (Kalman, EKF, frame change, PHD weights)."""

from __future__ import annotations

import math

import numpy as np

from localization import GaussianMixture, PHDConfig, RobotCentricPHD, phd
from localization.gaussian import (
    bearing_update,
    frame_change_matrix,
    joseph_update,
    position_update,
    wrap_angle,
)
from localization.mixture import table_from_arrays

ATOL = 1e-12


def _sym(p: np.ndarray) -> np.ndarray:
    """(2, 2) -> (3, 1) packed covariance."""
    return np.array([[p[0, 0]], [p[0, 1]], [p[1, 1]]])


def test_position_update_diagonal_by_hand():
    # P = diag(0.0075, 0.0025), R = 0.0025 I  =>  S = diag(0.01, 0.005), K = diag(0.75, 0.5).
    means = np.array([[1.0], [0.0]])
    covs = np.array([[0.0075], [0.0], [0.0025]])
    z = np.array([[1.1], [0.2]])
    post_m, post_p, lik = position_update(means, covs, z, 0.0025)
    # m+ = m + K (z - m) = (1 + 0.75 * 0.1, 0 + 0.5 * 0.2)
    assert np.allclose(post_m[:, 0, 0], [1.075, 0.1], atol=ATOL)
    # P+ = (I - K) P = diag(0.25 * 0.0075, 0.5 * 0.0025)
    assert np.allclose(post_p[:, 0], [0.001875, 0.0, 0.00125], atol=ATOL)
    # N(z; m, S): Mahalanobis 0.1^2/0.01 + 0.2^2/0.005 = 1 + 8 = 9
    expected = math.exp(-4.5) / (2 * math.pi * math.sqrt(0.01 * 0.005))
    assert np.allclose(lik, expected, rtol=1e-12, atol=0)


def test_position_update_matches_textbook_joseph_form(rng):
    for _ in range(20):
        a = rng.normal(size=(2, 2))
        p = a @ a.T * 0.01 + np.eye(2) * 1e-4
        m = rng.normal(size=2)
        z = m + rng.normal(size=2) * 0.1
        r = 0.0025
        s = p + r * np.eye(2)
        k = p @ np.linalg.inv(s)
        joseph = (np.eye(2) - k) @ p @ (np.eye(2) - k).T + k @ (r * np.eye(2)) @ k.T
        m_exp = m + k @ (z - m)
        lik_exp = math.exp(-0.5 * (z - m) @ np.linalg.solve(s, z - m)) / (
            2 * math.pi * math.sqrt(np.linalg.det(s))
        )
        post_m, post_p, lik = position_update(m[:, None], _sym(p), z[:, None], r)
        assert np.allclose(post_m[:, 0, 0], m_exp, atol=ATOL)
        assert np.allclose(post_p[:, 0], _sym(joseph)[:, 0], atol=ATOL)
        assert np.isclose(lik[0, 0], lik_exp, rtol=1e-10)


def test_bearing_update_by_hand():
    # m = (2, 0), P = diag(0.01, 0.04): H = [-y, x]/r^2 = [0, 0.5], H P H^T = 0.25 * 0.04.
    rc = math.radians(5.0) ** 2
    means = np.array([[2.0], [0.0]])
    covs = np.array([[0.01], [0.0], [0.04]])
    post_m, post_p, lik = bearing_update(means, covs, np.array([0.05]), rc, 0.1)
    s = 0.01 + rc
    ky = 0.04 * 0.5 / s  # K = P H^T / S = [0, 0.02 / S]
    assert np.allclose(post_m[:, 0, 0], [2.0, ky * 0.05], atol=ATOL)
    pyy = (1 - ky * 0.5) ** 2 * 0.04 + ky * ky * rc  # Joseph, yy entry
    assert np.allclose(post_p[:, 0], [0.01, 0.0, pyy], atol=ATOL)
    assert np.isclose(lik[0, 0], math.exp(-0.5 * 0.05**2 / s) / math.sqrt(2 * math.pi * s))


def test_bearing_jacobian_matches_finite_differences(rng):
    # With P = eps * I the gain is K = eps H^T / S; read H back and compare with the numerical
    # derivative of atan2.
    eps = 1e-9
    for _ in range(20):
        m = rng.uniform(-3, 3, size=2)
        if np.hypot(*m) < 0.3:
            continue
        covs = np.array([[eps], [0.0], [eps]])
        post_m, _, _ = bearing_update(m[:, None], covs, np.array([1.0]), 1.0, 0.1)
        innov = wrap_angle(1.0 - math.atan2(m[1], m[0]))
        s = 1.0  # H P H^T is negligible next to R = 1
        jac = (post_m[:, 0, 0] - m) / (innov * eps / s)
        h = 1e-6
        fd = np.array(
            [
                (math.atan2(m[1], m[0] + h) - math.atan2(m[1], m[0] - h)) / (2 * h),
                (math.atan2(m[1] + h, m[0]) - math.atan2(m[1] - h, m[0])) / (2 * h),
            ]
        )
        assert np.allclose(jac, fd, rtol=1e-5, atol=1e-8)
        # Perera 2021's H = [-y, x] / ||m|| is wrong by a factor ||m|| (fails unless ||m|| = 1).
        seed_h = np.array([-m[1], m[0]]) / np.hypot(*m)
        assert np.allclose(seed_h / np.hypot(*m), fd, rtol=1e-5)


def test_joseph_update_equals_standard_form_for_optimal_gain(rng):
    for _ in range(10):
        a = rng.normal(size=(2, 2))
        p = a @ a.T + 0.1 * np.eye(2)
        h = rng.normal(size=2)
        r = 0.3
        s = h @ p @ h + r
        k = p @ h / s
        standard = p - np.outer(k, h @ p)
        out = joseph_update(_sym(p), k[:, None], h[:, None], r)
        assert np.allclose(out[:, 0], _sym(standard)[:, 0], atol=1e-12)


def test_camera_update_shrinks_tangential_not_radial_variance():
    # A component at 2 m straight ahead with isotropic 0.2 m std, one bearing measurement.
    # Prior bearing variance 0.04 / 2^2 = 0.01 rad^2, R_C = (5 deg)^2 = 0.0076 rad^2, so the
    # posterior bearing variance is 1 / (1/0.01 + 1/0.0076): tangential variance x 0.43.
    cfg = PHDConfig.perera2021()
    table = table_from_arrays(np.array([1.0]), np.array([[2.0, 0.0]]), 0.04 * np.eye(2)[None])
    out, _ = phd.camera_update(
        table, np.array([0.02]), np.array([0.9]), cfg.camera.noise_var_rad2, 0.05, 0.1
    )
    pxx, pxy, pyy = out[3:, 1]  # the detected copy
    rc = cfg.camera.noise_var_rad2
    assert np.isclose(pyy, 4.0 / (1 / 0.01 + 1 / rc), rtol=1e-12)
    assert pyy < 0.5 * 0.04  # tangential variance shrinks
    assert pxx == 0.04 and pxy == 0.0  # radial untouched: a bearing says nothing about range
    # Through the filter (detected and missed copies merged) the tangential std still shrinks.
    f = RobotCentricPHD(cfg)
    f.set_mixture(GaussianMixture(table[0], table[1:3].T, 0.04 * np.eye(2)[None]))
    f.update_camera(np.array([0.02]))
    cov = f.mixture.covs[int(np.argmax(f.mixture.weights))]
    assert cov[1, 1] < 0.75 * 0.04 and cov[0, 0] > 0.99 * 0.04


def test_single_component_phd_lidar_update_by_hand():
    # One component, P_d given, two measurements (one near, one far), clutter 0.5 / m^2.
    w, pd, kappa, r = 0.8, 0.9, 0.5, 0.0025
    table = table_from_arrays(
        np.array([w]), np.array([[1.0, 0.0]]), np.array([[[0.0075, 0.0], [0.0, 0.0025]]])
    )
    points = np.array([[1.1, 0.2], [3.0, 3.0]])
    out, explained = phd.lidar_update(table, points, np.array([pd]), r, kappa)
    assert out.shape == (6, 3)
    g1 = math.exp(-4.5) / (2 * math.pi * math.sqrt(0.01 * 0.005))
    g2 = math.exp(-0.5 * (2.0**2 / 0.01 + 3.0**2 / 0.005)) / (
        2 * math.pi * math.sqrt(0.01 * 0.005)
    )
    assert g2 == 0.0  # underflows to exactly zero, never NaN
    expected_w = [(1 - pd) * w, pd * w * g1 / (kappa + pd * w * g1), 0.0]
    assert np.allclose(out[0], expected_w, atol=ATOL)
    # Missed copy keeps the prior; detected copies carry the Kalman posterior.
    assert np.allclose(out[1:, 0], table[1:, 0], atol=ATOL)
    assert np.allclose(out[1:3, 1], [1.075, 0.1], atol=ATOL)
    assert np.allclose(out[3:, 1], [0.001875, 0.0, 0.00125], atol=ATOL)
    assert np.allclose(out[3:, 2], [0.001875, 0.0, 0.00125], atol=ATOL)
    assert np.allclose(explained, [pd * w * g1 / (kappa + pd * w * g1), 0.0], atol=ATOL)


def test_zero_clutter_underflow_gives_zero_weight_not_nan():
    table = table_from_arrays(np.array([1.0]), np.zeros((1, 2)), 1e-4 * np.eye(2)[None])
    out, explained = phd.lidar_update(table, np.array([[50.0, 50.0]]), np.array([1.0]), 1e-4, 0.0)
    assert np.isfinite(out).all()
    assert out[0, 1] == 0.0 and explained[0] == 0.0


def test_frame_change_static_teammate_stays_put_in_world(rng):
    # Compose random observer moves with its world pose: a static teammate's predicted
    # relative position must always equal the truth re-expressed in the new frame.
    def rel(pose, target):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        d = target - pose[:2]
        return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])

    pose = np.array([0.3, -0.2, 0.7])
    target = np.array([1.5, 0.9])
    table = table_from_arrays(np.array([1.0]), rel(pose, target)[None], 0.01 * np.eye(2)[None])
    for _ in range(50):
        odo = np.array([rng.uniform(-0.05, 0.1), rng.uniform(-0.03, 0.03), rng.uniform(-0.3, 0.3)])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose = pose + np.array([c * odo[0] - s * odo[1], s * odo[0] + c * odo[1], odo[2]])
        table = phd.predict(table, odo, np.ones(1), 0.0)
        assert np.allclose(table[1:3, 0], rel(pose, target), atol=1e-9)
    # Perera 2021's eq. 7 as written, R(dpsi) (m - d), drifts away from the truth.
    m = rel(np.array([0.0, 0.0, 0.0]), target)
    odo = np.array([0.1, 0.0, 0.5])
    c, s = math.cos(odo[2]), math.sin(odo[2])
    seed = np.array([[c, -s], [s, c]]) @ (m - odo[:2])
    truth = rel(np.array([0.1, 0.0, 0.5]), target)
    assert not np.allclose(seed, truth, atol=1e-3)


def test_frame_change_rotates_covariance_with_the_means():
    # An elongated covariance along x, observer turns +90 deg: the ellipse is now along -y/+y.
    a = frame_change_matrix(0.0, 0.0, math.pi / 2, 0.0)
    table = table_from_arrays(np.array([1.0]), np.array([[1.0, 0.0]]), np.diag([0.09, 0.01])[None])
    out = a[:, :6] @ table + a[:, 6:]
    assert np.allclose(out[1:3, 0], [0.0, -1.0], atol=ATOL)
    assert np.allclose(out[3:, 0], [0.01, 0.0, 0.09], atol=ATOL)


def test_filter_predict_moves_the_estimate_with_seed_survival():
    f = RobotCentricPHD(PHDConfig.perera2021().replace(prediction={"process_noise_std_m": 1e-9}))
    f.set_mixture(GaussianMixture(np.array([1.0]), np.array([[1.0, 0.0]]), 0.01 * np.eye(2)[None]))
    f.predict(np.array([0.5, 0.0, 0.0]))
    mix = f.mixture
    assert len(mix) == 1
    ps = 1.0 / (1.05 + math.exp(4 * (1.0 - 4)))  # eq. 10 at the prior range, 1 m
    assert np.allclose(mix.weights, [ps], atol=ATOL)
    assert np.allclose(mix.means, [[0.5, 0.0]], atol=ATOL)
    assert np.allclose(mix.covs[0], (0.01 + 1e-18) * np.eye(2), atol=ATOL)


def test_fixed_birth_enters_lidar_updates_through_its_detected_copies_only():
    cfg = PHDConfig.perera2021()
    f = RobotCentricPHD(cfg)
    z = np.array([[1.0, -0.5]])
    f.update_lidar(z)
    mix = f.mixture
    # Only the birth's detected copy: w_b P_d(0) N(z; 0, 4 I + R) / (kappa + same).
    r = cfg.lidar.noise_var_m2
    s = 4.0 + r
    g = math.exp(-0.5 * (1.0 + 0.25) / s) / (2 * math.pi * s)
    pd0 = 1.0 / (1.02 + math.exp(8 * (0.0 - 1.5)))
    num = 0.001 * pd0 * g
    assert len(mix) == 1
    assert np.isclose(mix.weights[0], num / (cfg.lidar.clutter_intensity + num), rtol=1e-12)
    k = 4.0 / s
    assert np.allclose(mix.means[0], k * z[0], atol=ATOL)
    assert np.allclose(mix.covs[0], r * k * np.eye(2), atol=ATOL)
    f.update_lidar(np.empty((0, 2)))  # no detection: no birth at all
    assert len(f) <= 1
