"""Every localizer family keeps the bound on total weight and cardinality that it documents
(``docs/concepts/localizers.md``, "Bounds on weight and cardinality"), checked after every filter
call
of adversarial measurement streams: many detections, clutter bursts, repeated identical
detections and bearings, empty scans and frames, far detections, lidar scans with no time
update between them, and a long mixed run.

Each feed carries one kind of record for every robot (an odometry sample, a lidar scan or a
camera frame), so one ``Localizer.step`` is one filter call per robot and the bound of that call
is checked on its own. The bounds are recomputed here from the documented formulas, with the
detection probabilities of :class:`localization.detection.DetectionModel` on the prior.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization import PHDConfig
from localization.detection import DetectionModel, inverse_sigmoid
from localization.feed import SwarmFeed
from localization.mixture import ROW_PXX, ROW_PYY, ROW_W
from localization.registry import LOCALIZERS, make_localizer, oracle_range_bearing
from swarm_core.records import (
    Broadcast,
    CameraRecord,
    LidarRecord,
    OdometryRecord,
    RobotMeasurements,
)
from swarm_core.world import GroundTruth
from swarm_env.config import SIMULATOR_PHD

R = 3  # robots: observer 0 and two teammates (each robot is also an observer)
#: Absolute slack on a bound: the merge's 1e-150 weight floor, and the banks' and this test's
#: detection probabilities differing in the last bits.
TOL = 1e-9

#: True world poses; only the oracle baselines (ukf, pf) read them.
POSES = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.3], [-0.8, 1.2, -2.0]])


def _truth() -> GroundTruth:
    rel = np.zeros((R, R, 2))
    for i in range(R):
        c, s = math.cos(POSES[i, 2]), math.sin(POSES[i, 2])
        d = POSES[:, :2] - POSES[i, :2]
        rel[i] = np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))
    return GroundTruth(POSES.copy(), rel)


TRUTH = _truth()

# ---------------------------------------------------------------------- adversarial streams
_NO = np.zeros(0)
_NO2 = np.zeros((0, 2))


def _lidar(t: float, points: np.ndarray, nulls: np.ndarray = _NO) -> RobotMeasurements:
    rec = LidarRecord(t, _NO, _NO, _NO, np.asarray(points, float).reshape(-1, 2), nulls)
    return RobotMeasurements([], [rec], [])


def _camera(t: float, bearings: np.ndarray) -> RobotMeasurements:
    return RobotMeasurements([], [], [CameraRecord(t, np.asarray(bearings, float))])


def _odometry(t: float, delta: np.ndarray) -> RobotMeasurements:
    return RobotMeasurements([OdometryRecord(t, np.asarray(delta, float), np.zeros(2))], [], [])


def _event(kind: str, rng: np.random.Generator, r: int, t: float) -> RobotMeasurements:
    """Robot ``r``'s record of one adversarial kind."""
    mates = TRUTH.relative_xy[r][np.arange(R) != r]
    if kind == "predict":
        return _odometry(t, rng.normal(0.0, [0.02, 0.005, 0.05]))
    if kind == "still":
        return _odometry(t, np.zeros(3))
    if kind == "teammates":  # each teammate seen, with lidar noise
        return _lidar(t, mates + rng.normal(0.0, 0.03, mates.shape))
    if kind == "many":  # 200 detections inside the lidar's range
        rad, ang = 2.5 * np.sqrt(rng.random(200)), rng.uniform(-np.pi, np.pi, 200)
        return _lidar(t, np.column_stack((rad * np.cos(ang), rad * np.sin(ang))))
    if kind == "burst":  # 400 clutter points far and near, plus 100 null returns
        pts = np.vstack((rng.uniform(-10, 10, (300, 2)), rng.uniform(-1.5, 1.5, (100, 2))))
        return _lidar(t, pts, rng.uniform(-np.pi, np.pi, 100))
    if kind == "repeated":  # one detection reported 60 times, on a teammate
        return _lidar(t, np.repeat(mates[:1], 60, axis=0))
    if kind == "repeated_fresh":  # 60 copies where nothing is tracked
        return _lidar(t, np.tile([[0.7, -0.9]], (60, 1)))
    if kind == "far":  # finite and inside MAX_INPUT_MAGNITUDE, nowhere near anything
        return _lidar(t, rng.uniform(-9e3, 9e3, (20, 2)))
    if kind == "empty_scan":
        return _lidar(t, np.zeros((0, 2)))
    if kind == "bearings":  # 300 clutter bearings
        return _camera(t, rng.uniform(-np.pi, np.pi, 300))
    if kind == "repeated_bearings":
        return _camera(t, np.full(80, math.atan2(mates[0, 1], mates[0, 0])))
    if kind == "empty_frame":
        return _camera(t, _NO)
    raise AssertionError(kind)


KINDS = [
    "predict",
    "still",
    "teammates",
    "many",
    "burst",
    "repeated",
    "repeated_fresh",
    "far",
    "empty_scan",
    "bearings",
    "repeated_bearings",
    "empty_frame",
]


def _script(seed: int, n: int) -> list[str]:
    """A warm-up on the teammates, every kind in turn (runs of it included: scans with no
    time update between them), then a long random mix."""
    rng = np.random.default_rng(seed)
    warm = ["teammates", "bearings", "predict"] * 6
    runs = [k for kind in KINDS for k in [kind] * 3 + ["predict"]]
    mix = list(rng.choice(KINDS, n))
    return warm + runs + mix


# ---------------------------------------------------------------------- per-family observations
def _tables(loc, r: int) -> dict:
    """Robot ``r``'s state as this test reads it: the table (``(6, N)``, weight row = PHD weight
    or existence) and, per family, the rest of its mass (PMB's Poisson, ID-PHD's full mixture)."""
    table, counts = loc.padded_tables()
    out = {"table": table[:, r, : counts[r]].copy()}
    if hasattr(loc, "poisson_table"):  # the compiled PMB bank
        out["poisson"] = loc.poisson_table(r)
    elif hasattr(loc, "filters") and hasattr(loc.filters[r], "poisson_table"):
        out["poisson"] = np.array(loc.filters[r].poisson_table)
    if loc.name == "id-phd":
        f = loc.filters[r]
        out["full_w"] = f.weights.copy()
        out["full_table"] = _xy_table(f.weights, f.means, f.covs)
        out["tags"] = f.tags.copy()
    if loc.has_identities:
        out["ids"] = set(loc.identities(r))
    return out


def _xy_table(w: np.ndarray, m: np.ndarray, p: np.ndarray) -> np.ndarray:
    t = np.zeros((6, w.shape[0]))
    t[0], t[1], t[2] = w, m[:, 0], m[:, 1]
    t[3], t[4], t[5] = p[:, 0, 0], p[:, 0, 1], p[:, 1, 1]
    return t


def _phd_config(loc, r: int) -> PHDConfig:
    cfg = loc.filters[r].config if hasattr(loc, "filters") else loc.config
    return getattr(cfg, "phd", cfg)


def _survival_max(cfg: PHDConfig) -> float:
    """Largest ``P_s`` of the config: eq. 10's ``1 / (offset + exp(..)) < 1 / offset``."""
    if cfg.prediction.survival_model == "constant":
        return cfg.prediction.survival_probability
    return 1.0 / cfg.prediction.survival_offset


def _births(cfg: PHDConfig, state: dict) -> float:
    """Weight the time update adds: one measurement birth per detection of the last scan."""
    return (
        cfg.births.measurement_weight * state["pending"]
        if cfg.births.model == "measurement"
        else 0.0
    )


def _missed_bound(w: np.ndarray, pd: np.ndarray, bernoulli: bool) -> np.ndarray:
    """Largest weight of each component's missed copy: ``(1 - P_d) w`` (PHD), or the
    Bernoulli copy ``w (1 - P_d) / (1 - r P_d + r Lambda) <= w (1 - P_d) / (1 - r P_d)``
    with ``r = w / max(1, ceil(w))`` (its ``Lambda >= 0`` only lowers it)."""
    miss = w * (1.0 - pd)
    if not bernoulli:
        return miss
    r = w / np.maximum(1.0, np.ceil(w))
    den = 1.0 - r * pd
    return np.where(miss > 0, miss / np.where(den > 0, den, 1.0), 0.0)


# ---------------------------------------------------------------------- the bounds
def _only_diffused(t0: np.ndarray, t1: np.ndarray) -> None:
    """A frame the filter does not use: weights and means unchanged; the variances may grow by
    the process noise accrued to its stamp (``time_update="measurement"``'s advance)."""
    np.testing.assert_array_equal(t1[:3], t0[:3])  # rows w, x, y
    assert np.all(t1[3] >= t0[3]) and np.all(t1[5] >= t0[5])  # Pxx, Pyy


def _lowest_expected_pd(cfg, table: np.ndarray, pd: np.ndarray) -> np.ndarray:
    """A lower bound of ``E[P_d]`` over each component (``lidar_missed_moments``): the range
    factor decreases with range, so its value 5 sigma out bounds the 9-node rule's average;
    sigma grows by the process noise the advance before the scan may add (two periods')."""
    r = np.hypot(table[1], table[2])
    u = table[1:3] / np.maximum(r, cfg.reduction.min_range_m)
    s2 = u[0] ** 2 * table[3] + 2 * u[0] * u[1] * table[4] + u[1] ** 2 * table[5]
    s_max = np.sqrt(np.maximum(s2, 0.0) + 2.0 * cfg.prediction.process_noise_std_m**2)
    f = inverse_sigmoid(r, cfg.lidar.pd_offset, cfg.lidar.pd_slope_per_m, cfg.lidar.pd_midpoint_m)
    f_far = inverse_sigmoid(
        r + 5.0 * s_max, cfg.lidar.pd_offset, cfg.lidar.pd_slope_per_m, cfg.lidar.pd_midpoint_m
    )
    g = np.divide(pd, f, out=np.zeros_like(f), where=f > 1e-12)
    return g * f_far


def _lowest_pd_after_advance(model: DetectionModel, table: np.ndarray, lid) -> np.ndarray:
    """A lower bound of ``P_d`` at the scan: the ``"visible-width"`` blind-sector factor
    averages over each component's bearing, which the advance before the scan may widen by
    up to two periods' process noise. The average is not monotone in the std (just outside a
    notch it dips, then rises), so the bound is the least over 33 widenings from none to two
    periods': the factor is smooth in the std and varies little between grid points."""
    nulls = lid.null_bearings_rad if lid.null_bearings_rad.size else None
    pd = model.lidar(table, nulls)
    if model.config.lidar.blind_sector_model == "visible-width":
        for extra in np.linspace(0.0, 2.0 * model.config.prediction.process_noise_std_m**2, 33)[
            1:
        ]:
            widened = table.copy()
            widened[ROW_PXX] += extra
            widened[ROW_PYY] += extra
            pd = np.minimum(pd, model.lidar(widened, nulls))
    return pd


def check_common(loc, after: dict, r: int) -> None:
    t = after["table"]
    assert np.all(np.isfinite(t)), f"{loc.name} robot {r}: non-finite table"
    assert np.all(t[ROW_W] >= 0.0), f"{loc.name} robot {r}: negative weight"


def check_gm_phd(loc, before, after, kind, rec, r, state) -> None:
    cfg = _phd_config(loc, r)
    t0, t1 = before["table"], after["table"]
    w0, w1 = t0[ROW_W].sum(), t1[ROW_W].sum()
    bern = cfg.missed_detection == "bernoulli"
    model = DetectionModel(cfg)
    assert t1.shape[1] <= cfg.reduction.max_components
    if rec.odometry:
        bound = _survival_max(cfg) * w0 + _births(cfg, state)
    elif rec.lidar:
        lid = rec.lidar[0]
        pd = _lowest_pd_after_advance(model, t0, lid)
        if cfg.lidar.missed_moments and cfg.lidar.pd_model == "seed":
            pd = _lowest_expected_pd(cfg, t0, pd)
        bound = _missed_bound(t0[ROW_W], pd, bern).sum() + lid.detections.shape[0]
        assert np.all(t1[ROW_W] >= cfg.reduction.prune_threshold)  # reduced
    else:
        k = rec.camera[0].bearings_rad.shape[0]
        if cfg.mode == "lidar-only":
            _only_diffused(t0, t1)
            return
        pc = model.camera(t0)
        ray = cfg.births.camera_weight * k if cfg.births.camera == "ray" else 0.0
        bound = _missed_bound(t0[ROW_W], pc, bern).sum() + k + ray
        assert np.all(t1[ROW_W] >= cfg.reduction.prune_threshold)
    assert w1 <= bound + TOL * (1 + bound), f"{loc.name} {kind} robot {r}: {w1} > {bound}"


def check_pmb(loc, before, after, kind, rec, r, state) -> None:
    fcfg = loc.filters[r].config if hasattr(loc, "filters") else loc.config
    cfg = fcfg.phd
    t0, t1 = before["table"], after["table"]
    p0, p1 = before["poisson"], after["poisson"]
    n0 = t0[ROW_W].sum() + p0[ROW_W].sum()
    n1 = t1[ROW_W].sum() + p1[ROW_W].sum()
    assert np.all(t1[ROW_W] <= 1.0), f"{loc.name}: existence above 1"
    assert t1.shape[1] <= fcfg.max_tracks
    assert p1.shape[1] <= cfg.reduction.max_components
    assert np.all(np.isfinite(p1)) and np.all(p1[ROW_W] >= 0.0)
    model = DetectionModel(cfg)
    moment = np.concatenate((t0, p0), axis=1)  # P_d is evaluated on the first moment
    if rec.odometry:
        bound = _survival_max(cfg) * n0 + _births(cfg, state)
    elif rec.lidar:
        lid = rec.lidar[0]
        pd = _lowest_pd_after_advance(model, moment, lid)
        bound = t0[ROW_W].sum() + (p0[ROW_W] * (1.0 - pd[t0.shape[1] :])).sum()
        bound += lid.detections.shape[0]
        assert np.all(t1[ROW_W] >= fcfg.recycle_threshold)  # recycled below it
    else:
        if cfg.mode == "lidar-only":
            _only_diffused(t0, t1)
            _only_diffused(p0, p1)
            return
        pc = model.camera(moment)
        bound = t0[ROW_W].sum() + (p0[ROW_W] * (1.0 - pc[t0.shape[1] :])).sum()
        bound += rec.camera[0].bearings_rad.shape[0]
        assert np.all(t1[ROW_W] >= fcfg.recycle_threshold)
    assert n1 <= bound + TOL * (1 + bound), f"{loc.name} {kind} robot {r}: {n1} > {bound}"


def check_id_phd(loc, before, after, kind, rec, r, state) -> None:
    cfg = loc.filters[r].config
    w0, w1 = before["full_w"].sum(), after["full_w"].sum()
    assert after["full_w"].shape[0] <= cfg.max_components
    assert after["table"][ROW_W].sum() <= w1 + TOL  # the teammates' part of the mixture
    teammates = set(range(R)) - {r}
    tags = set(after["tags"].tolist())
    assert tags <= teammates | {-1, -2}, f"robot {r}: tags {tags}"
    assert after["ids"] <= teammates
    if rec.odometry:
        bound = cfg.survival_probability * (w0 + cfg.birth_weight * state["pending"])
    elif rec.lidar:
        lid = rec.lidar[0]
        pd = _lowest_pd_after_advance(DetectionModel(cfg.detection), before["full_table"], lid)
        bound = (before["full_w"] * (1.0 - pd)).sum() + lid.detections.shape[0]
        assert np.all(after["full_w"] >= cfg.prune_threshold)
    else:  # camera frames are not used
        np.testing.assert_array_equal(after["full_w"], before["full_w"])
        return
    assert w1 <= bound + TOL * (1 + bound), f"id-phd {kind} robot {r}: {w1} > {bound}"


def check_oracle(loc, before, after, kind, rec, r, state) -> None:
    t1 = after["table"]
    teammates = set(range(R)) - {r}
    np.testing.assert_array_equal(t1[ROW_W], 1.0)  # one unit-weight component per teammate
    assert after["ids"] <= teammates and len(after["ids"]) == t1.shape[1]
    if rec.lidar:  # every newly identified teammate starts a track, nobody else
        seen = set(oracle_range_bearing(rec.lidar[0].detections, TRUTH, r))
        assert after["ids"] == before["ids"] | seen, f"{loc.name} robot {r}"
    elif rec.odometry:
        assert after["ids"] <= before["ids"]  # the UKF may drop a diverged track, never add
        if loc.name == "pf":
            assert after["ids"] == before["ids"]
    else:
        assert after["ids"] == before["ids"]


def check_mutual(loc, before, after, kind, rec, r, state) -> None:
    """The Stegagno 2012 thesis's methods: one existence-1 component per teammate it holds a belief
    about, and only real teammates (the feeds carry the others' broadcasts of the same adversarial
    scans: FastSLAM-MC holds both teammates by the end; the registrations find none in the
    clutter)."""
    t1 = after["table"]
    np.testing.assert_array_equal(t1[ROW_W], 1.0)
    assert after["ids"] <= set(range(R)) - {r} and len(after["ids"]) == t1.shape[1]


def _checker(name: str):
    if LOCALIZERS[name].needs_comms:
        return check_mutual
    if name.startswith("pmb"):
        return check_pmb
    if name.startswith("phd"):
        return check_gm_phd
    return {"id-phd": check_id_phd, "ukf": check_oracle, "pf": check_oracle}[name]


# ---------------------------------------------------------------------- the runs
#: Config variants: the simulator's (measurement births, Bernoulli missed copies), the
#: Perera 2021 study's ``PHDConfig()`` (fixed birth, PHD missed copies), and camera ray births with
#: a constant P_s.
CONFIGS = {
    "sim": SIMULATOR_PHD,
    "seed": PHDConfig.perera2021(),
    "ray": SIMULATOR_PHD.replace(
        births={"camera": "ray"},
        prediction={"survival_model": "constant"},
        reduction={"max_components": 24},
    ),
}
ALL = list(LOCALIZERS)
CASES = [(name, "sim") for name in ALL] + [
    (name, c)
    for name in ALL
    if name.startswith(("phd", "pmb")) and name.endswith(("-lc", "-lo"))
    for c in ("seed", "ray")
    if not (c == "ray" and name.startswith("pmb"))  # the PMB has no ray births
]


def _broadcasts(records: list[RobotMeasurements], t: float) -> list[tuple[Broadcast, ...]]:
    """What each robot hears from the others (the Stegagno 2012 thesis's radio): its still pose and
    the (adversarial) detections of its scan this step."""
    sent = [
        Broadcast(f"ugv_{j}", t, TRUTH.poses[j], rec.lidar[0].detections if rec.lidar else _NO2)
        for j, rec in enumerate(records)
    ]
    return [tuple(b for j, b in enumerate(sent) if j != r) for r in range(R)]


def _run(name: str, config: PHDConfig, n_mix: int, seed: int = 0) -> int:
    loc = make_localizer(name, R, config, seed=seed)
    check = _checker(name)
    rng = np.random.default_rng(seed + 1)
    pending = [0] * R  # detections of each robot's last lidar scan since its last time update
    calls = 0
    for k, kind in enumerate(_script(seed, n_mix)):
        t = 0.1 * (k + 1)
        records = [_event(kind, rng, r, t) for r in range(R)]
        before = [_tables(loc, r) for r in range(R)]
        comms = _broadcasts(records, t) if LOCALIZERS[name].needs_comms else ()
        loc.step(SwarmFeed(t, records, [()] * R, truth=TRUTH, comms=comms))
        for r in range(R):
            after = _tables(loc, r)
            check_common(loc, after, r)
            check(loc, before[r], after, kind, records[r], r, {"pending": pending[r]})
            calls += 1
            if records[r].odometry:
                pending[r] = 0
            elif records[r].lidar:
                pending[r] = records[r].lidar[0].detections.shape[0]
    return calls


@pytest.mark.parametrize(("name", "config"), CASES)
def test_localizer_keeps_its_documented_bound(name, config):
    # numpy families are slower; the Stegagno 2012 thesis's methods (FastSLAM: an EKF per landmark
    # per particle) slower still
    slow = name == "id-phd" or LOCALIZERS[name].needs_comms
    n_mix = 30 if slow else 40 if "reference" in name else 150
    assert _run(name, CONFIGS[config], n_mix) >= 90 * R


def test_every_registered_family_is_covered():
    assert {name for name, _ in CASES} == set(LOCALIZERS)


def test_gm_phd_bound_is_attained_and_checked():
    """The bound is not loose and the check is not vacuous: 60 copies of one detection on 60
    pending births of weight 0.25 (15 in all) leave a weight of almost 60 (each detection's
    normalised share approaches 1, the missed copies keep little), and 5 more breaks the check."""
    loc = make_localizer("phd-reference-lc", 1, SIMULATOR_PHD)
    rec = _lidar(0.1, np.tile([[0.7, -0.9]], (60, 1)))
    loc.step(SwarmFeed(0.1, [rec], [()]))
    loc.step(SwarmFeed(0.2, [_odometry(0.2, np.zeros(3))], [()]))  # 60 births join
    before = _tables(loc, 0)
    loc.step(SwarmFeed(0.3, [rec], [()]))
    after = _tables(loc, 0)
    assert before["table"][ROW_W].sum() == pytest.approx(15.0)
    assert after["table"][ROW_W].sum() > 0.9 * 60
    check_gm_phd(loc, before, after, "repeated", rec, 0, {"pending": 60})
    after["table"][ROW_W, 0] += 5.0
    with pytest.raises(AssertionError):
        check_gm_phd(loc, before, after, "repeated", rec, 0, {"pending": 60})
