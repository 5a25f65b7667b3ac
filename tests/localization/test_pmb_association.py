"""PMB association marginals: loopy belief propagation against exact enumeration."""

from __future__ import annotations

import numpy as np
import pytest

from localization.pmb.association import exact_marginals, exclusive_sums, lbp_marginals

# Loopy BP is exact on graphs without cycles and approximate on graphs with cycles. Measured
# on 300 random problems (N, M <= 4, psi lognormal(0, 2), 30 % of pairs gated out): the largest
# marginal error was 0.076. The tolerance for cyclic problems is stated with that margin.
LOOPY_TOLERANCE = 0.1


def random_psi(rng, n, m, density=0.7):
    return rng.lognormal(0.0, 2.0, (n, m)) * (rng.random((n, m)) < density)


def test_exclusive_sums_match_total_minus_own():
    rng = np.random.default_rng(0)
    for m in range(0, 7):
        a = rng.random((3, m))
        np.testing.assert_allclose(exclusive_sums(a), a.sum(axis=1, keepdims=True) - a, atol=1e-14)


def test_exclusive_sums_do_not_cancel():
    # total - own would return 0 for the small entries' complement next to a huge one
    a = np.array([[1e20, 1.0, 2.0]])
    np.testing.assert_array_equal(exclusive_sums(a), [[3.0, 1e20 + 2.0, 1e20 + 1.0]])


@pytest.mark.parametrize("seed", range(5))
def test_lbp_close_to_exact_on_random_small_problems(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        n, m = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        psi = random_psi(rng, n, m)
        p_track, p_unused, iterations = lbp_marginals(psi)
        e_track, e_unused = exact_marginals(psi)
        assert iterations <= 100
        np.testing.assert_allclose(p_track.sum(axis=1), 1.0, atol=1e-12)
        assert np.abs(p_track - e_track).max() < LOOPY_TOLERANCE
        assert np.abs(p_unused - e_unused).max() < LOOPY_TOLERANCE
        assert (p_track >= 0).all() and (p_unused >= 0).all() and (p_unused <= 1).all()


@pytest.mark.parametrize("shape", [(1, 5), (5, 1), (1, 1)])
def test_lbp_exact_on_stars(shape):
    """One track (or one measurement): the graph is a star, no cycle: BP is exact."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        psi = random_psi(rng, *shape)
        p_track, p_unused, _ = lbp_marginals(psi)
        e_track, e_unused = exact_marginals(psi)
        np.testing.assert_allclose(p_track, e_track, atol=1e-12)
        np.testing.assert_allclose(p_unused, e_unused, atol=1e-12)


def test_lbp_exact_on_forests():
    """Tracks with disjoint gates, and a chain (track 0 - z0 - track 1 - z1): no cycle."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        forest = np.zeros((4, 5))
        forest[0, 0:2] = rng.lognormal(0, 2, 2)
        forest[1, 2] = rng.lognormal(0, 2)
        forest[2, 3:5] = rng.lognormal(0, 2, 2)
        chain = np.array([[rng.lognormal(0, 2), 0.0], rng.lognormal(0, 2, 2)])
        for psi in (forest, chain):
            p_track, p_unused, _ = lbp_marginals(psi)
            e_track, e_unused = exact_marginals(psi)
            np.testing.assert_allclose(p_track, e_track, atol=1e-10)
            np.testing.assert_allclose(p_unused, e_unused, atol=1e-10)


def test_lbp_hand_case_two_tracks_one_measurement():
    """psi = (a, b) for one measurement: P(track 0 uses it) = a / (1 + a + b)."""
    a, b = 3.0, 0.5
    p_track, p_unused, _ = lbp_marginals(np.array([[a], [b]]))
    np.testing.assert_allclose(p_track[:, 1], [a / (1 + a + b), b / (1 + a + b)], atol=1e-14)
    np.testing.assert_allclose(p_unused, [1 / (1 + a + b)], atol=1e-14)


def test_lbp_empty_and_gated():
    p_track, p_unused, it = lbp_marginals(np.zeros((0, 3)))
    assert p_track.shape == (0, 4) and np.array_equal(p_unused, np.ones(3)) and it == 0
    p_track, p_unused, _ = lbp_marginals(np.zeros((2, 0)))
    assert np.array_equal(p_track, np.ones((2, 1))) and p_unused.shape == (0,)
    p_track, p_unused, _ = lbp_marginals(np.zeros((2, 2)))  # everything gated out
    assert np.array_equal(p_track[:, 0], [1.0, 1.0]) and np.array_equal(p_unused, [1.0, 1.0])


def test_lbp_huge_weights_stay_finite():
    psi = np.array([[1e200, 1.0], [1e-200, 1e150]])
    p_track, p_unused, _ = lbp_marginals(psi)
    assert np.isfinite(p_track).all() and np.isfinite(p_unused).all()
    np.testing.assert_allclose(p_track[0, 1], 1.0) and np.testing.assert_allclose(
        p_track[1, 2], 1.0
    )


def test_compiled_lbp_equals_reference():
    from localization.pmb.kernels import lbp

    rng = np.random.default_rng(9)
    for _ in range(50):
        psi = random_psi(rng, int(rng.integers(0, 6)), int(rng.integers(0, 6)))
        p_track, p_unused, _ = lbp_marginals(psi, 100, 1e-12)
        k_track, k_unused = lbp(psi, 100, 1e-12)
        np.testing.assert_allclose(k_track, p_track, rtol=0, atol=1e-13)
        np.testing.assert_allclose(k_unused, p_unused, rtol=0, atol=1e-13)
