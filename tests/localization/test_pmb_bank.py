"""PMBBank: every robot must end each batch with what its own RobotCentricPMB holds (1e-10)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from localization import GaussianMixture, PHDConfig
from localization.frames import bearings_to_filter_frame, points_to_filter_frame
from localization.pmb import PMBBank, PMBConfig, RobotCentricPMB
from swarm_env.config import SIMULATOR_PHD

R = 8


def assert_same(filters, bank, where):
    for r, f in enumerate(filters):
        for name, a, b in (
            ("tracks", np.asarray(f.table), bank.table(r)),
            ("poisson", np.asarray(f.poisson_table), bank.poisson_table(r)),
            ("pending", f.__getstate__()["pending_births"], bank.pending_births(r)),
        ):
            assert a.shape == b.shape, f"{where}: robot {r} {name} {b.shape} != {a.shape}"
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-10, err_msg=f"{where} r{r} {name}")


def random_call_lists(rng, steps, with_poses=False):
    """Per-robot call lists for ``steps`` batches: clutter, empty sets, null bearings, poses."""
    targets = rng.uniform(-2.5, 2.5, size=(R, 8, 2))
    for _ in range(steps):
        calls = [[] for _ in range(R)]
        for r in range(R):
            for _ in range(int(rng.integers(0, 4))):
                kind = rng.choice(["predict", "lidar", "camera"], p=[0.3, 0.3, 0.4])
                pose = (
                    rng.normal(0, [0.03, 0.01, 0.1]) if with_poses and rng.random() < 0.7 else None
                )
                targets[r] += rng.normal(0, 0.02, (8, 2))
                if kind == "predict":
                    calls[r].append(("predict", rng.normal(0.0, [0.03, 0.01, 0.05])))
                elif kind == "lidar":
                    m = int(rng.integers(0, 6))
                    pts = targets[r, rng.choice(8, size=m, replace=False)]
                    pts = pts + rng.normal(0.0, 0.05, (m, 2))
                    if rng.random() < 0.3:
                        pts = np.concatenate([pts, rng.uniform(-2.0, 2.0, (2, 2))])
                    nb = (
                        None
                        if rng.random() < 0.5
                        else rng.uniform(-np.pi, np.pi, rng.integers(0, 4))
                    )
                    calls[r].append(("lidar", pts, nb, pose))
                else:
                    tg = targets[r, rng.integers(0, 8, int(rng.integers(0, 12)))]
                    brg = np.arctan2(tg[:, 1], tg[:, 0]) + rng.normal(0.0, 0.08, len(tg))
                    calls[r].append(("camera", brg, pose))
        yield calls


def run_reference(f, seq):
    for c in seq:
        if c[0] == "predict":
            f.predict(c[1])
        elif c[0] == "lidar":
            f.update_lidar(c[1], c[2], sensor_pose=c[3])
        else:
            f.update_camera(c[1], sensor_pose=c[2])


def run_both(config, seed, steps=30, with_poses=False):
    filters = [RobotCentricPMB(config) for _ in range(R)]
    bank = PMBBank(config, R)
    rng = np.random.default_rng(seed)
    for step, calls in enumerate(random_call_lists(rng, steps, with_poses)):
        for f, seq in zip(filters, calls, strict=True):
            run_reference(f, seq)
        bank.apply(calls)
        assert_same(filters, bank, f"seed {seed} step {step}")
    return filters, bank


def phd(**kw):
    return PHDConfig.perera2021().replace(**kw)


CONFIGS = {
    "lc-fixed": PMBConfig(phd=phd(births={"model": "fixed"})),
    "lc-measurement": PMBConfig(phd=phd(births={"model": "measurement"})),
    "lo-fixed": PMBConfig(phd=phd(mode="lidar-only", births={"model": "fixed"})),
    "lo-measurement": PMBConfig(phd=phd(mode="lidar-only", births={"model": "measurement"})),
    "seed-defaults": PMBConfig(),
    "simulator": PMBConfig(phd=SIMULATOR_PHD),
    "constant-models": PMBConfig(
        phd=phd(
            lidar={"pd_model": "constant", "occlusion_min_separation_m": 0.0},
            prediction={"survival_model": "constant"},
            births={"model": "measurement"},
        )
    ),
    "visible-width": PMBConfig(
        phd=phd(
            births={"model": "measurement"},
            lidar={
                "blind_sector_model": "visible-width",
                "blind_sector_centers_deg": (30.0, 150.0, -90.0),
                "blind_sector_widths_deg": (40.0, 60.0, 50.0),
            },
        )
    ),
    "track-cap": PMBConfig(
        phd=phd(births={"model": "measurement"}, reduction={"max_components": 5}), max_tracks=3
    ),
    "range-noise": PMBConfig(
        phd=phd(
            births={"model": "measurement"},
            camera={"noise_std_deg": 2.0, "noise_width_fraction": 0.5},
        )
    ),
    "no-clutter": PMBConfig(
        phd=phd(
            births={"model": "measurement"},
            lidar={"clutter_intensity": 0.0},
            camera={"clutter_intensity": 0.0},
        )
    ),
    "camera-rays-to-poisson": PMBConfig(phd=phd(births={"model": "measurement", "camera": "ray"})),
    "camera-rays-simulator": PMBConfig(
        phd=SIMULATOR_PHD.replace(births={"camera": "ray", "camera_max_range_m": 4.7})
    ),
    "one-bp-sweep-wide-gate": PMBConfig(
        phd=phd(births={"model": "measurement"}),
        bp_max_iterations=1,
        gate_sigma=10.0,
        recycle_threshold=0.3,
    ),
    "narrow-gate-low-recycle": PMBConfig(
        phd=phd(births={"model": "measurement"}, reduction={"prune_threshold": 1e-8}),
        gate_sigma=2.0,
        recycle_threshold=1e-3,
    ),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_bank_matches_reference_filters(name):
    filters, bank = run_both(CONFIGS[name], seed=0)
    assert max(len(f) for f in filters) > 0
    if name == "track-cap":
        assert max(len(f) for f in filters) == 3


def test_camera_rays_stay_poisson_until_the_lidar_confirms():
    """With camera_birth="ray" a bearing starts no track: its ray joins the Poisson part
    (weight camera_birth_weight over the camera's reach), repeated bearings keep it there, and
    a lidar detection on the ray starts a track there (with the Poisson mass as its prior)."""
    cfg = PMBConfig(
        phd=phd(
            births={"model": "measurement", "camera": "ray"}, lidar={"clutter_intensity": 0.05}
        )
    )
    f = RobotCentricPMB(cfg)
    bearing = 0.6
    f.update_camera(np.array([bearing]))
    poisson = np.asarray(f.poisson_table)
    assert len(f) == 0
    assert poisson[0].sum() == pytest.approx(cfg.phd.births.camera_weight, rel=1e-6)
    angles = np.arctan2(poisson[2], poisson[1])
    assert np.allclose(angles, bearing, atol=1e-9)  # all of it on the ray
    for _ in range(5):
        f.update_camera(np.array([bearing]))
    assert len(f) == 0  # bearings alone never start a track
    target = 1.0 * np.array([np.cos(bearing), np.sin(bearing)])  # P_d(1 m) = 0.95 (eq. 19)
    f.update_lidar(target[None, :])
    means, existences = f.estimate(threshold=0.5)
    assert means.shape == (1, 2) and np.linalg.norm(means[0] - target) < 0.1


def test_bank_matches_with_sensor_poses_camera_rays():
    run_both(CONFIGS["camera-rays-simulator"], seed=2, with_poses=True)


def test_bank_matches_with_sensor_poses():
    run_both(CONFIGS["lc-measurement"], seed=1, with_poses=True)


def test_sensor_pose_equals_moved_measurements():
    rng = np.random.default_rng(2)
    calls = next(random_call_lists(rng, 1, with_poses=True))
    bank = PMBBank(CONFIGS["lc-fixed"], R)
    bank.apply(calls)
    for r, seq in enumerate(calls):
        f = RobotCentricPMB(CONFIGS["lc-fixed"])
        for c in seq:
            if c[0] == "predict":
                f.predict(c[1])
            elif c[0] == "lidar":
                pts, nulls, pose = c[1:]
                if pose is not None:
                    pts = points_to_filter_frame(pts, pose)
                    nulls = None if nulls is None else bearings_to_filter_frame(nulls, pose)
                f.update_lidar(pts, nulls)
            else:
                brg, pose = c[1:]
                f.update_camera(brg if pose is None else bearings_to_filter_frame(brg, pose))
        np.testing.assert_allclose(bank.table(r), f.table, atol=1e-10)


def test_views_tables_round_trip_and_pickle():
    filters, bank = run_both(CONFIGS["lc-measurement"], seed=3, steps=15)
    table, counts = bank.padded_tables()
    assert (
        table.shape == (6, R, CONFIGS["lc-measurement"].max_tracks) and not table.flags.writeable
    )
    for r in range(R):
        n = counts[r]
        np.testing.assert_array_equal(table[:, r, :n], bank.table(r))
        assert (table[:, r, n:] == 0).all()
        view = bank.views[r]
        mix = view.mixture
        assert isinstance(mix, GaussianMixture) and view.mixture is mix and len(mix) == n
        np.testing.assert_allclose(mix.weights, filters[r].tracks.r, atol=1e-10)
        means, existences = view.estimate(0.3)
        ref_means, _ = filters[r].estimate(0.3)
        np.testing.assert_allclose(means, ref_means, atol=1e-10)
        assert existences.shape == (means.shape[0],) and np.all(existences >= 0.3)
        np.testing.assert_array_equal(view.table, bank.table(r))
    copy = pickle.loads(pickle.dumps(bank))
    assert_same(filters, copy, "pickle")
    assert_same(filters, PMBBank.from_filters(filters), "from_filters")
    assert_same([bank.to_filter(r) for r in range(R)], bank, "to_filter")
    # single-robot calls through a view equal the filter's
    view, f = bank.views[4], filters[4]
    view.predict([0.02, 0.0, 0.01])
    f.predict([0.02, 0.0, 0.01])
    view.update_lidar([[1.0, 0.5]], [0.3], [0.01, 0.0, 0.05])
    f.update_lidar([[1.0, 0.5]], [0.3], sensor_pose=[0.01, 0.0, 0.05])
    view.update_camera([0.4, -1.0])
    f.update_camera([0.4, -1.0])
    np.testing.assert_allclose(bank.table(4), f.table, atol=1e-10)
    np.testing.assert_allclose(bank.poisson_table(4), f.poisson_table, atol=1e-10)
    bank.views[2].reset()
    assert len(bank.views[2]) == 0 and bank.poisson_table(2).shape == (6, 0)
    bank.reset()
    assert bank.counts.sum() == 0


def test_batched_methods_equal_apply():
    cfg = CONFIGS["lc-measurement"]
    a, b = PMBBank(cfg, R), PMBBank(cfg, R)
    robots = np.array([0, 3, 5])
    pts = [np.array([[1.0, 0.5]]), np.empty((0, 2)), np.array([[0.3, -1.0], [2.0, 0.1]])]
    a.update_lidar(robots, pts, [None, np.array([0.2]), None])
    a.predict(robots, np.full((3, 3), 0.01))
    a.update_lidar(robots, pts)
    a.update_camera(robots, [np.array([0.4]), np.array([]), np.array([-1.2, 0.05])])
    calls = [[] for _ in range(R)]
    for k, r in enumerate(robots):
        calls[r] += [
            ("lidar", pts[k], [None, np.array([0.2]), None][k]),
            ("predict", np.full(3, 0.01)),
            ("lidar", pts[k], None),
            ("camera", [np.array([0.4]), np.array([]), np.array([-1.2, 0.05])][k]),
        ]
    b.apply(calls)
    assert snapshot(a) == snapshot(b) and a.counts.sum() > 0
    with pytest.raises(ValueError, match="distinct"):
        a.predict([1, 1], np.zeros((2, 3)))
    with pytest.raises(ValueError, match="odometry"):
        a.predict([1, 2], np.zeros((2, 2)))
    with pytest.raises(ValueError, match="points"):
        a.update_lidar([1], [np.array([[np.nan, 0.0]])])
    with pytest.raises(ValueError, match="bearings"):
        a.update_camera([1, 2], [np.zeros(1)])
    assert snapshot(a) == snapshot(b)


def snapshot(bank):
    return pickle.dumps(bank.__getstate__())


def test_bad_input_raises_before_any_change():
    _, bank = run_both(CONFIGS["lc-measurement"], seed=4, steps=5)
    before = snapshot(bank)
    empty = [[] for _ in range(R - 1)]
    cases = [
        ([[("predict", np.array([0.0, np.nan, 0.0]))]] + empty, "odometry"),
        ([[("predict", [0.0, 0.0])]] + empty, "odometry"),
        ([[("lidar", np.array([[1.0, np.inf]]), None)]] + empty, "points"),
        ([[("lidar", [[1.0, 0.0]], np.array([np.nan]))]] + empty, "null_bearings"),
        ([[("camera", np.array([0.1, np.nan]))]] + empty, "bearings"),
        ([[("camera", [0.1], [0.0, 0.0])]] + empty, "sensor_pose"),
        ([[("lidar", [[1.0, 0.0]], None, [0.0, np.inf, 0.0])]] + empty, "sensor_pose"),
        ([[("teleport", 1.0)]] + empty, "invalid call"),
        ([None] + empty, r"calls\[0\]"),
        (empty, "one list per robot"),
        # a good call before the bad one must not run either
        ([[("predict", np.zeros(3)), ("camera", np.array([np.inf]))]] + empty, "bearings"),
    ]
    for calls, name in cases:
        with pytest.raises(ValueError, match=name):
            bank.apply(calls)
        assert snapshot(bank) == before
    with pytest.raises(ValueError, match="n_robots"):
        PMBBank(PMBConfig(), 0)
    with pytest.raises(ValueError, match="config"):
        PMBBank("nope", 2)
    for bad in (-1, R, 0.5):
        with pytest.raises(ValueError, match="robot"):
            bank.table(bad)


def test_one_view_class_steps_and_loads_like_the_reference():
    """The banks' one view class: a PMB robot stepped through its view (advance, scan profile)
    and loaded with ``set_mixture`` holds what its RobotCentricPMB holds."""
    from localization import PHDBank
    from localization.bank import BankView
    from localization.scan_memory import N_BINS

    cfg = PMBConfig(phd=SIMULATOR_PHD)
    bank, f = PMBBank(cfg, 3), RobotCentricPMB(cfg)
    view = bank.views[1]
    assert type(view) is BankView and type(PHDBank(PHDConfig.perera2021(), 2).views[0]) is BankView
    profile = np.full(N_BINS, 2.5)
    for target in (view, f):
        target.advance(0.1)
        target.update_lidar([[1.0, 0.5], [0.3, -0.8]], None, [0.02, 0.0, 0.01], profile)
        target.advance(0.2)
        target.update_camera([0.45, -1.2])
    assert_same([f], PMBBank.from_filters([view.to_filter()]), "view")
    np.testing.assert_allclose(bank.table(1), f.table, atol=1e-10)
    np.testing.assert_allclose(bank.poisson_table(1), f.poisson_table, atol=1e-10)
    tracks = GaussianMixture(np.array([0.9]), np.array([[1.0, 2.0]]), 0.04 * np.eye(2)[None])
    view.set_mixture(tracks)
    f.set_state(tracks)
    np.testing.assert_array_equal(bank.table(1), f.table)
    assert bank.poisson_table(1).shape == (6, 0) and view.mixture.weights.tolist() == [0.9]
    assert repr(view).startswith("BankView(PMBBank, robot=1, components=1")
    with pytest.raises(ValueError, match="tracks weights out of range"):
        view.set_mixture(GaussianMixture(np.array([1.5]), np.zeros((1, 2)), np.eye(2)[None]))
    np.testing.assert_array_equal(bank.table(1), f.table)  # unchanged
