"""The per-teammate particle filter (Stegagno 2012 section 6.2) and the P-MultiReg system."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from localization.mutual.fastslam import FastSLAMLocalizer
from localization.mutual.particles import MotionNoise, TeammateParticles, gaussian_log_density
from localization.mutual.pmultibeareg import PMultiBeaRegConfig, PMultiBeaRegLocalizer
from localization.mutual.pmultireg import PMultiRegConfig, PMultiRegLocalizer
from localization.mutual.se2 import compose, inverse_compose
from swarm_core.geometry import wrap_angle

from .synthetic import SyntheticSwarm

DIST_M, ANGLE_RAD = 0.1, math.radians(7.0)  # the thesis's accuracy thresholds


def _errors(est: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    return float(np.hypot(*(est[:2] - truth[:2]))), abs(float(wrap_angle(est[2] - truth[2])))


def test_gaussian_log_density_matches_scipy():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(2, 3, 3))
    covs = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(3)
    r = rng.normal(size=(5, 2, 3))
    ours = gaussian_log_density(r, covs)
    for h in range(2):
        ref = multivariate_normal(np.zeros(3), covs[h]).logpdf(r[:, h])
        np.testing.assert_allclose(ours[:, h], ref, rtol=1e-10)


def test_motion_updates_follow_the_pose_algebra():
    """Noise-free, eq. 13 then eq. 15 move every particle as the robots moved."""
    noise = MotionNoise(0.0, 0.0, 0.0, 0.0, 0.0)
    pf = TeammateParticles(5, noise, np.full(3, 1e-7), 0.0, np.random.default_rng(0))
    x0 = np.array([1.0, 0.5, 0.3])
    pf.initialize(np.tile(x0, (1, 1)), np.eye(3)[None] * 1e-12)
    u_i, u_j = np.array([0.2, 0.05, 0.4]), np.array([-0.1, 0.3, -0.2])
    pf.predict_own(u_i)
    pf.predict_teammate(u_j)
    # j's world pose x_i (+) x0 (+) u_j, seen from i's new pose x_i (+) u_i (x_i = 0).
    expected = inverse_compose(compose(x0, u_j), u_i)
    np.testing.assert_allclose(pf.x, np.tile(expected, (5, 1)), atol=1e-5)


def _two_robot_run(seed: int, kidnap_at: int | None = None):
    """Both robots drive circles; the filter gets their noisy odometry and, every 0.5 s, a
    registration (true relative pose + the registration noise). The first 4 updates are
    ambiguous: the truth plus two rotations of it about the observer (a symmetric scene)."""
    rng = np.random.default_rng(seed)
    noise = MotionNoise()
    pf = TeammateParticles(400, noise, np.array([0.02, 0.02, math.radians(2)]), 0.05, rng)
    xi, xj = np.zeros(3), np.array([1.2, -0.4, 2.0])
    vi, vj = np.array([0.1, 0.2]), np.array([0.08, -0.15])
    errs = []
    sig = np.array([0.02, 0.02, math.radians(1.5)])
    cov = np.diag(sig**2)
    for k in range(600):  # 60 s at 10 Hz
        ui = np.array([vi[0] * 0.1, 0.0, vi[1] * 0.1])
        uj = np.array([vj[0] * 0.1, 0.0, vj[1] * 0.1])
        xi, xj = compose(xi, ui), compose(xj, uj)
        if kidnap_at is not None and k == kidnap_at:
            xj = compose(xj, np.array([-0.8, 0.6, 2.5]))  # not in j's odometry
        d = np.hypot(ui[0], ui[1])
        pf.predict_own(ui + rng.normal(0, [0.01 * d, 0.01 * d, 0.35 * d + 1e-3]))
        pf.predict_teammate(uj + rng.normal(0, [0.01 * d, 0.01 * d, 0.35 * d + 1e-3]))
        truth = inverse_compose(xj, xi)
        if k % 5 == 4:
            meas = truth + rng.normal(0.0, sig)
            if k < 20:
                rot = [compose(np.array([0, 0, a]), meas) for a in (2.1, -2.1)]
                meas = np.vstack([meas, *rot])
            pf.update(meas.reshape(-1, 3), np.tile(cov, (len(meas.reshape(-1, 3)), 1, 1)))
        if pf.initialized:
            errs.append(_errors(pf.mean(), truth))
    return np.array(errs)


@pytest.mark.parametrize("seed", [0, 1])
def test_filter_converges_on_a_two_robot_case(seed):
    errs = _two_robot_run(seed)
    late = errs[-300:]  # the last 30 s
    assert (late[:, 0] < DIST_M).all() and (late[:, 1] < ANGLE_RAD).all()
    assert late[:, 0].mean() < 0.03
    early = errs[:15]  # while the measurements are ambiguous the mean sits between them
    assert early[:, 0].max() > 0.3


def test_filter_recovers_from_kidnapping():
    errs = _two_robot_run(3, kidnap_at=300)  # errs[i] is step i + 4 (first update at step 4)
    assert errs[295, 0] < DIST_M  # converged before
    assert errs[296, 0] > 0.5  # lost when it happens
    after = errs[296 + 20 :]  # 2 s later it is back (restarted from the registrations)
    assert (after[:, 0] < DIST_M).all() and (after[:, 1] < ANGLE_RAD).all()


def test_pmultireg_system_on_a_synthetic_swarm():
    """Three robots (one observer), an irregular triangle plus a decoy post, noisy detections:
    every teammate's pose is right within the thesis's accuracy after a few seconds."""
    world = SyntheticSwarm(
        np.array([[0.0, 0.0, 0.3], [1.1, 0.4, 2.0], [0.2, 1.3, -1.0]]),
        features=np.array([[1.5, 1.6]]),
        seed=5,
    )
    loc = PMultiRegLocalizer(
        "ugv_0", world.ids, PMultiRegConfig(n_particles=200), np.random.default_rng(0)
    )
    vel = np.array([[0.05, 0.1], [0.05, -0.1], [0.0, 0.2]])
    for _ in range(60):
        meas, comms = world.step(vel, det_noise_m=0.015)
        loc.step(world.time_s, meas["ugv_0"], comms["ugv_0"])
    est = loc.estimates()
    for j in (1, 2):
        d, a = _errors(est[f"ugv_{j}"], world.relative(0, j))
        assert d < 0.05 and a < math.radians(3.0), (j, d, a)
    assert loc.n_registrations == 12


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="n_particles"):
        PMultiRegConfig(n_particles=1)
    with pytest.raises(ValueError, match="reseed_fraction"):
        PMultiRegConfig(reseed_fraction=1.0)
    with pytest.raises(ValueError, match="trans_per_m"):
        MotionNoise(trans_per_m=-1.0)


@pytest.mark.parametrize("config", [PMultiRegConfig, PMultiBeaRegConfig])
@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("gate_mahalanobis2", 0.0),
        ("gate_mahalanobis2", float("nan")),
        ("gate_mahalanobis2", float("inf")),
        ("gate_mahalanobis2", "25"),
        ("lost_after", 0),
        ("lost_after", 2.5),
        ("lost_after", True),
        ("reseed_fraction", -0.1),
        ("reseed_fraction", float("nan")),
        ("reseed_fraction", "0.05"),
        ("motion_noise", None),
    ],
)
def test_registration_configs_name_the_bad_field_and_value(config, field, value):
    with pytest.raises(ValueError, match=rf"{field}.*{re.escape(repr(value))}"):
        config(**{field: value})


def test_localizers_refuse_bad_constructor_arguments():
    ids = ("ugv_0", "ugv_1")
    for cls in (PMultiRegLocalizer, PMultiBeaRegLocalizer, FastSLAMLocalizer):
        with pytest.raises(ValueError, match="observer"):
            cls(0, ids)
        with pytest.raises(ValueError, match="teammates"):
            cls("ugv_0", "ugv_1")
        with pytest.raises(ValueError, match="config"):
            cls("ugv_0", ids, config={"n_particles": 10})
        with pytest.raises(ValueError, match="rng"):
            cls("ugv_0", ids, rng=0)


def test_registration_schedule_does_not_drift():
    """Every update_period_s from the first registration, whatever the step: with 0.3 s steps
    and a 0.5 s period, registrations at 0.3, 0.9, 1.5, 1.8, 2.4, 3.0 (due 0.8, 1.3, 1.8, 2.3,
    2.8); a gap of several periods skips the missed ones instead of registering at each step."""
    from localization.mutual.links import next_due

    due, fired = -math.inf, []
    for k in range(1, 11):
        t = 0.3 * k
        if t + 1e-9 >= due:
            fired.append(round(t, 9))
            due = next_due(due, t, 0.5)
    assert fired == [0.3, 0.9, 1.5, 1.8, 2.4, 3.0]
    assert next_due(0.8, 3.05, 0.5) == pytest.approx(3.3)  # 4 periods behind: next grid point
    assert next_due(0.8, 0.8 - 1e-12, 0.5) == pytest.approx(1.3)  # due within 1e-9: advances
