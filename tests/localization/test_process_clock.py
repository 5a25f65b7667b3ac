"""Process noise added up to each measurement's stamp (``PHDConfig.prediction.time_update``).

Hand-derived: with a random walk of variance ``q`` per ``T`` seconds, a stamp ``dt`` after the
previous one adds ``q dt / T`` to every covariance, a predict after stamps adds nothing more, and
an unstamped predict adds all of ``q`` (Perera 2021). The compiled banks match the references on
random stamped call sequences.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from localization import PHDBank, PHDConfig, RobotCentricPHD
from localization.feed import localizer_calls
from localization.mixture import GaussianMixture
from localization.pmb import PMBBank, PMBConfig, RobotCentricPMB
from localization.registry import run_calls
from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements
from tests.localization.test_bank import assert_same as assert_same_phd
from tests.localization.test_pmb_bank import R, random_call_lists
from tests.localization.test_pmb_bank import assert_same as assert_same_pmb

MEASUREMENT = PHDConfig.perera2021().replace(
    prediction={"time_update": "measurement"}, births={"model": "measurement"}
)
Q = MEASUREMENT.prediction.process_noise_std_m**2
T = MEASUREMENT.prediction.process_noise_interval_s


def one_component(f, p0=0.01):
    mix = GaussianMixture(np.array([0.9]), np.array([[1.0, 0.5]]), np.array([p0 * np.eye(2)]))
    if isinstance(f, RobotCentricPMB):
        f.set_state(mix)
    else:
        f.set_mixture(mix)


def pxx(f):
    return float(f.table[3, 0])


@pytest.mark.parametrize("family", ["phd", "pmb"])
def test_noise_accrues_between_stamps_and_sums_to_q_per_period(family):
    f = (
        RobotCentricPHD(MEASUREMENT)
        if family == "phd"
        else RobotCentricPMB(PMBConfig(MEASUREMENT))
    )
    one_component(f)
    f.advance(10.0)  # first stamp: starts the clock, adds nothing
    assert pxx(f) == pytest.approx(0.01, abs=1e-15)
    f.advance(10.025)
    assert pxx(f) == pytest.approx(0.01 + Q * 0.25, abs=1e-15)
    f.advance(10.02)  # out of order: nothing, and the clock does not go back
    f.advance(10.1)
    assert pxx(f) == pytest.approx(0.01 + Q, abs=1e-15)
    f.predict(np.zeros(3))  # the period's noise is already in
    assert pxx(f) == pytest.approx(0.01 + Q, abs=1e-15)
    f.predict(np.zeros(3))  # no stamp since the last predict: Perera 2021's whole Q
    assert pxx(f) == pytest.approx(0.01 + 2 * Q, abs=1e-15)
    assert f.table[4, 0] == 0.0  # isotropic: no cross term


def test_odometry_time_update_ignores_stamps():
    f = RobotCentricPHD(PHDConfig.perera2021())
    one_component(f)
    for t in (0.0, 0.03, 0.07, 0.1):
        f.advance(t)
    assert pxx(f) == pytest.approx(0.01, abs=1e-15)
    f.predict(np.zeros(3))
    assert pxx(f) == pytest.approx(0.01 + Q, abs=1e-15)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "1.0", None, True, 1j])
def test_bad_stamp_is_refused_before_any_change(bad):
    f = RobotCentricPHD(MEASUREMENT)
    one_component(f)
    before = f.table.copy()
    with pytest.raises(ValueError, match="stamp_s"):
        f.advance(bad)
    np.testing.assert_array_equal(f.table, before)
    bank = PHDBank(MEASUREMENT, 2)
    bank.load_filter(0, f)
    with pytest.raises(ValueError, match=r"calls\[1\].*stamp_s"):
        bank.apply([[("advance", 1.0)], [("advance", bad)]])
    np.testing.assert_array_equal(bank.table(0), before)


def stamped(call_lists, rng, clock):
    """Each call after an advance to a later stamp (sometimes a stale one), ROS-time sized."""
    for calls in call_lists:
        out = []
        for r, seq in enumerate(calls):
            robot = []
            for c in seq:
                clock[r] += rng.uniform(0.0, 0.06)
                late = rng.random() < 0.1
                robot.append(("advance", clock[r] - (0.05 if late else 0.0)))
                robot.append(c)
            out.append(robot)
        yield out


@pytest.mark.parametrize("family", ["phd", "pmb"])
def test_banks_match_references_on_stamped_calls(family):
    rng = np.random.default_rng(11)
    clock = np.full(R, 1.7e9)  # ROS time: stamps far beyond the 1e4 input bound
    if family == "phd":
        refs = [RobotCentricPHD(MEASUREMENT) for _ in range(R)]
        bank, same = PHDBank(MEASUREMENT, R), assert_same_phd
    else:
        config = PMBConfig(MEASUREMENT)
        refs = [RobotCentricPMB(config) for _ in range(R)]
        bank, same = PMBBank(config, R), assert_same_pmb
    for step, calls in enumerate(stamped(random_call_lists(rng, 25, with_poses=True), rng, clock)):
        for f, seq in zip(refs, calls, strict=True):
            run_calls(f, seq)
        bank.apply(calls)
        same(refs, bank, f"step {step}")
    # The clock travels with the state: to_filter, load_filter and pickling keep it.
    restored = pickle.loads(pickle.dumps(bank))
    twin = copy.deepcopy(refs[0])
    moved = bank.to_filter(0)
    for f in (twin, moved):
        f.advance(clock[0] + 0.05)
    restored.apply([[("advance", clock[0] + 0.05)]] + [[]] * (R - 1))
    np.testing.assert_allclose(moved.table, twin.table, atol=1e-10)
    np.testing.assert_allclose(restored.table(0), twin.table, atol=1e-10)
    # A reset forgets the clock (no stamp, not advanced), in the bank as in the reference.
    bank.reset([0])
    np.testing.assert_array_equal(bank.to_filter(0).__getstate__()["clock"], [np.nan, 0.0])
    refs[0].reset()
    np.testing.assert_array_equal(refs[0].__getstate__()["clock"], [np.nan, 0.0])


def test_feed_stamps_every_call_with_its_record():
    odo = OdometryRecord(0.1, np.array([0.01, 0.0, 0.02]), np.array([0.1, 0.2]))
    lidar = LidarRecord(
        0.08, np.zeros(3), np.zeros(3), np.zeros(3), np.array([[1.0, 0.0]]), np.zeros(0)
    )
    cams = [CameraRecord(t, np.array([0.3])) for t in (0.033, 0.066, 0.1)]
    calls = localizer_calls(RobotMeasurements([odo], [lidar], cams))
    kinds = [(c[0], c[1]) if c[0] == "advance" else c[0] for c in calls]
    assert kinds == [
        ("advance", 0.033), "camera",
        ("advance", 0.066), "camera",
        ("advance", 0.08), "lidar",
        ("advance", 0.1), "predict",  # odometry first on equal stamps
        ("advance", 0.1), "camera",
    ]  # fmt: skip
    no_camera = localizer_calls(RobotMeasurements([odo], [lidar], cams), ("camera",))
    assert [c[0] for c in no_camera] == ["advance", "lidar", "advance", "predict"]


@pytest.mark.parametrize("family", ["phd", "pmb"])
def test_a_clock_that_jumps_back_restarts_and_the_predict_adds_q(family):
    """A ROS /clock restart (stamp 30 s behind): no noise from the jump, and the next predict
    adds the whole Q instead of none (which waiting for the old maximum would have given)."""
    f = (
        RobotCentricPHD(MEASUREMENT)
        if family == "phd"
        else RobotCentricPMB(PMBConfig(MEASUREMENT))
    )
    one_component(f)
    f.advance(100.0)
    f.advance(100.05)
    f.predict(np.zeros(3))
    p = pxx(f)
    f.advance(70.0)  # reset: restarts the clock here
    assert pxx(f) == pytest.approx(p, abs=1e-15)
    f.predict(np.zeros(3))
    assert pxx(f) == pytest.approx(p + Q, abs=1e-15)
    f.advance(70.05)  # and accrues from the new origin
    assert pxx(f) == pytest.approx(p + Q + 0.5 * Q, abs=1e-15)
    f.advance(70.04)  # a small step back: nothing, the clock stays
    f.advance(70.1)
    assert pxx(f) == pytest.approx(p + 2 * Q, abs=1e-15)


def test_bank_clock_restarts_like_the_reference():
    ref = RobotCentricPHD(MEASUREMENT)
    one_component(ref)
    bank = PHDBank(MEASUREMENT, 1)
    bank.load_filter(0, ref)
    calls = [("advance", 100.0), ("advance", 100.05), ("predict", np.zeros(3)),
             ("advance", 70.0), ("predict", np.zeros(3)), ("advance", 70.05)]  # fmt: skip
    run_calls(ref, calls)
    bank.apply([calls])
    np.testing.assert_allclose(bank.table(0), ref.table, atol=1e-15)
