"""PHDBank: batched filters must give exactly what independent RobotCentricPHD filters give."""

from __future__ import annotations

import numpy as np
import pytest

from localization import GaussianMixture, PHDBank, PHDConfig, RobotCentricPHD
from localization.frames import bearings_to_filter_frame, points_to_filter_frame
from swarm_env.config import SIMULATOR_PHD

R = 20


def canonical(table: np.ndarray) -> np.ndarray:
    """Columns sorted by (w, x, y, ...) so two tables with the same components compare.

    The keys are rounded to 1e-7 so that ties equal up to round-off (weights of exactly 1
    with zero clutter) sort the same way in both tables."""
    if table.shape[1] == 0:
        return table
    return table[:, np.lexsort(np.round(table[::-1], 7))]


def assert_same(
    filters: list[RobotCentricPHD], bank: PHDBank, where: str, atol: float = 1e-10
) -> None:
    for r, f in enumerate(filters):
        a, b = canonical(np.asarray(f.table)), canonical(bank.table(r))
        assert a.shape == b.shape, (
            f"{where}: robot {r} has {b.shape[1]} != {a.shape[1]} components"
        )
        assert np.allclose(a, b, rtol=0.0, atol=atol), f"{where}: robot {r} differs"
        pa, pb = f.__getstate__()["pending_births"], bank.pending_births(r)
        assert pa.shape == pb.shape and np.allclose(pa, pb, rtol=0.0, atol=1e-10), where


def random_calls(rng: np.random.Generator, steps: int, bearing_std: float = 0.08):
    """Random mixed batches: (kind, robots, args) with empty sets, clutter and null bearings."""
    targets = rng.uniform(-2.5, 2.5, size=(R, 8, 2))
    for _ in range(steps):
        kind = rng.choice(["predict", "lidar", "camera"], p=[0.3, 0.3, 0.4])
        robots = rng.choice(R, size=int(rng.integers(0, R + 1)), replace=False)
        if kind == "predict":
            yield kind, robots, (rng.normal(0.0, [0.03, 0.01, 0.05], size=(robots.size, 3)),)
        elif kind == "lidar":
            points, nulls = [], []
            for r in robots:
                m = int(rng.integers(0, 6))
                pts = targets[r, rng.choice(8, size=m, replace=False)]
                pts = pts + rng.normal(0.0, 0.05, (m, 2))
                if rng.random() < 0.3:  # clutter
                    pts = np.concatenate([pts, rng.uniform(-2.0, 2.0, (2, 2))])
                points.append(pts)
                nb = None if rng.random() < 0.5 else rng.uniform(-np.pi, np.pi, rng.integers(0, 4))
                nulls.append(nb)
            yield kind, robots, (points, None if rng.random() < 0.3 else nulls)
        else:
            bearings = []
            for r in robots:
                tg = targets[r, rng.integers(0, 8, int(rng.integers(0, 15)))]
                bearings.append(
                    np.arctan2(tg[:, 1], tg[:, 0]) + rng.normal(0.0, bearing_std, len(tg))
                )
            yield kind, robots, (bearings,)


def run_both(
    config: PHDConfig, seed: int, steps: int = 60, bearing_std: float = 0.08, atol: float = 1e-10
):
    filters = [RobotCentricPHD(config) for _ in range(R)]
    bank = PHDBank(config, R)
    rng = np.random.default_rng(seed)
    for step, (kind, robots, args) in enumerate(random_calls(rng, steps, bearing_std)):
        for i, r in enumerate(robots):
            f = filters[r]
            if kind == "predict":
                f.predict(args[0][i])
            elif kind == "lidar":
                f.update_lidar(args[0][i], None if args[1] is None else args[1][i])
            else:
                f.update_camera(args[0][i])
        getattr(bank, "predict" if kind == "predict" else f"update_{kind}")(robots, *args)
        assert_same(filters, bank, f"seed {seed} step {step} ({kind})", atol)
    return filters, bank


CONFIGS = {
    "lc-fixed": PHDConfig.perera2021().replace(births={"model": "fixed"}),
    "lc-measurement": PHDConfig.perera2021().replace(births={"model": "measurement"}),
    "lo-fixed": PHDConfig.perera2021().replace(mode="lidar-only", births={"model": "fixed"}),
    "lo-measurement": PHDConfig.perera2021().replace(
        mode="lidar-only", births={"model": "measurement"}
    ),
    "lc-fixed-cap": PHDConfig.perera2021().replace(
        births={"model": "fixed"}, reduction={"max_components": 6}
    ),
    "seed-defaults": PHDConfig.perera2021(),
    # Without the cap: its ray births give many components of exactly equal weight (the same
    # cells from several bearings), and at the cap the two engines may keep different ones of
    # those ties (equal weights to 5e-14, different positions). The cap path with ray births
    # is "camera-ray-cap" below. The bearing noise is the generator's (~5 deg): with the
    # simulator's measured 0.46 deg, the generator's bearings are 10-sigma outliers and the
    # thin ray cells' EKF updates amplify summation-order round-off to ~1e-10 m.
    "simulator": SIMULATOR_PHD.replace(
        reduction={"max_components": 400}, camera={"noise_std_deg": 5.0}
    ),
    "lc-measurement-cap": PHDConfig.perera2021().replace(
        births={"model": "measurement"}, reduction={"max_components": 5}
    ),
    "constant-models": PHDConfig.perera2021().replace(
        lidar={"pd_model": "constant", "occlusion_min_separation_m": 0.0},
        prediction={"survival_model": "constant"},
    ),
    "wide-merge": PHDConfig.perera2021().replace(
        births={"model": "measurement"}, reduction={"merge_threshold": 30.0}
    ),
    # below the compiled engine's likelihood-skip fraction: nothing may be skipped that survives
    "tiny-prune": PHDConfig.perera2021().replace(
        births={"model": "measurement"}, reduction={"prune_threshold": 1e-30, "max_components": 40}
    ),
    # the camera's own tracks, the untracked-teammate clutter and the Bernoulli missed term
    "camera-ray": PHDConfig.perera2021().replace(births={"model": "measurement", "camera": "ray"}),
    "camera-ray-cap": PHDConfig.perera2021().replace(
        births={"camera": "ray", "camera_components": 9}, reduction={"max_components": 12}
    ),
    "camera-ray-prune": PHDConfig.perera2021().replace(
        births={"camera": "ray", "camera_weight": 3e-4}
    ),
    "untracked-kappa": PHDConfig.perera2021().replace(
        births={"model": "measurement"}, camera={"untracked_density_per_m2": 0.3}
    ),
    # R_C(r): the blob-centroid term evaluated at each component's (and ray cell's) range
    "range-noise": PHDConfig.perera2021().replace(
        births={"model": "measurement"}, camera={"noise_std_deg": 2.0, "noise_width_fraction": 0.5}
    ),
    "range-noise-ray": PHDConfig.perera2021().replace(
        births={"camera": "ray"}, camera={"noise_std_deg": 2.0, "noise_width_fraction": 0.5}
    ),
    "bernoulli": PHDConfig.perera2021().replace(
        missed_detection="bernoulli", births={"model": "measurement"}
    ),
    # the lidar's missed copies moment-matched under the range-dependent P_d
    "missed-moments": PHDConfig.perera2021().replace(
        births={"model": "measurement"}, lidar={"missed_moments": True}
    ),
    "missed-moments-bernoulli-fixed": PHDConfig.perera2021().replace(
        missed_detection="bernoulli", lidar={"missed_moments": True, "pd_midpoint_m": 1.0}
    ),
    "bernoulli-fixed": PHDConfig.perera2021().replace(missed_detection="bernoulli"),
    # the blind sectors' notch from the beam geometry, averaged over each component's bearing;
    # wide sectors so that many components sit on a notch's edges
    "visible-width": PHDConfig.perera2021().replace(
        births={"model": "measurement"}, lidar={"blind_sector_model": "visible-width"}
    ),
    "visible-width-wide-sectors": PHDConfig.perera2021().replace(
        lidar={
            "blind_sector_model": "visible-width",
            "blind_sector_centers_deg": (30.0, 150.0, -90.0),
            "blind_sector_widths_deg": (40.0, 60.0, 50.0),
            "min_returns": 5,
        }
    ),
    "bernoulli-ray-constant": PHDConfig.perera2021().replace(
        missed_detection="bernoulli",
        births={"camera": "ray"},
        lidar={"pd_model": "constant", "detection_probability": 1.0},
        prediction={"survival_model": "constant"},
    ),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
@pytest.mark.parametrize("seed", [0, 1])
def test_bank_matches_independent_filters(name, seed):
    filters, bank = run_both(CONFIGS[name], seed)
    # the scenario did exercise the filter: some robots track something
    assert max(len(f) for f in filters) > 0
    if "cap" in name:
        assert max(len(f) for f in filters) == CONFIGS[name].reduction.max_components


def test_cap_and_covering_chains_are_exercised(monkeypatch):
    """The equivalence runs hit the cap and covering chains (a best coverer itself absorbed),
    counted on the reference filters, which the bank matches at every step."""
    import localization.filter as filter_module
    import localization.reducer as reducer

    seen = {"chains": 0, "cap": 0}

    def counting_reduce(table, prune_threshold, merge_threshold, max_components):
        pruned = reducer.prune(table, prune_threshold)
        if pruned.shape[1] > 1:
            means, covs = pruned[1:3], pruned[3:]
            close = reducer.gate_distances(means, covs) <= merge_threshold
            n = pruned.shape[1]
            rank_score = np.empty(n)  # n - rank: the heaviest coverer wins, even at 1e-30
            rank_score[np.lexsort((np.arange(n), -pruned[0]))] = np.arange(n, 0, -1)
            best = (close * rank_score[:, None]).argmax(axis=0)
            seen["chains"] += int(not (best == np.arange(best.size))[best].all())
        merged = reducer.merge(pruned, merge_threshold)
        seen["cap"] += int(merged.shape[1] > max_components)
        return reducer.cap(merged, max_components)

    monkeypatch.setattr(filter_module, "reduce", counting_reduce)
    run_both(CONFIGS["lc-measurement-cap"], 3, steps=40)
    assert seen["cap"] > 0 and seen["chains"] > 0


@pytest.mark.parametrize("with_poses", [False, True])
def test_apply_schedules_per_robot_order(with_poses):
    """``apply`` runs each robot's calls in order; sensor poses move lidar points into the
    filter's frame exactly as :mod:`localization.frames` does before the reference updates, and
    camera updates take the camera's position as the reference's ``sensor_pose`` does."""
    config = PHDConfig.perera2021().replace(births={"model": "measurement"})
    rng = np.random.default_rng(5)
    calls = [[] for _ in range(R)]
    for kind, robots, args in random_calls(rng, 40):
        for i, r in enumerate(robots):
            pose = (
                rng.normal(0.0, [0.03, 0.01, 0.1]) if with_poses and rng.random() < 0.7 else None
            )
            if kind == "predict":
                calls[r].append(("predict", args[0][i]))
            elif kind == "lidar":
                nulls = None if args[1] is None else args[1][i]
                calls[r].append(("lidar", args[0][i], nulls, pose))
            else:
                calls[r].append(("camera", args[0][i], pose))
    filters = [RobotCentricPHD(config) for _ in range(R)]
    for f, seq in zip(filters, calls, strict=True):
        for c in seq:
            if c[0] == "predict":
                f.predict(c[1])
            elif c[0] == "lidar":
                pts, nulls, pose = c[1:]
                if pose is not None:  # the reference's sensor_pose is exactly this
                    pts = points_to_filter_frame(pts, pose)
                    nulls = None if nulls is None else bearings_to_filter_frame(nulls, pose)
                f.update_lidar(pts, nulls)
            else:  # bearings rotated, and the model evaluated from the camera's position
                f.update_camera(c[1], sensor_pose=c[2])
    bank = PHDBank(config, R)
    bank.apply(calls)
    assert_same(filters, bank, "apply")


def test_round_trip_and_views():
    filters, bank = run_both(CONFIGS["lc-measurement"], 7, steps=30)
    copy = PHDBank.from_filters(filters)
    assert_same(filters, copy, "from_filters")
    back = bank.to_filters()
    assert_same(back, bank, "to_filters")
    for r in range(R):
        view = bank.views[r]
        mix = view.mixture
        assert isinstance(mix, GaussianMixture) and len(mix) == len(view) == len(filters[r])
        assert view.mixture is mix  # cached
        pos, w = view.estimate(0.3)
        pos_f, w_f = filters[r].estimate(0.3)
        assert pos.shape == pos_f.shape and np.allclose(w, w_f, atol=1e-10)
        assert view.total_weight == pytest.approx(filters[r].total_weight, abs=1e-9)
    # single-robot calls through a view equal the filter's
    view, f = bank.views[4], filters[4]
    view.predict([0.02, 0.0, 0.01])
    f.predict(np.array([0.02, 0.0, 0.01]))
    view.update_lidar([[1.0, 0.5]], [0.3])
    f.update_lidar(np.array([[1.0, 0.5]]), np.array([0.3]))
    view.update_camera([0.4, -1.0])
    f.update_camera(np.array([0.4, -1.0]))
    assert np.allclose(canonical(bank.table(4)), canonical(np.asarray(f.table)), atol=1e-10)
    view.reset()
    assert len(view) == 0 and len(bank.views[5]) == len(filters[5])
    bank.reset()
    assert bank.counts.sum() == 0


def snapshot(bank: PHDBank):
    return (
        bank.padded_tables()[0].copy(),
        bank.counts,
        [bank.pending_births(r) for r in range(bank.n_robots)],
    )


def assert_unchanged(bank: PHDBank, before) -> None:
    table, counts, pending = snapshot(bank)
    assert np.array_equal(table, before[0]) and np.array_equal(counts, before[1])
    assert all(np.array_equal(a, b) for a, b in zip(pending, before[2], strict=False))


GOOD = [np.array([[1.0, 0.5]]), np.empty((0, 2))]


@pytest.mark.parametrize(
    "method, args, name",
    [
        ("predict", ([0, 1], np.zeros((2, 2))), "odometry"),
        ("predict", ([0, 1], [[0.0, 0.0, np.nan], [0.0, 0.0, 0.0]]), "odometry"),
        ("predict", ([0, 1], np.zeros((3, 3))), "odometry"),
        ("predict", ([0, 0], np.zeros((2, 3))), "robots"),
        ("predict", ([0, 20], np.zeros((2, 3))), "robots"),
        ("predict", ([0.5, 1.0], np.zeros((2, 3))), "robots"),
        ("predict", ([[0, 1]], np.zeros((2, 3))), "robots"),
        ("update_lidar", ([0, 1], [np.zeros((1, 3)), np.zeros((0, 2))]), "points"),
        ("update_lidar", ([0, 1], [np.array([[0.0, np.inf]]), np.zeros((0, 2))]), "points"),
        ("update_lidar", ([0, 1], GOOD[:1]), "points"),
        ("update_lidar", ([0, 1], np.zeros((2, 1, 2))), "points"),
        ("update_lidar", ([0, 1], GOOD, [np.array([0.1, np.nan]), None]), "null_bearings"),
        ("update_lidar", ([0, 1], GOOD, [np.ones((2, 2)), None]), "null_bearings"),
        ("update_lidar", ([0, 1], GOOD, [None]), "null_bearings"),
        ("update_camera", ([0, 1], [np.array([0.1, np.nan]), np.zeros(0)]), "bearings"),
        ("update_camera", ([0, 1], [np.zeros((2, 2)), np.zeros(0)]), "bearings"),
        ("update_camera", ([0], [np.zeros(1), np.zeros(1)]), "bearings"),
        ("update_camera", ([-1], [np.zeros(1)]), "robots"),
    ],
)
def test_bad_input_raises_before_any_change(method, args, name):
    filters, bank = run_both(CONFIGS["lc-measurement"], 2, steps=20)
    before = snapshot(bank)
    with pytest.raises(ValueError, match=name):
        getattr(bank, method)(*args)
    assert_unchanged(bank, before)


def test_bad_constructor_and_apply():
    with pytest.raises(ValueError, match="config"):
        PHDBank("nope", 3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n_robots"):
        PHDBank(PHDConfig.perera2021(), 0)
    bank = PHDBank(PHDConfig.perera2021(), 2)
    bank.apply([[("predict", [0.0, 0.0, 0.0]), ("lidar", [[1.0, 0.0]], None)], []])
    before = snapshot(bank)
    with pytest.raises(ValueError, match="odometry"):
        bank.apply([[("camera", [0.1])], [("predict", [0.0, np.nan, 0.0])]])
    with pytest.raises(ValueError, match="calls"):
        bank.apply([[("teleport", 1.0)], []])
    with pytest.raises(ValueError, match="sensor_pose"):
        bank.apply([[("camera", [0.1], [0.0, 0.0])], []])
    with pytest.raises(ValueError, match=r"calls\[0\]"):
        bank.apply([None, []])
    with pytest.raises(ValueError, match="invalid call"):
        bank.apply([[([1], 2.0)], []])
    with pytest.raises(ValueError, match="invalid call"):
        bank.apply([[("camera", np.zeros(1), None, "extra")], []])
    # NaN / inf inside float64 arrays pass the per-call shape checks and are caught by the one
    # finiteness check over the joined buffers, which then names the culprit.
    bad_arrays = [
        [[("predict", np.array([0.0, np.nan, 0.0]))], []],
        [[], [("lidar", np.array([[1.0, np.inf]]), None)]],
        [[], [("lidar", np.array([[1.0, 0.0]]), np.array([np.nan]))]],
        [[("camera", np.array([0.1, np.nan]))], []],
        [[("camera", np.array([0.1]), np.array([0.0, np.nan, 0.0]))], []],
    ]
    for calls, name in zip(
        bad_arrays, ["odometry", "points", "null_bearings", "bearings", "sensor_pose"], strict=True
    ):
        with pytest.raises(ValueError, match=name):
            bank.apply(calls)
    with pytest.raises(ValueError, match="sensor_pose"):
        bank.apply([[], [("lidar", [[1.0, 0.0]], None, [0.0, np.inf, 0.0])]])
    assert_unchanged(bank, before)
    for bad in (-1, 2, 0.5):
        with pytest.raises(ValueError, match="robot"):
            bank.table(bad)
        with pytest.raises(ValueError, match="robot"):
            bank.estimate(bad)
    with pytest.raises(ValueError, match="same config"):
        PHDBank.from_filters([RobotCentricPHD(), RobotCentricPHD(mode="lidar-only")])


def test_greedy_merge_ranks_tiny_weights_by_weight():
    """Component 2 is in the gates of 0 and 1; it must join the heavier, 1, even when all
    weights are far below 1e-16 (where ``w + 1`` rounds to 1 and loses the order)."""
    from localization.reducer import greedy_clusters

    for scale in (1.0, 1e-28):
        weights = np.array([1.0, 3.0, 2.0]) * scale
        close = np.array([[True, False, True], [False, True, True], [False, False, True]])
        np.testing.assert_array_equal(greedy_clusters(close, weights), [0, 1, 1])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bank_matches_with_the_simulators_sharp_bearings(seed):
    """SIMULATOR_PHD as the env runs it (ray births, Bernoulli missed term, 0.46 deg bearing
    noise, the cap), fed bearings with that noise."""
    # 0.46 deg bearings on 10-sigma-wide priors amplify summation-order round-off (the
    # engines sum the Gauss-Hermite terms of the missed copies in different orders): 2e-10.
    filters, bank = run_both(SIMULATOR_PHD, seed, bearing_std=np.radians(0.46), atol=1e-9)
    assert sum(len(f) for f in filters) > 0
