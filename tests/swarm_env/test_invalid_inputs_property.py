"""Property tests (hypothesis) of the one validation layer: generated invalid configs, actions
and measurement sets give a ``ValueError`` naming the field, agent or argument, raised before
any state changes; what is accepted runs.

The enumerated cases stay in ``test_bad_input.py`` (env) and
``tests/localization/test_hostile_measurements.py`` (anonymous filters' numeric values); here
hypothesis draws the field, the agent, the value class and the mix:

- configs: any field of any ``SwarmConfig`` sub-config (and the top-level fields) set to NaN,
  infinities, strings, bytes, ``None``, bools, complex numbers, lists, negatives, zeros, tiny,
  huge and ``10**400`` values. Either a ``ValueError`` naming the field, or an env that builds,
  resets and steps with finite observations.
- actions: NaN, inf, strings, bytes, complex numbers, bools, wrong shapes, ``None``, object
  arrays, ``10**400``, torch tensors that require grad, unknown agents of mixed key types and
  missing agents, on one or several agents at once. The env stays bit-identical to a twin that
  never saw them: ``env.state()``, the generator's state, every robot's filter table, and the
  next valid step.
- measurement sets: every localizer family, the bad value in a detection, a null bearing, a
  bearing, an odometry increment, an odometry velocity (motion compensation) or a stamp.
"""

from __future__ import annotations

import dataclasses
import reprlib
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from localization.feed import SwarmFeed
from localization.registry import LOCALIZERS, make_localizer
from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements
from swarm_core.world import GroundTruth
from swarm_env import parallel_env
from swarm_env.config import SIMULATOR_PHD, make_config

PRESET = "lab-3m-4"
FAST = settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


# ---------------------------------------------------------------------- configs
def _config_fields() -> list[tuple[str, ...]]:
    """Every leaf field of the preset's config, as its path (``("phd", "lidar", "range_m")``)."""

    def leaves(obj: object, path: tuple[str, ...]) -> list[tuple[str, ...]]:
        if not dataclasses.is_dataclass(obj):
            return [path]
        return [
            p
            for f in dataclasses.fields(obj)
            for p in leaves(getattr(obj, f.name), path + (f.name,))
        ]

    return leaves(make_config(PRESET), ())


def _nested(path: tuple[str, ...], value: object) -> dict:
    """``{path[0]: {path[1]: ... value}}``."""
    out: object = value
    for name in reversed(path):
        out = {name: out}
    return out  # type: ignore[return-value]


CONFIG_FIELDS = _config_fields()

#: Values no config field takes: the property test samples them, the sweep tries them all.
SWEEP_VALUES = [
    float("nan"),
    np.float64("nan"),
    float("inf"),
    -float("inf"),
    "1",
    "",
    b"1",
    None,
    True,
    False,
    np.bool_(True),
    1 + 1j,
    [1.0],
    (),
    {},
    -1,
    -1.0,
    -1e300,
    0,
    0.0,
    1e-300,
    1e300,
    10**18,
    10**400,
    -(10**400),
    np.int64(2**62),
]

hostile_values = st.one_of(
    st.sampled_from(SWEEP_VALUES),
    st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=-1e-6),
)


def _names_the_field(message: str, path: tuple[str, ...]) -> bool:
    return path[-1] in message


def _run_briefly(overrides: dict) -> None:
    """An accepted config must build, reset and step with finite observations."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = parallel_env(PRESET, **overrides)
        try:
            env.reset(seed=0)
            for _ in range(2):
                obs, *_ = env.step({a: np.array([0.2, 0.5]) for a in env.agents})
            for agent, o in obs.items():
                assert np.all(np.isfinite(np.asarray(o, dtype=float))), (overrides, agent)
        finally:
            env.close()


@FAST
@given(field=st.sampled_from(CONFIG_FIELDS), value=hostile_values)
def test_any_config_field_refuses_hostile_values_naming_it_or_runs(field, value):
    if field[0] == "phd" and _nested(field[1:], value) in PHD_GAPS:
        return  # known, open: test_phd_config_refuses_implausible_values_naming_the_field
    overrides = _nested(field, value)
    try:
        make_config(PRESET, **overrides)
    except ValueError as exc:
        message = str(exc)
        assert _names_the_field(message, field), (overrides, message)
        # ...and the value (repr, str or the shortened repr of a huge int)
        shown = {repr(value), str(value), reprlib.repr(value), f"{value}"}
        assert any(s in message for s in shown) or isinstance(value, (list, tuple, dict)), (
            overrides,
            message,
        )
        return
    _run_briefly(overrides)


@pytest.mark.parametrize(
    "overrides, match",
    [
        # Found by the property test above (each was accepted, or failed without the field).
        ({"n_robots": 10**400}, "n_robots is too large"),  # was OverflowError
        ({"phd": {"births": {"weight": 10**400}}}, r"births\.weight is too large"),
        ({"lidar_features": {"foreground_only": None}}, "foreground_only must be True or False"),
        ({"localize": 1}, "localize must be True or False"),
        ({"arena": {"box_size_range_m": 0.5}}, "box_size_range_m must be a tuple"),  # TypeError
        ({"arena": {"box_size_range_m": (0.3, 9.0)}}, "box_size_range_m must fit the arena"),
        ({"arena": {"decoy_post_radius_m": 1e300}}, "decoy_post_radius_m must be <"),  # at reset
        ({"arena": {"width_m": 1e300}}, "arena.width_m"),
        ({"robot": {"axle_width_m": 1e300}}, "axle_width_m must be <= 2"),  # step() raised
        ({"robot": {"axle_width_m": 1e-300}}, "axle_width_m must be >= 0.01"),
        ({"robot": {"length_m": 1e300}}, "length_m must be <= 2"),  # was OverflowError
        ({"camera": {"range_min_m": 0.0}}, "range_min_m must be > 0"),  # > 20 s for 3 steps
        ({"camera": {"bearing_noise_std_deg": 1e300}}, "bearing_noise_std_deg"),  # step() raised
        ({"localizer": ["phd"]}, "localizer"),  # was TypeError: unhashable
        ({"spawn_clearance_m": 1e300}, "spawn_clearance_m"),  # was OverflowError
    ],
)
def test_config_gaps_found_by_the_property_test(overrides, match):
    with pytest.raises(ValueError, match=match):
        make_config(PRESET, **overrides)


PHD_GAPS = [
    # PHDConfig once accepted these; the env then failed with an error that did not name the
    # field (OverflowError, ZeroDivisionError, numba's SystemError). Now refused by its
    # plausibility bounds and the max_components cost guard.
    {"prediction": {"process_noise_std_m": 1e300}},
    {"births": {"std_m": 1e300}},
    {"lidar": {"noise_std_m": 1e300}},
    {"camera": {"noise_std_deg": 1e300}},
    {"lidar": {"occlusion_std_deg": 1e300}},
    {"lidar": {"occlusion_std_deg": 1e-300}},
    {"lidar": {"interference_std_deg": 1e-300}},
    {"births": {"measurement_cov_scale": 1e300}},  # numba SystemError inside apply_calls
    {"camera": {"noise_width_fraction": 1e300}},  # numba SystemError
    {
        "prediction": {"process_noise_interval_s": 1e-300}
    },  # numba SystemError (Q / interval overflows)
    {"reduction": {"max_components": 10**18}},  # "array is too big" from numpy, no field named
]


@pytest.mark.parametrize("phd", PHD_GAPS)
def test_phd_config_refuses_implausible_values_naming_the_field(phd):
    ((component, inner),) = phd.items()
    name = f"{component}.{next(iter(inner))}"
    try:
        make_config(PRESET, phd=phd)
    except ValueError as exc:
        assert name in str(exc)
        return
    with pytest.raises(ValueError, match=name):
        _run_briefly({"phd": phd})


# ---------------------------------------------------------------------- actions
class _Twins:
    """Two envs with the same seed: ``a`` gets the invalid actions, ``b`` never does."""

    def __init__(self) -> None:
        self.a = parallel_env(PRESET)
        self.b = parallel_env(PRESET)
        self.reset()

    def reset(self) -> None:
        self.a.reset(seed=3)
        self.b.reset(seed=3)

    def snapshot(self, env) -> tuple:
        table, counts = env.localizer.padded_tables()
        return (
            env.state().tobytes(),
            repr(env._rng.bit_generator.state),
            table.tobytes(),
            counts.tobytes(),
            env.world.poses().tobytes(),
            env.time_s,
        )


_TWINS: _Twins | None = None


def _twins() -> _Twins:
    global _TWINS
    if _TWINS is None:
        _TWINS = _Twins()
    return _TWINS


def _bad_action_values():
    values = [
        np.array([np.nan, 0.0]),
        np.array([0.1, -np.inf]),
        [0.1, float("nan")],
        "fast",
        b"\x00\x01",
        "0.1",
        ["0.1", "0.2"],
        1 + 2j,
        np.array([0.1 + 1j, 0.0]),
        [0.1, 1j],
        True,
        np.array([True, False]),
        [True, 0.0],
        [np.bool_(False), 0.0],
        np.zeros(3),
        np.zeros(1),
        np.zeros((2, 2)),
        np.zeros((1, 2)),
        0.2,
        np.float64(0.2),
        [],
        [[0.1, 0.2]],
        None,
        {"v": 0.1, "w": 0.0},
        np.array([0.1, None], dtype=object),
        np.array(["a", "b"]),
        [10**400, 0.0],
        [0.0, -(10**400)],
        np.array([10**400, 0], dtype=object),
        np.array(["2026-01-01", "2026-01-02"], dtype="datetime64[D]"),
    ]
    try:
        import torch

        values += [
            torch.zeros(2, requires_grad=True),
            torch.tensor([float("nan"), 0.0]),
            torch.zeros(3),
            torch.zeros(2, dtype=torch.complex64),
        ]
    except ImportError:  # pragma: no cover - torch is a project dependency
        pass
    return values


BAD_ACTIONS = _bad_action_values()
unknown_keys = st.sampled_from([0, 1.5, None, b"ugv_0", ("ugv_0",), "ugv_99", "UGV_0", " ugv_0"])


@FAST
@given(
    bad=st.lists(
        st.tuples(st.integers(0, 3), st.integers(0, len(BAD_ACTIONS) - 1)),
        min_size=0,
        max_size=3,
    ),
    extra=st.lists(unknown_keys, max_size=2, unique_by=repr),
    drop=st.sets(st.integers(0, 3), max_size=2),
    good=st.lists(st.floats(-2.0, 2.0), min_size=2, max_size=2),
)
def test_invalid_actions_raise_naming_the_agent_and_change_nothing(bad, extra, drop, good):
    twins = _twins()
    if not twins.a.agents:
        twins.reset()
    agents = list(twins.a.agents)
    actions: dict = {a: np.array(good) for a in agents}
    culprits = set()
    for i, k in bad:
        actions[agents[i]] = BAD_ACTIONS[k]
        culprits.add(agents[i])
    for key in extra:
        actions[key] = np.zeros(2)
    missing = {agents[i] for i in drop}
    for a in missing:
        actions.pop(a, None)
    if not (culprits or extra or missing):
        culprits = {agents[0]}
        actions[agents[0]] = BAD_ACTIONS[0]
    before = twins.snapshot(twins.a)
    with pytest.raises(ValueError) as info:
        twins.a.step(actions)
    message = str(info.value)
    named = {repr(k) for k in extra} | missing | culprits
    assert any(n in message for n in named), message
    assert twins.snapshot(twins.a) == before, "a refused action changed the env"
    # The twin that never saw the bad actions and this env take the same next step.
    step = {a: np.array(good) for a in agents}
    twins.a.step(step)
    twins.b.step(step)
    assert twins.snapshot(twins.a) == twins.snapshot(twins.b)


@given(value=st.sampled_from(BAD_ACTIONS))
@settings(max_examples=20, deadline=None)
def test_invalid_actions_never_raise_anything_but_value_error(value):
    """Whatever the value, the error type is ValueError (no TypeError, OverflowError or a
    torch error from inside numpy)."""
    twins = _twins()
    if not twins.a.agents:
        twins.reset()
    actions = {a: np.zeros(2) for a in twins.a.agents}
    actions[twins.a.agents[-1]] = value
    with pytest.raises(ValueError, match=twins.a.agents[-1]):
        twins.a.step(actions)
    twins.b.step({a: np.zeros(2) for a in twins.b.agents})
    twins.a.step({a: np.zeros(2) for a in twins.a.agents})
    assert twins.snapshot(twins.a) == twins.snapshot(twins.b)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.one_of(
        st.sampled_from([True, False, np.bool_(True), 1.5, np.float64(2.0), "0", b"0", 1j, [0]]),
        st.integers(max_value=-1),
    ),
    options=st.sampled_from([None, {}, "fast", [1], 3]),
)
def test_invalid_reset_arguments_raise_naming_them_and_change_nothing(seed, options):
    twins = _twins()
    before = twins.snapshot(twins.a)
    with pytest.raises(ValueError, match="seed"):
        twins.a.reset(seed=seed, options=options)
    if options not in (None, {}):
        with pytest.raises(ValueError, match="options"):
            twins.a.reset(seed=0, options=options)
    assert twins.snapshot(twins.a) == before


# ---------------------------------------------------------------------- measurement sets
R = 2
TRUTH = GroundTruth(
    np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0]]),
    np.array([[[0.0, 0.0], [1.0, 0.5]], [[-1.0, -0.5], [0.0, 0.0]]]),
)
#: Bad values per slot: beyond MAX_INPUT_MAGNITUDE (1e4 m or rad) or not finite. A stamp may
#: be any finite time; a velocity only enters through the sensor pose (velocity x up to one
#: odometry period), which must stay within the bound.
NON_FINITE = [np.nan, np.inf, -np.inf]
BAD = {
    "detection": NON_FINITE + [1e300, -1e300, 2e4, -2e4],
    "null_bearing": NON_FINITE + [1e300, -2e4],
    "bearing": NON_FINITE + [1e300, 2e4],
    "delta": NON_FINITE + [1e300, 2e4, -2e4],
    "velocity": NON_FINITE + [1e300, -1e300],
    "stamp": NON_FINITE,
}
SLOTS = list(BAD)
bad_slot_values = st.sampled_from(
    [(slot, v) for slot, values in BAD.items() for v in values if slot != "bearing"]
)
ANONYMOUS = [n for n in LOCALIZERS if n.startswith(("phd", "pmb"))]
IDENTITY = [n for n in LOCALIZERS if n not in ANONYMOUS]


def _lidar(t, det, nulls=()):
    det = np.asarray(det, float).reshape(-1, 2)
    return LidarRecord(t, np.zeros(0), np.zeros(0), np.zeros(0), det, np.asarray(nulls, float))


def _good(t: float) -> RobotMeasurements:
    return RobotMeasurements(
        [OdometryRecord(t + 0.05, np.array([0.01, 0.0, 0.02]), np.array([0.1, 0.2]))],
        [_lidar(t, [[1.0, 0.5], [-0.7, 0.2]], [0.3])],
        [CameraRecord(t, np.array([0.46, 2.8]))],
    )


def _bad(t: float, slot: str, value: float) -> RobotMeasurements:
    det, nulls, brg = [[1.0, 0.5], [-0.7, 0.2]], [0.3], [0.46, 2.8]
    delta, vel, stamp = [0.01, 0.0, 0.02], [0.1, 0.2], t
    if slot == "detection":
        det[1][0] = value
    elif slot == "null_bearing":
        nulls = [value]
    elif slot == "bearing":
        brg = [0.46, value]
    elif slot == "delta":
        delta = [0.01, value, 0.02]
    elif slot == "velocity":
        vel = [value, 0.2]
    else:
        stamp = value
    return RobotMeasurements(
        [OdometryRecord(t + 0.05, np.array(delta), np.array(vel))],
        [_lidar(stamp, det, nulls)],
        [CameraRecord(t, np.array(brg))],
    )


def _state(loc) -> tuple:
    table, counts = loc.padded_tables()
    ids = [sorted((k, v.tobytes()) for k, v in loc.identities(r).items()) for r in range(R)]
    return table.tobytes(), counts.tobytes(), repr(ids)


def _measurement_property(name: str, slot: str, value: float, robot: int) -> None:
    loc = make_localizer(name, R, SIMULATOR_PHD)
    for k in range(3):
        loc.step(SwarmFeed(0.1 * k, [_good(0.1 * k)] * R, [()] * R, truth=TRUTH))
    before = _state(loc)
    records = [_good(0.5)] * R
    records[robot] = _bad(0.5, slot, value)
    try:
        loc.step(SwarmFeed(0.5, records, [()] * R, truth=TRUTH))
    except ValueError as exc:
        assert _state(loc) == before, f"{name}: state changed before the error"
        message = str(exc)
        assert any(s in message for s in ("finite", "within", "stamp")), message
        return
    raise AssertionError(f"{name} accepted {slot}={value!r}")


@pytest.mark.parametrize("name", ANONYMOUS)
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(slot_value=bad_slot_values, robot=st.integers(0, R - 1))
def test_anonymous_localizers_refuse_invalid_measurements_unchanged(name, slot_value, robot):
    _measurement_property(name, *slot_value, robot)


@pytest.mark.parametrize("name", [n for n in ANONYMOUS if not n.endswith("-lo")])
@settings(max_examples=6, deadline=None)
@given(value=st.sampled_from(BAD["bearing"]), robot=st.integers(0, R - 1))
def test_camera_families_refuse_invalid_bearings_unchanged(name, value, robot):
    _measurement_property(name, "bearing", value, robot)


@pytest.mark.parametrize("name", IDENTITY)
def test_identity_localizers_refuse_invalid_measurements_unchanged(name):
    for slot in ("detection", "delta", "stamp"):
        _measurement_property(name, slot, 2e4 if slot == "delta" else np.nan, 1)


def _mixture(n: int, cov: float, mean: float = 1.0):
    from localization.mixture import GaussianMixture

    means = np.column_stack((np.full(n, mean), np.linspace(-1.0, 1.0, n)))
    return GaussianMixture(np.full(n, 0.5), means, np.tile(np.eye(2) * cov, (n, 1, 1)))


@pytest.mark.parametrize(
    "case", [(500, 0.01, 1.0), (1, 1e200, 1.0), (1, 0.01, 1e5)], ids=["500", "cov", "mean"]
)
def test_set_mixture_limits_are_the_same_for_reference_and_bank(case):
    from localization import RobotCentricPHD
    from localization.bank import PHDBank

    n, cov, mean = case
    reference = RobotCentricPHD(SIMULATOR_PHD)
    bank = PHDBank(SIMULATOR_PHD, 1)
    for target in (reference, bank.views[0]):
        with pytest.raises(ValueError):
            target.set_mixture(_mixture(n, cov, mean))
        assert len(target) == 0


def test_record_constructors_refuse_wrong_shapes():
    with pytest.raises(ValueError):
        _lidar(0.0, np.zeros((3, 3)))
    with pytest.raises(ValueError):
        OdometryRecord(0.0, np.zeros(2), np.zeros(2))
    # (A (2, 2) bearing array is flattened, not refused: swarm_core.records' choice.)


def test_feed_for_the_wrong_swarm_size_is_refused_unchanged():
    for name in ("phd-lc", "pmb-lc", "id-phd", "ukf"):
        loc = make_localizer(name, R, SIMULATOR_PHD)
        before = _state(loc)
        with pytest.raises(ValueError, match="robots"):
            loc.step(SwarmFeed(0.0, [_good(0.0)] * (R + 1), [()] * (R + 1), truth=TRUTH))
        assert _state(loc) == before


# ---------------------------------------------------------------------- the exhaustive sweep


def sweep_configs() -> None:
    """Every config field x every value of :data:`SWEEP_VALUES` (what the property test
    samples), with the outcome of each; the figures of ``docs/reference/reliability.md``. Run:
    ``.venv/bin/python -m tests.swarm_env.test_invalid_inputs_property``."""
    import collections
    import signal
    import time

    def timeout(*_):
        raise TimeoutError

    signal.signal(signal.SIGALRM, timeout)
    outcomes: collections.Counter = collections.Counter()
    notes = []
    t0 = time.monotonic()
    for field in CONFIG_FIELDS:
        for value in SWEEP_VALUES:
            overrides = _nested(field, value)
            label = ".".join(field)
            try:
                make_config(PRESET, **overrides)
            except ValueError as exc:
                named = _names_the_field(str(exc), field)
                outcomes["refused, ValueError naming the field" if named else "refused, "
                         "ValueError naming a related field"] += 1  # fmt: skip
                if not named:
                    notes.append(f"{label}={reprlib.repr(value)}: {str(exc)[:100]}")
                continue
            except Exception as exc:  # noqa: BLE001 - the sweep reports every failure kind
                outcomes["other exception at construction"] += 1
                notes.append(f"{label}={reprlib.repr(value)}: {type(exc).__name__}: {exc}"[:140])
                continue
            signal.alarm(20)
            try:
                _run_briefly(overrides)
                outcomes["accepted; builds, resets, steps, finite observations"] += 1
            except TimeoutError:
                outcomes["accepted; over 20 s for 2 steps"] += 1
                notes.append(f"{label}={reprlib.repr(value)}: over 20 s")
            except Exception as exc:  # noqa: BLE001
                outcomes["accepted; fails at reset or step"] += 1
                notes.append(f"{label}={reprlib.repr(value)}: {type(exc).__name__}: {exc}"[:140])
            finally:
                signal.alarm(0)
    total = sum(outcomes.values())
    print(
        f"{len(CONFIG_FIELDS)} fields x {len(SWEEP_VALUES)} values = {total} cases, "
        f"{time.monotonic() - t0:.0f} s"
    )
    for outcome, n in outcomes.most_common():
        print(f"| {outcome} | {n} |")
    for note in notes:
        print("-", note)


if __name__ == "__main__":
    sweep_configs()
