"""The compiled camera update visits only the kept (component, bearing) pairs: the same table, to
the bit, as the dense update over every pair (kept here as the readable reference)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from localization import kernels as K
from localization import scan_memory
from localization.mixture import N_ROWS
from swarm_env.config import SIMULATOR_PHD


@njit
def _camera_update_dense(tab, n, brg, fp, ip, memory, ox, oy):
    """Every (component, bearing) pair in an ``(n, M)`` array, then :func:`K._posterior`."""
    m = brg.shape[0]
    prune = fp[K.F_PRUNE]
    pd = K._camera_pd(tab, n, fp)
    if m == 0:
        return K._missed_only(tab, n, pd, prune, ip[K.I_MISSED_BERNOULLI], tab)
    kappa = fp[K.F_KAPPA_C_UNIFORM] if memory[0] != 0.0 else fp[K.F_KAPPA_C]
    kappas = K.camera_clutter(brg, memory, ox, oy, fp)
    min_r2 = fp[K.F_MIN_RANGE] * fp[K.F_MIN_RANGE]
    detected = np.empty((n, m))
    post_means = np.empty((2, n, m))
    post_covs = np.empty((3, n))
    for i in range(n):
        x, y, g0, g1, predicted, norm, half_inv_s = K.camera_component(
            tab, i, fp, min_r2, post_covs
        )
        pd_w = pd[i] * tab[0, i]
        floor = K._negligible_exponent(pd_w, norm, kappa, prune)
        for h in range(m):
            innov = brg[h] - predicted
            if innov >= math.pi or innov < -math.pi:
                innov = K._wrap(innov)
            exponent = (innov * innov) * half_inv_s
            if exponent < floor:
                detected[i, h] = 0.0
                continue
            detected[i, h] = math.exp(exponent) * norm * pd_w
            post_means[0, i, h] = x + g0 * innov
            post_means[1, i, h] = y + g1 * innov
    out, k, explained = K._posterior(
        tab, n, pd, detected, post_means, post_covs, kappas, prune, -1,
        ip[K.I_MISSED_BERNOULLI], tab, pd,
    )  # fmt: skip
    if ip[K.I_CAMERA_BIRTH]:
        return K._with_ray_births(out, k, brg, explained, fp, ip)
    return out, k


def _memory(rng, with_scan: bool) -> np.ndarray:
    """A robot's scan memory of a random scan taken where it stands (or none): a few objects,
    some wide enough to place camera clutter."""
    memory = np.zeros(scan_memory.MEMORY_LEN)
    if not with_scan:
        return memory
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    ranges = np.full(720, np.inf)
    for _ in range(3):
        centre, width = rng.uniform(-np.pi, np.pi), rng.uniform(0.02, 0.6)
        near = np.abs((angles - centre + np.pi) % (2 * np.pi) - np.pi) < width / 2
        ranges[near] = rng.uniform(0.4, 3.0)
    profiles = scan_memory.profiles_of(angles, ranges, np.array([720], dtype=np.int64))
    one = np.ones(1, dtype=np.int64)
    K._remember_scan(memory, profiles, one, np.zeros((1, 3)), 0 * one, 0)
    if memory[0] != 0.0:
        K.wide_objects_into(memory)
    return memory


def _table(rng, n: int) -> np.ndarray:
    """``n`` components: weights up to 1.2, means within 5 m (some at the origin, some on top
    of each other), covariances from tight to broad."""
    tab = np.zeros((N_ROWS, n))
    tab[0] = rng.uniform(1e-4, 1.2, n)
    tab[1:3] = rng.uniform(-5.0, 5.0, (2, n))
    if n > 2:
        tab[1:3, 0] = 0.0  # inside the robot
        tab[1:3, 1] = tab[1:3, 2] + 1e-3  # nearly coincident
    sd = rng.uniform(0.01, 1.0, (2, n))
    rho = rng.uniform(-0.9, 0.9, n)
    tab[3], tab[5] = sd[0] ** 2, sd[1] ** 2
    tab[4] = rho * sd[0] * sd[1]
    return tab


def _bearings(rng, tab, n: int, m: int) -> np.ndarray:
    """Half near components' bearings (detections), half anywhere (clutter), some past +-pi."""
    near = np.arctan2(tab[2, :n], tab[1, :n])[rng.integers(0, max(n, 1), m // 2)] if n else []
    brg = np.concatenate([np.asarray(near) + rng.normal(0, 0.02, len(near)),
                          rng.uniform(-np.pi, np.pi, m - len(near))])  # fmt: skip
    brg[:: max(m // 3, 1)] += 2 * np.pi * rng.choice([-1, 1])  # unwrapped inputs
    return brg


CONFIGS = [
    {},
    {"births": {"camera": "ray"}},
    {"missed_detection": "phd"},
    {"missed_detection": "bernoulli"},
    {"reduction": {"prune_threshold": 1e-12}},
    {"camera": {"clutter_per_wide_object": 0.0}},
]


@pytest.mark.parametrize(
    "overrides", CONFIGS, ids=lambda o: ",".join(map(str, o.items())) or "env"
)
def test_sparse_camera_update_equals_the_dense_one_bit_for_bit(overrides):
    try:
        config = SIMULATOR_PHD.replace(**overrides)
    except (TypeError, ValueError) as exc:  # an option this config does not have
        pytest.skip(str(exc))
    fp, ip, _, _ = K.pack_params(config)
    rng = np.random.default_rng(7)
    n_kept = 0
    for trial in range(300):
        n = int(rng.integers(0, 40))
        m = int(rng.integers(0, 25))
        tab = _table(rng, n)
        brg = _bearings(rng, tab, n, m)
        memory = _memory(rng, with_scan=trial % 3 != 0)
        ox, oy = rng.normal(0.0, 0.05, 2)
        a, ka = _camera_update_dense(tab, n, brg, fp, ip, memory, ox, oy)
        b, kb = K._camera_update(tab, n, brg, fp, ip, memory, ox, oy)
        assert ka == kb, (trial, n, m)
        np.testing.assert_array_equal(a[:, :ka], b[:, :kb], err_msg=f"trial {trial}")
        n_kept += kb
    assert n_kept > 300  # the cases keep components (detections are near components)
