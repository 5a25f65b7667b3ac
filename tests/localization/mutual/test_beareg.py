"""P-MultiBeaReg (Stegagno 2012 chapter 10): triangles, 3-intersections, bearing-orientations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization.mutual.beareg import bearing_solutions, find_triangles, three_intersections
from localization.mutual.particles import MotionNoise, TeammateParticles
from localization.mutual.se2 import inverse_compose, points_to_frame
from swarm_core.geometry import wrap_angle

IRREGULAR = np.array([[0.0, 0.0], [1.1, 0.3], [0.4, 1.2], [1.5, 1.6]])
SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _bearing_sets(points: np.ndarray, seed: int):
    rng = np.random.default_rng(seed)
    poses = np.column_stack([points, rng.uniform(-np.pi, np.pi, len(points))])
    sets = {}
    for i in range(len(points)):
        z = points_to_frame(np.delete(points, i, axis=0), poses[i])
        sets[i] = np.arctan2(z[:, 1], z[:, 0])
    return sets, poses


def test_triangle_angles_sum_to_pi_and_give_the_true_bearing_orientation():
    sets, poses = _bearing_sets(IRREGULAR[:3], 0)
    tris = find_triangles(sets)
    # Three robots, two bearings each: the true triangle and the one with every assignment
    # swapped (its mirror image, clockwise): bearings alone cannot tell them apart.
    assert len(tris) == 2 and all(t.residual_rad < 1e-9 for t in tris)
    truth1 = inverse_compose(poses[1], poses[0])
    t = min(tris, key=lambda t: abs(float(wrap_angle(t.pose[1][2] - truth1[2]))))
    for j in (1, 2):
        truth = inverse_compose(poses[j], poses[0])
        # pose[j] is at unit |01|: same bearing and orientation as the truth, scaled.
        scale = np.hypot(*inverse_compose(poses[1], poses[0])[:2])
        np.testing.assert_allclose(t.pose[j][:2] * scale, truth[:2], atol=1e-9)
        assert abs(float(wrap_angle(t.pose[j][2] - truth[2]))) < 1e-9


def test_fourth_robot_is_a_three_intersection():
    sets, _ = _bearing_sets(IRREGULAR, 1)
    tris = [t for t in find_triangles(sets) if t.labels == (0, 1, 2)]
    ratings = sorted(three_intersections(t, sets) for t in tris)
    assert ratings[-1] == 1  # the true triangle sees robot 3 from its three corners


def test_unique_solution_of_an_irregular_formation():
    sets, poses = _bearing_sets(IRREGULAR, 2)
    sols = bearing_solutions(sets)
    assert len(sols) == 1
    for j, xi in sols[0].items():
        t = inverse_compose(poses[j], poses[0])
        assert abs(float(wrap_angle(xi[0] - math.atan2(t[1], t[0])))) < 1e-9
        assert abs(float(wrap_angle(xi[1] - t[2]))) < 1e-9


def test_square_is_ambiguous():
    sets, _ = _bearing_sets(SQUARE, 3)
    assert len(bearing_solutions(sets)) == 6  # as many as Proposition 4 gives positions


def test_bearing_filter_recovers_the_range_once_the_robots_move():
    """Scale is not in a bearing: the filter starts on the ray; the observer's own translation
    (parallax) makes the range observable."""
    rng = np.random.default_rng(0)
    pf = TeammateParticles(800, MotionNoise(), np.full(3, 1e-3), 0.05, rng)
    xj = np.array([1.2, 0.5, 2.0])  # still teammate, in the observer's initial frame
    xi = np.zeros(3)
    std = np.radians([2.0, 3.0])
    for k in range(300):
        u = np.array([0.01, 0.0, 0.02 if k % 100 < 50 else -0.02])  # observer weaves
        from localization.mutual.se2 import compose

        xi = compose(xi, u)
        pf.predict_own(u)
        if k % 5 == 0:
            t = inverse_compose(xj, xi)
            xi_hat = np.array([[math.atan2(t[1], t[0]), t[2]]]) + rng.normal(0, std)
            pf.update_bearing(xi_hat, std)
    t = inverse_compose(xj, xi)
    est = pf.mean()
    assert np.hypot(*(est[:2] - t[:2])) < 0.1


# ------------------------------------------------------------------ eq. 18's scale search
def _belief_at(pose: np.ndarray, n: int = 400, spread: float = 0.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    pf = TeammateParticles(n, MotionNoise(), np.full(3, 1e-3), 0.05, rng)
    pf.x = pose + spread * rng.standard_normal((n, 3))
    pf.initialized = True
    return pf


def test_scale_search_recovers_the_range_of_a_concentrated_belief():
    """Hand-derived: a belief that is one point on the ray at range ``R`` with the candidate's
    heading. Then
    ``log P(r) = -(r - R)^2 / (2 r^2 s^2) - log(2 pi r^2 s^2) - log(sqrt(2 pi) s_t)``,
    whose maximum is at ``R / q`` with ``q^2 - q - 2 s^2 = 0``: ``q = (1 + sqrt(1 + 8 s^2)) / 2``
    (the ``1 / r^2`` normalisation pulls the scale 0.4 % short of ``R`` at ``s`` = 2.5 deg)."""
    beta, theta, big_r = 0.7, -2.1, 1.63
    std = np.radians([2.5, 3.5])
    pf = _belief_at(np.array([big_r * math.cos(beta), big_r * math.sin(beta), theta]), n=4)
    grid = np.linspace(0.2, 4.7, 45001)  # 0.1 mm steps
    lf, scale = pf.scale_search(np.array([[beta, theta]]), std, grid)
    s = std[0]
    q = (1.0 + math.sqrt(1.0 + 8.0 * s * s)) / 2.0
    r_star = big_r / q
    assert abs(scale[0] - r_star) < 2e-4
    expected = (
        -((r_star - big_r) ** 2) / (2 * r_star**2 * s**2)
        - math.log(2 * math.pi * r_star**2 * s**2)
        - math.log(math.sqrt(2 * math.pi) * std[1])
    )
    assert abs(lf[0] - expected) < 1e-6


def test_scale_search_on_a_spread_belief_and_the_filters_grid():
    """A belief spread about a range (5 cm, 2 deg): the chosen scale is that range within the
    grid's step; a candidate off the belief's bearing fits far worse; uninformed: ``None``."""
    std = np.radians([2.5, 3.5])
    for big_r in (0.45, 1.2, 3.1):
        pose = np.array([big_r * math.cos(-2.0), big_r * math.sin(-2.0), 1.0])
        pf = _belief_at(pose, spread=0.0, seed=1)
        pf.x[:, :2] += 0.05 * np.random.default_rng(2).standard_normal((pf.n, 2))
        pf.x[:, 2] += math.radians(2.0) * np.random.default_rng(3).standard_normal(pf.n)
        grid = 0.2 * (1.0 + 0.5 * std[0]) ** np.arange(150)
        lf, scale = pf.scale_search(np.array([[-2.0, 1.0], [-2.0 + 1.0, 1.0]]), std, grid)
        assert abs(scale[0] - big_r) < 0.03 * big_r + 0.05
        assert lf[0] > lf[1] + 10.0
    fresh = TeammateParticles(10, MotionNoise(), np.full(3, 1e-3), 0.05, np.random.default_rng(0))
    assert fresh.scale_search(np.zeros((1, 2)), std, grid) is None


def test_reseeded_particles_sit_at_the_chosen_scale():
    """Re-seeding with eq. 18's scales puts the redrawn particles on the hypothesis's ray at that
    range (relative spread ``s_b``), whatever the rest of the belief holds."""
    std = np.radians([2.5, 3.5])
    pf = _belief_at(np.array([2.0, 0.0, 0.0]), n=1000, spread=0.01)
    drawn = pf._sample_bearing(
        np.array([[0.5, 0.2]]), std, 4000, (0.2, 4.7), None, np.array([0.8])
    )
    r = np.hypot(drawn[:, 0], drawn[:, 1])
    assert abs(np.median(r) - 0.8) < 0.01
    assert abs(np.std(r) / 0.8 - std[0]) < 0.005
    assert abs(np.median(np.arctan2(drawn[:, 1], drawn[:, 0])) - 0.5) < 0.01


# ------------------------------------------------------------------ the camera's bearings
def _run_beareg(features: str, blind: str | None = None, steps: int = 12):
    from localization.mutual.pmultibeareg import PMultiBeaRegConfig, PMultiBeaRegLocalizer

    from .synthetic import SyntheticSwarm

    swarm = SyntheticSwarm(
        np.column_stack([IRREGULAR, [0.3, -1.0, 2.2, 0.9]]), features=np.array([[2.6, 0.2]])
    )
    loc = PMultiBeaRegLocalizer(
        "ugv_0", swarm.ids, PMultiBeaRegConfig(features=features), np.random.default_rng(0)
    )
    seen = []
    for _ in range(steps):
        meas, comms = swarm.step(np.zeros((4, 2)))
        m = meas["ugv_0"]
        if blind == "camera":  # the sensor the localizer must not need
            m = type(m)(m.odometry, m.lidar, [])
        elif blind == "lidar":
            m = type(m)(m.odometry, [], m.camera)
        loc.step(swarm.time_s, m, comms["ugv_0"])
        seen.append(dict(loc.last_hypotheses))
    return swarm, loc, seen


def test_camera_bearings_drive_the_registration():
    """Camera mode registers from the camera frames alone (the lidar may be blind) and gives every
    teammate its true bearing-orientation; lidar mode reads the lidar detections' bearings
    (the camera may be blind), and with only the camera it never registers."""
    for features, blind in (("camera", "lidar"), ("lidar", "camera")):
        swarm, loc, seen = _run_beareg(features, blind)
        assert loc.n_registrations >= 2
        hyps = next(h for h in seen if len(h) == 3)
        for k, t in enumerate(swarm.ids[1:], start=1):
            true = swarm.relative(0, k)
            (xi,) = hyps[t]
            assert abs(wrap_angle(xi[0] - math.atan2(true[1], true[0]))) < 1e-6
            assert abs(wrap_angle(xi[1] - true[2])) < 1e-6
    _, loc, _ = _run_beareg("lidar", "lidar")
    assert loc.n_registrations == 0 and all(f.mean() is None for f in loc.filters.values())


def test_bad_bearing_config_names_the_field():
    from localization.mutual.pmultibeareg import FEATURE_MODELS, PMultiBeaRegConfig

    for kwargs, field in (
        ({"features": "sonar"}, "features"),
        ({"scale_search": 1}, "scale_search"),
        ({"bearing_std_deg": -1.0}, "bearing_std_deg"),
        ({"range_m": (2.0, 1.0)}, "range_m"),
    ):
        try:
            PMultiBeaRegConfig(**kwargs)
        except ValueError as exc:
            assert field in str(exc)
        else:
            raise AssertionError(f"{kwargs} accepted")
    cam, lid = PMultiBeaRegConfig(), PMultiBeaRegConfig(features="lidar", bearing_std_deg=2.0)
    assert cam.features == "camera" and cam.range_m == FEATURE_MODELS["camera"]["range_m"]
    assert lid.bearing_std_deg == 2.0 and lid.triangle_tol_deg == 6.0


def test_lidar_scale_free_mode_reproduces_the_first_implementation():
    """``features="lidar", scale_search=False`` is the first implementation bit for bit (its
    figures stay reproducible): the particle means after 10 s of a noisy synthetic episode, as
    that code (commit before the camera and eq. 18's scale search) computed them."""
    from localization.mutual.pmultibeareg import PMultiBeaRegConfig, PMultiBeaRegLocalizer

    from .synthetic import SyntheticSwarm

    pts = np.array([[0.0, 0.0, 0.3], [1.1, 0.3, -1.0], [0.4, 1.2, 2.2], [1.5, 1.6, 0.9]])
    swarm = SyntheticSwarm(pts, features=np.array([[2.6, 0.2]]), seed=4)
    cfg = PMultiBeaRegConfig(features="lidar", scale_search=False)
    loc = PMultiBeaRegLocalizer("ugv_0", swarm.ids, cfg, np.random.default_rng(5))
    for k in range(100):
        v = np.column_stack([0.1 * np.ones(4), 0.5 * np.sin(0.05 * k + np.arange(4))])
        meas, comms = swarm.step(v, det_noise_m=0.01)
        loc.step(swarm.time_s, meas["ugv_0"], comms["ugv_0"])
    pinned = [
        [0.4109344072, -2.019542883673, -2.434129415803],
        [1.066544826495, 0.469162527313, -0.009830505869],
        [1.59776715058, -1.561735772001, -0.99994995503],
    ]
    means = np.array([loc.filters[t].mean() for t in swarm.ids[1:]])
    np.testing.assert_allclose(means, pinned, rtol=0, atol=1e-11)


def test_sorted_triangle_search_equals_the_dense_reference():
    """The windowed search over the sorted third differences finds exactly the reference's
    candidates, in the same order, with the same residuals (random sets, a clustered set that
    puts many sums near the tolerance's edge, and empty ones)."""
    from localization.mutual.beareg import (
        _ordered_pairs,
        _triangle_candidates,
        _triangle_candidates_dense,
    )

    rng = np.random.default_rng(7)
    for trial in range(30):
        sets = [rng.uniform(-np.pi, np.pi, rng.integers(0, 9)) for _ in range(3)]
        if trial % 3 == 0:  # near-regular: many triples close to the tolerance's edge
            sets = [
                np.round(np.linspace(-np.pi, np.pi, 7, endpoint=False) + k, 2) for k in range(3)
            ]
        diffs = []
        for k, bs in enumerate(sets):
            p = _ordered_pairs(len(bs))
            d = bs[p[:, 1]] - bs[p[:, 0]] if k != 1 else bs[p[:, 0]] - bs[p[:, 1]]
            diffs.append(wrap_angle(d))
        for tol in (math.radians(1.0), math.radians(5.0), 0.5):
            hits, res = _triangle_candidates(*diffs, tol)
            ref_hits, ref_res = _triangle_candidates_dense(*diffs, tol)
            np.testing.assert_array_equal(hits, ref_hits)
            np.testing.assert_array_equal(res, ref_res)


def test_scale_search_grid_is_bounded_and_range_refuses_bools():
    import math

    from localization.mutual.pmultibeareg import MAX_SCALES, PMultiBeaRegConfig, scale_grid

    grid = scale_grid((0.2, 4.7), math.radians(2.5))
    assert grid[0] == 0.2 and grid[-1] >= 4.7 and grid[-2] < 4.7  # covers the range, no more
    np.testing.assert_allclose(grid[1:] / grid[:-1], 1.0 + 0.5 * math.radians(2.5))
    with pytest.raises(ValueError, match=f"more than {MAX_SCALES}"):
        PMultiBeaRegConfig(bearing_std_deg=0.01)
    PMultiBeaRegConfig(bearing_std_deg=0.01, scale_search=False)  # no grid without the search
    with pytest.raises(ValueError, match="range_m"):
        PMultiBeaRegConfig(range_m=(True, 2.0))
