"""P-MultiBeaReg (seed 001 chapter 10): triangles, 3-intersections, bearing-orientations."""

from __future__ import annotations

import math

import numpy as np

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
