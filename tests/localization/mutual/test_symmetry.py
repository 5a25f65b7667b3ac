"""Rotational symmetry and the number of registration solutions (Stegagno 2012, Props. 1-4)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from localization.mutual.multireg import multi_register
from localization.mutual.se2 import points_to_frame
from localization.mutual.symmetry import (
    _invariant,
    is_rotationally_symmetric,
    number_of_solutions,
    prime_factors,
    symmetric_partition,
    symmetry_order,
)


def _polygon(n: int, radius: float = 1.0) -> np.ndarray:
    a = 2 * np.pi * np.arange(n) / n
    return radius * np.column_stack([np.cos(a), np.sin(a)])


SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
LATTICE = np.array([[i, j] for i in range(3) for j in range(3)], dtype=float)
TRIANGLE_CENTRE = np.vstack([[0.0, 0.0], _polygon(3)])
IRREGULAR = np.array([[0.0, 0.0], [1.0, 0.0], [1.3, 1.0], [0.0, 1.0]])


def _observations(points: np.ndarray, rng: np.random.Generator, noise_m: float = 0.0):
    """Every robot's detections of the others in its own randomly oriented frame."""
    yaw = rng.uniform(-np.pi, np.pi, len(points))
    poses = np.column_stack([points, yaw])
    out = []
    for i in range(len(points)):
        z = points_to_frame(np.delete(points, i, axis=0), poses[i])
        out.append(z + rng.normal(0.0, noise_m, z.shape))
    return out, poses


def test_prime_factors():
    assert prime_factors(1) == [] and prime_factors(12) == [2, 3] and prime_factors(13) == [13]
    with pytest.raises(ValueError, match="n must be"):
        prime_factors(0)


@pytest.mark.parametrize(
    ("points", "order", "count"),
    [
        (SQUARE, 4, 6),  # regular n-gon: (n-1)! (Corollary 1)
        (_polygon(5), 5, 24),
        (_polygon(6), 6, 120),
        (TRIANGLE_CENTRE, 3, 6),  # c in Z: (l!)^((n-1)/l) = 3!
        (LATTICE, 4, 576),  # the thesis's 9-robot lattice (section 12.1: 576 solutions)
        (np.vstack([_polygon(3), _polygon(3, 2.0)]), 3, 2 * 6),  # two orbits: 2! * 3!
        (IRREGULAR, 1, 1),
    ],
)
def test_order_and_number_of_solutions(points, order, count):
    assert symmetry_order(points) == order
    assert is_rotationally_symmetric(points) == (order > 1)
    assert number_of_solutions(points) == count
    # Symmetry is invariant under roto-translations (section 4.1.1).
    moved = points @ np.array([[0.6, -0.8], [0.8, 0.6]]).T + [3.0, -1.0]
    assert symmetry_order(moved, 1e-9) == order


def test_partition_of_the_lattice():
    sizes = sorted(len(e) for e in symmetric_partition(LATTICE))
    assert sizes == [1, 4, 4]  # the centre, the corners, the edge midpoints (Lemma 1)


def test_near_symmetry_within_tolerance():
    rng = np.random.default_rng(0)
    noisy = SQUARE + rng.normal(0.0, 0.005, SQUARE.shape)
    assert symmetry_order(noisy, tol_m=0.05) == 4
    assert symmetry_order(noisy, tol_m=1e-4) == 1


@pytest.mark.parametrize(
    ("points", "expected"),
    [(SQUARE, 6), (_polygon(5), 24), (TRIANGLE_CENTRE, 6), (IRREGULAR, 1)],
)
@pytest.mark.parametrize("noise_m", [0.0, 0.01])
def test_multireg_finds_every_solution_of_a_symmetric_formation(points, expected, noise_m):
    """P-MultiReg with an uninformed belief returns exactly the formations of Proposition 4,
    and every hypothesis for a robot lies on a point of its orbit (Proposition 3)."""
    rng = np.random.default_rng(1)
    obs, poses = _observations(points, rng, noise_m)
    result = multi_register(obs[0], {k: obs[k] for k in range(1, len(points))})
    assert result.n_branches == expected == len(result.branches)
    assert not result.truncated
    true_rel = points_to_frame(points, poses[0])  # the formation in robot 0's frame
    for k, (hyp, _) in result.hypotheses.items():
        d = np.linalg.norm(hyp[:, None, :2] - true_rel[None, :, :], axis=-1)
        assert (d.min(axis=1) < 0.05).all()  # every hypothesis sits on a robot's position
        truth_k = np.hypot(*(hyp[:, :2] - true_rel[k]).T).min()
        assert truth_k < 0.05  # and the true pose is among them


def test_belief_resolves_the_ambiguity():
    """With a belief around the truth, the fitness test keeps the one right formation."""
    rng = np.random.default_rng(2)
    obs, poses = _observations(SQUARE, rng, 0.005)
    from localization.mutual.se2 import inverse_compose

    truth = {k: inverse_compose(poses[k], poses[0]) for k in (1, 2, 3)}

    def fitness(label, cand, covs):
        r = cand - truth[label]
        r[:, 2] = np.remainder(r[:, 2] + np.pi, 2 * np.pi) - np.pi
        return -0.5 * ((r[:, :2] ** 2).sum(1) / 0.05**2 + r[:, 2] ** 2 / math.radians(5) ** 2)

    result = multi_register(obs[0], {k: obs[k] for k in (1, 2, 3)}, fitness)
    assert len(result.branches) == 1
    for k, (hyp, _) in result.hypotheses.items():
        assert len(hyp) == 1 and np.hypot(*(hyp[0, :2] - truth[k][:2])) < 0.03


def _matches_one_to_one(z: np.ndarray, phi: float, tol_m: float) -> tuple[bool, bool]:
    """Brute force over permutations: (a one-to-one matching within tol exists, every point of
    each set has some point of the other within tol)."""
    c = z.mean(axis=0)
    rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    d = np.linalg.norm(z[:, None] - ((z - c) @ rot.T + c)[None], axis=-1)
    close = d <= tol_m
    perfect = any(close[np.arange(len(z)), p].all() for p in itertools.permutations(range(len(z))))
    return perfect, bool(close.any(axis=0).all() and close.any(axis=1).all())


def test_symmetry_needs_a_one_to_one_matching():
    """Each point has a partner within tol under the half-turn (n - 1 = 4: a point sits on the
    centroid), in both directions, but two points share their only partner: not symmetric."""
    z = np.array([[0.0, 0.0], [0.3, -0.6], [0.6, -0.6], [-0.1, 0.1], [-0.4, 0.1]])
    for tol in (0.25, 0.3, 0.35):
        assert _matches_one_to_one(z, math.pi, tol) == (False, True)
        assert not is_rotationally_symmetric(z, tol)
        assert symmetry_order(z, tol) == 1


def test_invariance_agrees_with_brute_force_matching():
    rng = np.random.default_rng(3)
    for _ in range(300):
        n = int(rng.integers(2, 7))
        z = np.round(rng.uniform(-1.0, 1.0, (n, 2)), 1)
        for m in (2, 3):
            assert (
                _invariant(z, 2 * math.pi / m, 0.3)
                == _matches_one_to_one(z, 2 * math.pi / m, 0.3)[0]
            )
