"""The vectorised filter against a naive Python-loop reference written from the equations.

The reference below loops over components, measurements and component pairs with plain
``math`` and 2x2 ``numpy.linalg`` calls; it shares no code with the package.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization import GaussianMixture, PHDConfig, RobotCentricPHD
from localization.detection import DetectionModel
from localization.mixture import arrays_from_table, table_from_arrays
from localization.reducer import cap, merge, prune

RTOL = 1e-9
ATOL = 1e-12


# ----------------------------------------------------------------------------- reference
def ref_bump(mean, direction_rad: float, sigma: float, min_range: float) -> float:
    """Peak-1 angular bump exp((cos d - 1) / sigma^2) (see localization.detection), with the
    bearing vector m / max(|m|, min_range) (a mean at the origin gets the zero vector)."""
    r = max(math.hypot(*mean), min_range)
    cos_d = (mean[0] * math.cos(direction_rad) + mean[1] * math.sin(direction_rad)) / r
    return math.exp((cos_d - 1.0) / sigma**2)


def ref_lidar_pd(cfg: PHDConfig, weights, means, nulls=()):
    out = []
    for i in range(len(weights)):
        r = math.hypot(*means[i])
        if cfg.lidar.pd_model == "constant":
            out.append(cfg.lidar.detection_probability if r <= cfg.lidar.range_m else 0.0)
            continue
        slope, mid = cfg.lidar.pd_slope_per_m, cfg.lidar.pd_midpoint_m
        pd = 1.0 / (cfg.lidar.pd_offset + math.exp(slope * (r - mid)))
        for c, width in zip(
            cfg.lidar.blind_sector_centers_deg, cfg.lidar.blind_sector_widths_deg, strict=True
        ):
            sigma = math.radians(width) / 2
            pd *= 1.0 - ref_bump(means[i], math.radians(c), sigma, cfg.reduction.min_range_m)
        pd *= ref_occlusion(cfg, i, weights, means)
        for b in nulls:
            sigma = math.radians(cfg.lidar.interference_std_deg)
            pd *= 1.0 - cfg.lidar.interference_depth * ref_bump(
                means[i], b, sigma, cfg.reduction.min_range_m
            )
        out.append(pd)
    return np.array(out)


def ref_occlusion(cfg, i, weights, means):
    f = 1.0
    ri = math.hypot(*means[i])
    for j in range(len(weights)):
        rj = math.hypot(*means[j])
        if rj < ri - cfg.lidar.occlusion_min_separation_m:
            ui = np.asarray(means[i]) / max(ri, cfg.reduction.min_range_m)
            uj = np.asarray(means[j]) / max(rj, cfg.reduction.min_range_m)
            bump = math.exp(
                (float(ui @ uj) - 1.0) / math.radians(cfg.lidar.occlusion_std_deg) ** 2
            )
            f *= 1.0 - min(weights[j], 1.0) * bump
    return f


def ref_camera_pd(cfg, weights, means):
    out = []
    for i in range(len(weights)):
        r = math.hypot(*means[i])
        pd = 1.0 / (
            cfg.camera.pd_offset
            + math.exp(cfg.camera.pd_slope_per_m * (r - cfg.camera.pd_midpoint_m))
        )
        if r < cfg.reduction.min_range_m:
            pd = 0.0
        out.append(pd * ref_occlusion(cfg, i, weights, means))
    return np.array(out)


def ref_lidar_update(weights, means, covs, points, pd, r, kappa):
    """GM-PHD update, Vo & Ma 2006 Table I, one loop per component and measurement."""
    R = r * np.eye(2)
    out_w, out_m, out_p = [], [], []
    for i in range(len(weights)):
        out_w.append((1 - pd[i]) * weights[i])
        out_m.append(means[i])
        out_p.append(covs[i])
    for i in range(len(weights)):
        s = covs[i] + R
        k = covs[i] @ np.linalg.inv(s)
        a = np.eye(2) - k
        p_post = a @ covs[i] @ a.T + k @ R @ k.T  # Joseph form
        for z in points:
            out_m.append(means[i] + k @ (z - means[i]))
            out_p.append(p_post)
    per_meas = []
    for z in points:
        terms = []
        for i in range(len(weights)):
            s = covs[i] + R
            d = z - means[i]
            g = math.exp(-0.5 * d @ np.linalg.solve(s, d)) / (
                2 * math.pi * math.sqrt(np.linalg.det(s))
            )
            terms.append(pd[i] * weights[i] * g)
        per_meas.append([t / (kappa + sum(terms)) for t in terms])
    for i in range(len(weights)):
        for h in range(len(points)):
            out_w.append(per_meas[h][i])
    return np.array(out_w), np.array(out_m).reshape(-1, 2), np.array(out_p).reshape(-1, 2, 2)


def ref_camera_update(weights, means, covs, bearings, pd, rc, kappa, min_range):
    out_w, out_m, out_p = list((1 - pd) * weights), list(means), list(covs)
    terms = np.zeros((len(weights), len(bearings)))
    for i in range(len(weights)):
        x, y = means[i]
        r2 = max(x * x + y * y, min_range**2)
        h = np.array([-y / r2, x / r2])
        s = h @ covs[i] @ h + rc
        k = covs[i] @ h / s
        a = np.eye(2) - np.outer(k, h)
        p_post = a @ covs[i] @ a.T + rc * np.outer(k, k)
        for j, b in enumerate(bearings):
            nu = (b - math.atan2(y, x) + math.pi) % (2 * math.pi) - math.pi
            out_m.append(means[i] + k * nu)
            out_p.append(p_post)
            terms[i, j] = (
                pd[i] * weights[i] * math.exp(-0.5 * nu * nu / s) / math.sqrt(2 * math.pi * s)
            )
    for i in range(len(weights)):
        for j in range(len(bearings)):
            out_w.append(terms[i, j] / (kappa + terms[:, j].sum()))
    return np.array(out_w), np.array(out_m).reshape(-1, 2), np.array(out_p).reshape(-1, 2, 2)


def ref_merge(weights, means, covs, threshold):
    """Vo & Ma 2006, Table II, literally: pop the heaviest, absorb its gate, repeat."""
    remaining = list(range(len(weights)))
    out = []
    while remaining:
        j = max(remaining, key=lambda i: (weights[i], -i))
        cluster = []
        for i in remaining:
            d = means[i] - means[j]
            if d @ np.linalg.solve(covs[i], d) <= threshold:
                cluster.append(i)
        wsum = sum(weights[i] for i in cluster)
        m = sum(weights[i] * means[i] for i in cluster) / wsum
        p = (
            sum(weights[i] * (covs[i] + np.outer(m - means[i], m - means[i])) for i in cluster)
            / wsum
        )
        out.append((wsum, m, p))
        remaining = [i for i in remaining if i not in cluster]
    return out


# ----------------------------------------------------------------------------- helpers
def random_mixture(rng, n, spread=2.5, clumped=False):
    if clumped:  # a few tight clusters: lots of merging and covering chains
        centres = rng.uniform(-spread, spread, size=(max(1, n // 4), 2))
        means = centres[rng.integers(0, len(centres), n)] + rng.normal(0, 0.05, (n, 2))
    else:
        means = rng.uniform(-spread, spread, size=(n, 2))
    a = rng.normal(size=(n, 2, 2)) * rng.uniform(0.02, 0.3, size=(n, 1, 1))
    covs = a @ a.transpose(0, 2, 1) + 1e-4 * np.eye(2)
    weights = rng.uniform(0.01, 1.2, size=n)
    return weights, means, covs


def sorted_components(weights, means, covs):
    order = np.lexsort((means[:, 1], means[:, 0], weights))
    return weights[order], means[order], covs[order]


# ----------------------------------------------------------------------------- tests
@pytest.mark.parametrize("seed", range(6))
def test_lidar_pd_matches_reference(seed):
    rng = np.random.default_rng(seed)
    cfg = PHDConfig.perera2021()
    n = int(rng.integers(1, 15))
    w, m, c = random_mixture(rng, n, clumped=bool(seed % 2))
    m[0] = [0.0, 0.0]  # a component at the origin exercises the range floor
    nulls = rng.uniform(-math.pi, math.pi, size=int(rng.integers(0, 5)))
    model = DetectionModel(cfg)
    table = table_from_arrays(w, m, c)
    got = model.lidar(table, nulls)
    assert np.allclose(got, ref_lidar_pd(cfg, w, m, nulls), rtol=RTOL, atol=ATOL)
    assert ((got >= 0) & (got <= 1)).all()
    assert np.allclose(model.camera(table), ref_camera_pd(cfg, w, m), rtol=RTOL, atol=ATOL)
    cfg_c = PHDConfig.perera2021().replace(lidar={"pd_model": "constant"})
    got_c = DetectionModel(cfg_c).lidar(table, None)
    assert np.allclose(got_c, ref_lidar_pd(cfg_c, w, m), atol=0)


def test_blind_sector_pd_vanishes_at_centre_and_recovers():
    cfg = PHDConfig.perera2021().replace(lidar={"occlusion_min_separation_m": 0.0})
    model = DetectionModel(cfg)
    angles = np.radians([45.0, 47.5, 50.0, 60.0, 90.0])
    means = 1.0 * np.stack((np.cos(angles), np.sin(angles)), axis=1)
    pd = model.lidar(
        table_from_arrays(np.full(5, 1e-9), means, 0.01 * np.tile(np.eye(2), (5, 1, 1))), None
    )
    range_factor = 1.0 / (1.02 + math.exp(8 * (1.0 - 1.5)))
    assert pd[0] < 1e-12  # centre of the 45 deg sector
    assert 0.0 < pd[1] < pd[2] < pd[3]
    assert np.isclose(pd[4], range_factor, rtol=1e-9)  # far from every sector
    # The bump is the Gaussian exp(-d^2 / (2 sigma^2)) to within a fraction of a percent.
    d = math.radians(2.5)
    sigma = math.radians(5.0)
    assert np.isclose(1 - pd[1] / range_factor, math.exp(-(d**2) / (2 * sigma**2)), rtol=1e-4)


@pytest.mark.parametrize(
    ("pd_model", "blind_model"),
    [("seed", "seed"), ("seed", "visible-width"), ("constant", "seed")],
)
def test_lidar_pd_is_its_range_factor_times_its_blind_sector_factor(pd_model, blind_model):
    """For a lone component (no occlusion) ``lidar`` is the product of the two public factors
    (what ``agents.scripted.expected_lidar_detections`` uses, with the component's bearing
    std); the constant model has no sectors, and the seed model's vanish at their centres."""
    cfg = PHDConfig.perera2021().replace(
        lidar={"pd_model": pd_model, "blind_sector_model": blind_model}
    )
    model = DetectionModel(cfg)
    rng = np.random.default_rng(7)
    ranges = rng.uniform(0.2, 3.0, 50)
    bearings = rng.uniform(-math.pi, math.pi, 50)
    # a quarter of them within 8 deg of a sector centre, where the notch's edges are
    near = rng.choice(np.radians(cfg.lidar.blind_sector_centers_deg), 12) + np.radians(
        rng.uniform(-8.0, 8.0, 12)
    )
    bearings[:12] = near
    lone = [
        model.lidar(
            table_from_arrays(
                np.ones(1), np.array([[r * math.cos(b), r * math.sin(b)]]), 0.01 * np.eye(2)[None]
            ),
            None,
        )[0]
        for r, b in zip(ranges, bearings, strict=True)
    ]
    bearing_std = 0.1 / np.maximum(
        ranges, cfg.reduction.min_range_m
    )  # sqrt(0.01) m across the bearing
    product = model.lidar_range_factor(ranges) * model.lidar_blind_sector_factor(
        bearings, ranges, bearing_std
    )
    np.testing.assert_allclose(product, lone, rtol=1e-9, atol=1e-12)
    centres = np.radians(cfg.lidar.blind_sector_centers_deg)
    expected = np.ones(4) if pd_model == "constant" else np.zeros(4)
    np.testing.assert_allclose(
        model.lidar_blind_sector_factor(centres, np.ones(4)), expected, atol=1e-12
    )
    np.testing.assert_allclose(
        model.lidar_blind_sector_factor(centres + math.pi / 4, np.ones(4)), 1.0
    )


def test_occlusion_hides_the_farther_component():
    cfg = PHDConfig.perera2021()
    model = DetectionModel(cfg)
    means = np.array([[0.5, 0.0], [1.2, 0.0], [1.2, 0.5]])
    pd = model.lidar(
        table_from_arrays(np.array([1.0, 1.0, 1.0]), means, 0.01 * np.tile(np.eye(2), (3, 1, 1))),
        None,
    )
    assert pd[1] < 1e-9 * pd[2]  # right behind a weight-1 component: hidden
    assert pd[0] > 0.9


def assert_table_is(table: np.ndarray, reference: tuple) -> None:
    """``table`` (6, N) holds the reference's ``(weights, means, covariances)``."""
    for got, want in zip(arrays_from_table(table), reference, strict=True):
        assert np.allclose(got, want, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("seed", range(8))
def test_lidar_update_matches_reference(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(1, 12))
    m_count = int(rng.integers(0, 6))
    w, m, c = random_mixture(rng, n)
    points = np.concatenate(
        [
            m[: m_count // 2] + rng.normal(0, 0.05, (m_count // 2, 2)),
            rng.uniform(-3, 3, (m_count - m_count // 2, 2)),
        ]
    )
    pd = rng.uniform(0, 1, n)
    from localization import phd

    table = table_from_arrays(w, m, c)
    out, _ = phd.lidar_update(table, points, pd, 0.0025, 0.3)
    assert_table_is(out, ref_lidar_update(w, m, c, points, pd, 0.0025, 0.3))


@pytest.mark.parametrize("seed", range(8))
def test_camera_update_matches_reference(seed):
    rng = np.random.default_rng(200 + seed)
    n = int(rng.integers(1, 12))
    w, m, c = random_mixture(rng, n)
    if seed == 0:
        m[0] = [0.0, 0.0]  # the Jacobian floor
    bearings = rng.uniform(-math.pi, math.pi, int(rng.integers(0, 6)))
    pd = rng.uniform(0, 1, n)
    rcam = math.radians(5) ** 2
    from localization import phd

    out, _ = phd.camera_update(table_from_arrays(w, m, c), bearings, pd, rcam, 0.2, 0.1)
    assert_table_is(out, ref_camera_update(w, m, c, bearings, pd, rcam, 0.2, 0.1))


@pytest.mark.parametrize("seed", range(12))
def test_merge_matches_sequential_vo_ma(seed):
    rng = np.random.default_rng(300 + seed)
    n = int(rng.integers(1, 40))
    w, m, c = random_mixture(rng, n, clumped=seed % 3 != 0)
    if seed % 4 == 1:
        w[: n // 2] = 0.5  # ties in weight
    threshold = [1.0, 4.0, 16.0][seed % 3]
    out = merge(table_from_arrays(w, m, c), threshold)
    gw, gm, gc = sorted_components(*arrays_from_table(out))
    ref = ref_merge(w, m, c, threshold)
    rw = np.array([r[0] for r in ref])
    rm = np.array([r[1] for r in ref]).reshape(-1, 2)
    rc = np.array([r[2] for r in ref]).reshape(-1, 2, 2)
    rw, rm, rc = sorted_components(rw, rm, rc)
    assert gw.shape == rw.shape
    assert np.allclose(gw, rw, rtol=RTOL, atol=ATOL)
    assert np.allclose(gm, rm, rtol=RTOL, atol=1e-10)
    assert np.allclose(gc, rc, rtol=1e-8, atol=1e-10)


def test_merge_resolves_covering_chains_like_the_sequential_loop():
    # a (heavy) covers b, b covers c, a does not cover c: greedy keeps c as its own cluster.
    w = np.array([1.0, 0.5, 0.2])
    m = np.array([[0.0, 0.0], [0.3, 0.0], [0.6, 0.0]])
    c = np.array([np.eye(2) * 0.04, np.eye(2) * 0.04, np.eye(2) * 0.01])
    # d(a, b) with P_b: 0.09/0.04 = 2.25 <= 4; d(b, c) with P_c: 9 > 4; d(a, c) with P_c: 36.
    out = merge(table_from_arrays(w, m, c), 4.0)
    assert out.shape[1] == 2
    assert np.allclose(np.sort(out[0]), [0.2, 1.5])
    ref = ref_merge(w, m, c, 4.0)
    assert len(ref) == 2


def test_merge_preserves_total_weight_exactly_and_prune_loses_exactly_the_pruned(rng):
    for _ in range(20):
        n = int(rng.integers(2, 60))
        w, m, c = random_mixture(rng, n, clumped=True)
        w = w * rng.choice([1e-6, 1.0], size=n)
        table = table_from_arrays(w, m, c)
        merged = merge(table, 4.0)
        assert math.isclose(merged[0].sum(), w.sum(), rel_tol=1e-13)
        pruned = prune(table, 1e-4)
        assert math.isclose(pruned[0].sum(), w.sum() - w[w < 1e-4].sum(), rel_tol=1e-13)
        capped = cap(table, 5)
        assert capped.shape[1] == min(5, n)
        assert np.allclose(np.sort(capped[0]), np.sort(w)[-min(5, n) :])


@pytest.mark.parametrize("seed", range(4))
def test_filter_step_matches_reference_pipeline(seed):
    """predict -> lidar -> camera through the public API vs the reference step by step."""
    rng = np.random.default_rng(400 + seed)
    cfg = PHDConfig.perera2021().replace(
        births={"model": "fixed"},
        reduction={"prune_threshold": 1e-5, "merge_threshold": 1e-300, "max_components": 10_000},
    )
    w, m, c = random_mixture(rng, int(rng.integers(1, 8)), spread=1.5)
    f = RobotCentricPHD(cfg)
    f.set_mixture(GaussianMixture(w, m, c))
    points = m[:2] + rng.normal(0, 0.05, (min(2, len(m)), 2))
    bearings = np.arctan2(m[:3, 1], m[:3, 0]) + rng.normal(0, 0.05, min(3, len(m)))
    f.update_lidar(points)
    # The fixed birth (mean 0, cov 4 I, weight 0.001) joins the lidar prior; its
    # missed-detection copy (right after the n prior components) is dropped.
    n = len(w)
    wb = np.append(w, cfg.births.weight)
    mb = np.vstack([m, [0.0, 0.0]])
    cb = np.concatenate([c, [cfg.births.std_m**2 * np.eye(2)]])
    pd = ref_lidar_pd(cfg, wb, mb)
    rw, rm, rc = ref_lidar_update(
        wb, mb, cb, points, pd, cfg.lidar.noise_var_m2, cfg.lidar.clutter_intensity
    )
    rw[n] = 0.0
    keep = rw >= cfg.reduction.prune_threshold
    rw, rm, rc = rw[keep], rm[keep], rc[keep]
    mix = f.mixture
    gw, gm, gc = sorted_components(np.array(mix.weights), np.array(mix.means), np.array(mix.covs))
    ew, em, ec = sorted_components(rw, rm, rc)
    assert np.allclose(gw, ew, rtol=RTOL, atol=ATOL)
    assert np.allclose(gm, em, rtol=RTOL, atol=ATOL)
    assert np.allclose(gc, ec, rtol=RTOL, atol=ATOL)
    f.update_camera(bearings)
    pdc = ref_camera_pd(cfg, rw, rm)
    rw2, rm2, rc2 = ref_camera_update(
        rw,
        rm,
        rc,
        bearings,
        pdc,
        cfg.camera.noise_var_rad2,
        cfg.camera.clutter_intensity,
        cfg.reduction.min_range_m,
    )
    keep = rw2 >= cfg.reduction.prune_threshold
    mix = f.mixture
    gw, gm, gc = sorted_components(np.array(mix.weights), np.array(mix.means), np.array(mix.covs))
    ew, em, ec = sorted_components(rw2[keep], rm2[keep], rc2[keep])
    assert np.allclose(gw, ew, rtol=RTOL, atol=ATOL)
    assert np.allclose(gm, em, rtol=RTOL, atol=ATOL)
    assert np.allclose(gc, ec, rtol=RTOL, atol=ATOL)


def ref_greedy_labels(close, weights):
    """Sequential greedy on an arbitrary gate matrix: heaviest first (ties: lower index)."""
    n = len(weights)
    remaining = set(range(n))
    labels = [-1] * n
    while remaining:
        j = max(remaining, key=lambda i: (weights[i], -i))
        for i in list(remaining):
            if close[j, i]:
                labels[i] = j
                remaining.discard(i)
    return np.array(labels)


@pytest.mark.parametrize("seed", range(40))
def test_greedy_clusters_matches_sequential_loop_on_arbitrary_gates(seed):
    from localization.reducer import greedy_clusters

    rng = np.random.default_rng(500 + seed)
    n = int(rng.integers(1, 80))
    density = rng.choice([0.02, 0.1, 0.3, 0.7])
    close = rng.random((n, n)) < density
    np.fill_diagonal(close, True)
    weights = rng.choice([0.1, 0.5, 1.0], size=n) if seed % 3 == 0 else rng.random(n)
    assert np.array_equal(greedy_clusters(close, weights), ref_greedy_labels(close, weights))
