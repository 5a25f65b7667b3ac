"""Encirclement (Lee 2012): where the intruder's position comes from (``intruder_source``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.scripted import TABLE_COLUMNS, EncirclementPolicy
from swarm_core.world import GroundTruth
from swarm_env.config import ArenaConfig
from swarm_env.tasks.encirclement import EncirclementTask

ARENA = ArenaConfig(width_m=3.0, height_m=3.0)
TOP_K = 4


def truth(xy, extra=(0.0, 0.0)) -> GroundTruth:
    xy = np.asarray(xy, dtype=float)
    poses = np.c_[xy, np.zeros(len(xy))]
    rel = xy[None, :, :] - xy[:, None, :]
    return GroundTruth(poses=poses, relative_xy=rel, extra_xy=np.asarray([extra], dtype=float))


def obs(components=(), valid=False, q=(0.0, 0.0), radius=0.9, odometry=(0.0, 0.0)):
    """One observation: PHD table rows ``[w, x, y, sxx, sxy, syy, valid]`` of confident
    components at ``components``, odometry ``[v, omega]``, features
    ``[r, valid, cos, sin, rho]``."""
    table = np.zeros((TOP_K, TABLE_COLUMNS))
    for k, (x, y) in enumerate(components):
        table[k] = [1.0, x, y, 0.01, 0.0, 0.01, 1.0]
    rho = math.hypot(*q)
    b = math.atan2(q[1], q[0])
    feats = [radius, 1.0, math.cos(b), math.sin(b), rho] if valid else [radius, 0, 0, 0, 0]
    return np.concatenate((table.ravel(), odometry, feats)).astype(np.float32)


def policy(source: str) -> EncirclementPolicy:
    return EncirclementPolicy(
        max_speed_mps=1.0, top_k=TOP_K, intruder_source=source, control_period_s=0.1, seed=0
    )


def scripted_encirclement(task_params: dict, max_steps: int):
    """A ``lab-3m-4`` encirclement env with ``task_params`` and ``max_steps``, and the scripted
    controller loaded for it: ``(env, act)``."""
    from agents.policies import load_policy
    from swarm_env import parallel_env

    env = parallel_env(
        "lab-3m-4", task="encirclement", task_params=task_params, max_steps=max_steps
    )
    return env, load_policy("scripted:encirclement", env)


def run_scripted(env, act, seed: int, steps: int) -> tuple[dict, dict]:
    """Reset ``env`` with ``seed`` and step it ``steps`` times with ``act``: the observations
    at reset (copied before the first step) and after the last step."""
    o, infos = env.reset(seed=seed)
    first = {a: x.copy() for a, x in o.items()}
    for _ in range(steps):
        o, _, _, _, infos = env.step(act(o, infos))
    return first, o


def velocity(p: EncirclementPolicy, o: np.ndarray):
    from agents.scripted import split_observation

    table, odometry, features = split_observation(o, TOP_K)
    return p.desired_velocity("ugv_0", table, odometry, features)


# --------------------------------------------------------------------------- the task
@pytest.mark.parametrize(
    ("params", "named"),
    [
        ({"intruder_source": "gps"}, "intruder_source"),
        ({"intruder_source": "particle", "beacon": False}, "beacon=True"),
        ({"intruder_source": "particle", "reading_dropout": 1.5}, "reading_dropout"),
        ({"intruder_features": "filter"}, "intruder_features"),  # beacon source
        ({"intruder_source": "particle", "intruder_features": "kalman"}, "intruder_features"),
        (
            {"intruder_source": "particle", "intruder_features": "filter", "n_particles": 3},
            "n_particles",
        ),
        ({"intruder_sensing": "range"}, "intruder_sensing"),  # beacon source
        ({"intruder_source": "particle", "intruder_sensing": "sonar"}, "intruder_sensing"),
        ({"intruder_source": "particle", "particle_start": "gps"}, "particle_start"),
    ],
)
def test_bad_task_parameters_are_refused_by_name(params, named):
    with pytest.raises(ValueError, match=named):
        EncirclementTask(**params)


def test_bad_policy_source_is_rejected():
    with pytest.raises(ValueError, match="intruder_source"):
        EncirclementPolicy(intruder_source="gps")


def _valid_counts(task: EncirclementTask, n_steps: int, n: int = 3) -> np.ndarray:
    t = truth(np.arange(n)[:, None] * np.array([[0.5, 0.0]]), extra=(0.2, 0.4))
    task.reset(t, np.random.default_rng(0), ARENA)
    counts = task.features(n)[:, 1].copy()
    for _ in range(n_steps):
        task.extra_commands(t, 0.1)
        task.rewards(t, np.zeros((n, 2)))
        counts += task.features(n)[:, 1]
    return counts


def test_beacon_reads_every_step():
    np.testing.assert_array_equal(_valid_counts(EncirclementTask(path="static"), 100), 101)


def test_particle_readings_come_at_the_rate_with_dropouts():
    task = EncirclementTask(
        path="static", intruder_source="particle", reading_rate_hz=2.0, reading_dropout=0.0
    )
    # 10 s at 2 Hz, the first within the first half second: 20 each
    np.testing.assert_array_equal(_valid_counts(task, 100), 20)
    lossy = EncirclementTask(
        path="static", intruder_source="particle", reading_rate_hz=2.0, reading_dropout=0.5
    )
    counts = _valid_counts(lossy, 1000, n=20)  # 200 due per robot, half lost
    assert abs(counts.mean() - 100.0) < 4 * math.sqrt(200 * 0.25 / 20)


def test_estimate_gets_one_cue_at_reset_only():
    task = EncirclementTask(path="static", intruder_source="estimate")
    t = truth([[1.0, 0.0], [0.0, 1.0]])
    task.reset(t, np.random.default_rng(0), ARENA)
    assert np.all(task.features(2)[:, 1] == 1.0)
    for _ in range(5):
        task.extra_commands(t, 0.1)
        task.rewards(t, np.zeros((2, 2)))
        np.testing.assert_array_equal(task.features(2)[:, 1:], 0.0)


def test_escape_metrics_hand_computed():
    task = EncirclementTask(path="static", beacon=False)
    ring = [[0.6, 0.0], [-0.3, 0.5], [-0.3, -0.5]]  # encloses the origin (largest gap 2pi/3)
    side = [[0.6, 0.1], [0.6, -0.1], [0.7, 0.0]]  # all on one side: not enclosed
    task.reset(truth(side), np.random.default_rng(0), ARENA)
    for xy in (side, ring, ring, side, ring):
        task.extra_commands(truth(xy), 0.1)
        task.rewards(truth(xy), np.zeros((3, 2)))
    m = task.metrics()
    # after the first enclosure: [in, in, out, in] -> 1 of 4 out, 1 escape in 0.5 s
    assert m["escape_fraction"] == pytest.approx(0.25)
    assert m["escapes_per_min"] == pytest.approx(1 / (0.5 / 60))
    assert m["ever_enclosed"] == 1.0


# --------------------------------------------------------------------------- the controller
def test_beacon_snaps_to_the_phd_component_particle_does_not():
    o = obs(components=[(1.3, 0.0)], valid=True, q=(1.0, 0.0))
    beacon = velocity(policy("beacon"), o)
    # beacon: q = the component at 1.3 m -> k_p (1.3 - 0.9) = 0.32 m/s outwards
    assert beacon == pytest.approx([0.32, 0.0], abs=1e-6)
    p = policy("particle")
    for _ in range(10):
        u = velocity(p, o)
    q = p.intruder_estimate("ugv_0")
    assert np.hypot(*(q - [1.0, 0.0])) < 0.05  # the filter's estimate, not the component
    dq = np.hypot(*q)
    np.testing.assert_allclose(u, 0.8 * (dq - 0.9) * q / dq, atol=1e-6)  # float32 obs


def test_without_a_reading_beacon_wanders_but_particle_and_estimate_keep_tracking():
    cue = obs(valid=True, q=(1.0, 0.0))
    silent = obs(components=[(1.1, 0.05)])
    b = policy("beacon")
    velocity(b, cue)
    assert velocity(b, silent) is None  # no reading: random walk
    p = policy("particle")
    for _ in range(5):
        velocity(p, cue)
    u = velocity(p, silent)
    assert u is not None and u[0] > 0
    e = policy("estimate")
    velocity(e, cue)
    u = velocity(e, silent)
    np.testing.assert_allclose(e.intruder_estimate("ugv_0"), [1.1, 0.05], atol=1e-6)
    assert u[0] == pytest.approx(0.8 * (math.hypot(1.1, 0.05) - 0.9) * 1.1 / math.hypot(1.1, 0.05))


def test_estimate_without_a_cue_does_not_guess():
    e = policy("estimate")
    assert velocity(e, obs(components=[(1.1, 0.0)])) is None


def test_estimate_follows_own_odometry_and_drops_a_lost_track():
    e = policy("estimate")
    velocity(e, obs(valid=True, q=(1.0, 0.0)))
    velocity(e, obs(odometry=(0.5, 0.0)))  # 5 cm forward, nothing in the PHD
    np.testing.assert_allclose(e.intruder_estimate("ugv_0"), [0.95, 0.0], atol=1e-9)
    for _ in range(int(e.lost_after_s / 0.1) + 1):
        velocity(e, obs())
    assert e.intruder_estimate("ugv_0") is None


def test_policy_reads_the_source_of_the_env_task():
    env, act = scripted_encirclement({"intruder_source": "estimate"}, max_steps=20)
    assert act.intruder_source == "estimate"
    assert act.control_period_s == env.config.control_period_s
    first, last = run_scripted(env, act, seed=0, steps=3)
    assert all(first[a][-4] == 1.0 for a in env.agents)  # the cue's valid flag at reset
    assert all(last[a][-4] == 0.0 for a in env.agents)
    env.close()


# ------------------------------------------------------------- the task's filter (learned input)
def test_command_arc_hand_computed():
    from swarm_env.tasks.encirclement import command_arc

    np.testing.assert_allclose(command_arc(np.array([0.2, 0.0]), 0.1), [0.02, 0.0, 0.0])
    # quarter turn at 1 m/s, pi/2 rad/s over 1 s: radius 2/pi, ends at (2/pi, 2/pi), heading pi/2
    r = 2.0 / math.pi
    np.testing.assert_allclose(
        command_arc(np.array([1.0, math.pi / 2]), 1.0), [r, r, math.pi / 2], atol=1e-12
    )


def _arcs_around_the_intruder(task: EncirclementTask, seed: int, steps: int):
    """Two robots drive arcs by their commands (their true poses follow the commanded arcs)
    around a static intruder at (0.3, -0.2) m; ``task`` (two robots) is reset with ``seed``
    and stepped ``steps`` control periods of 0.1 s. Returns the task's features per step
    ``(steps, 2, 5)`` and the distance (m) per step and robot ``(steps, 2)`` between the
    intruder the features give (``rho [cos b, sin b]``) and the truth in the robot's frame
    (meaningful where the valid flag ``[..., 1]`` is set)."""
    from swarm_core.geometry import integrate_body_delta
    from swarm_env.tasks.encirclement import command_arc, intruder_in_agent_frames

    q = np.array([0.3, -0.2])
    commands = np.array([[0.15, 0.3], [0.1, -0.2]])
    poses = np.array([[-1.0, 0.0, 0.0], [1.0, 0.5, math.pi]])

    def state():
        return GroundTruth(
            poses=poses.copy(), relative_xy=np.zeros((2, 2, 2)), extra_xy=q[None, :].copy()
        )

    task.reset(state(), np.random.default_rng(seed), ARENA)
    feats, errors = [], []
    for _ in range(steps):
        task.extra_commands(state(), 0.1)
        for i in range(2):
            poses[i] = integrate_body_delta(poses[i], command_arc(commands[i], 0.1))
        task.rewards(state(), commands)
        f = task.features(2)
        est = f[:, 4:5] * f[:, 2:4]
        feats.append(f)
        errors.append(np.hypot(*(est - intruder_in_agent_frames(poses, q)).T))
    return np.array(feats), np.array(errors)


def test_filter_features_track_the_intruder_between_sparse_readings():
    """Two robots drive arcs by their commands (their true poses follow the commanded arcs);
    readings come at 2 Hz with 20 % lost. The ``filter`` features give the intruder every
    step, within 10 cm of the truth in each robot's frame, where ``reading`` has it on ~2 steps
    in 10."""
    tasks = {
        mode: EncirclementTask(path="static", intruder_source="particle", intruder_features=mode)
        for mode in ("reading", "filter")
    }
    runs = {
        mode: _arcs_around_the_intruder(task, seed=5, steps=80) for mode, task in tasks.items()
    }
    valid = {mode: int(feats[20:, :, 1].sum()) for mode, (feats, _) in runs.items()}
    assert valid["filter"] == 2 * 60  # every step, both robots
    assert valid["reading"] < 0.3 * 2 * 60
    assert np.max(runs["filter"][1][20:]) < 0.10
    est = tasks["filter"].intruder_estimates()
    assert len(est) == 2 and all(e is not None for e in est)


def test_scripted_policy_reads_the_task_filter():
    env, act = scripted_encirclement(
        {"intruder_source": "particle", "intruder_features": "filter"}, max_steps=30
    )
    assert act.task_filter and act.intruder_source == "particle"
    _, o = run_scripted(env, act, seed=3, steps=30)
    # After 3 s every robot has had a reading: the features hold the filter's estimate.
    assert all(o[a][-4] == 1.0 for a in env.possible_agents)
    assert act.intruder_estimate(env.possible_agents[0]) is None  # the task keeps it
    env.close()


def test_range_sensing_drops_the_bearing():
    rates = {}
    for sensing in ("range-bearing", "range"):
        task = EncirclementTask(
            path="static", intruder_source="particle", intruder_sensing=sensing
        )
        t = truth([[1.0, 0.0], [0.0, 1.0]], extra=(0.0, 0.0))
        task.reset(t, np.random.default_rng(0), ARENA)
        feats = []
        for _ in range(40):
            task.extra_commands(t, 0.1)
            task.rewards(t, np.zeros((2, 2)))
            feats.append(task.features(2))
        f = np.concatenate(feats)
        got = f[f[:, 1] == 1.0]
        rates[sensing] = f[:, 1].copy()
        assert len(got) > 0
        np.testing.assert_allclose(got[:, 4], 1.0, atol=0.2)  # the range, 1 m, noisy
        if sensing == "range":
            np.testing.assert_array_equal(got[:, 2:4], 0.0)  # no bearing: (0, 0)
        else:
            assert np.all(np.hypot(got[:, 2], got[:, 3]) > 0.99)
    # the same rate and loss draws: the readings arrive on the same steps
    np.testing.assert_array_equal(rates["range"], rates["range-bearing"])


def _range_only_filter_errors(start: str, seed: int) -> tuple[list, np.ndarray]:
    """Two robots drive command arcs (poses follow the arcs) around a static intruder with
    range-only readings (2 Hz, 20 % lost) for 40 s; the task's filter features against the
    ground truth: the first step each robot's filter reports, and the errors (steps, 2) m
    (NaN before)."""
    task = EncirclementTask(
        path="static",
        intruder_source="particle",
        intruder_features="filter",
        intruder_sensing="range",
        particle_start=start,
    )
    feats, errors = _arcs_around_the_intruder(task, seed=seed, steps=400)
    valid = feats[:, :, 1] == 1.0
    first = [int(np.argmax(valid[:, i])) if valid[:, i].any() else None for i in range(2)]
    return first, np.where(valid, errors, np.nan)


def test_range_only_track_converges_with_the_trilateration_start():
    """Ground truth, six seeds: each robot's filter starts once its stations spread (after
    >= 3 readings, not at the first), then holds the intruder: error over the last 5 s below
    0.3 m for every robot and 0.2 m on average (measured 0.15 m; range-only leaves the bearing
    to the robot's own motion), below the uniform start's average (measured 0.21 m)."""
    tri, uni = [], []
    for seed in range(6):
        first, errors = _range_only_filter_errors("trilateration", seed)
        assert all(f is not None and 10 < f < 340 for f in first)
        tail = errors[-50:]
        assert not np.isnan(tail).any()
        assert np.all(tail.mean(axis=0) < 0.3)
        tri.append(tail.mean())
        first_u, errors_u = _range_only_filter_errors("uniform", seed)
        assert all(f is not None and f < 10 for f in first_u)
        uni.append(errors_u[-50:].mean())
    assert np.mean(tri) < 0.2
    assert np.mean(tri) < np.mean(uni)


def test_scripted_policy_takes_the_range_only_reading_and_the_start():
    env, act = scripted_encirclement(
        {
            "intruder_source": "particle",
            "intruder_sensing": "range",
            "particle_start": "trilateration",
        },
        max_steps=10,
    )
    assert act.particle_start == "trilateration"
    p = policy("particle")
    p.particle_start = "trilateration"
    reading = obs(valid=True, q=(1.0, 0.0))
    reading[-3:-1] = 0.0  # range only: (cos b, sin b) = (0, 0)
    for _ in range(3):  # standing still: the stations coincide, no fix, random walk
        assert velocity(p, reading) is None
    assert p.intruder_estimate("ugv_0") is None
    assert p._filters["ugv_0"].pending[0][0].shape == (3, 2)
    env.close()


@pytest.mark.parametrize(
    "params, message",
    [
        (
            {"intruder_features": "filter", "intruder_source": "beacon"},
            "task 'encirclement': intruder_features='filter' needs intruder_source='particle', "
            "got 'beacon'",
        ),
        (
            {"intruder_sensing": "range", "intruder_source": "estimate"},
            "task 'encirclement': intruder_sensing='range' needs intruder_source='particle' "
            "(the other sources use the reading's bearing), got 'estimate'",
        ),
    ],
)
def test_particle_only_options_refuse_another_source(params, message):
    with pytest.raises(ValueError) as err:
        EncirclementTask(**params)
    assert str(err.value) == message
    EncirclementTask(**{**params, "intruder_source": "particle"})  # the source they need
