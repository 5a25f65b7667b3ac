"""End to end against the loopback robot server: the bridge env runs the scripted wander policy
through real websockets; localization stays within a stated margin of the pure simulator; the
recorded bag replays to the same filter output; simulated episodes export and replay."""

from __future__ import annotations

import json

import numpy as np
import pytest

from agents.scripted import WanderPolicy
from hardware_bridge import real_env
from hardware_bridge.bag import ReplayWorld, replay_env
from hardware_bridge.loopback import LoopbackProcess
from swarm_env.config import make_config
from swarm_env.env import SwarmEnv
from swarm_env.world.sim import SimWorld
from swarm_phd.episode import run_episode
from swarm_phd.export_bag import export_sim_episode

SEED = 0
N_STEPS = 80  # 8 s of real time, 4 robots (seed-lab)

# Stated margin: over the same 8 s from the same arena and start poses, the bridge's
# localization may be this much worse than the pure simulator's, both with the simulator's
# sensor model (the loopback's robots carry the simulator's sensors). Each live run's
# trajectory and step boundaries differ, so one 8-s run is one draw from a spread with a long
# tail, and the margins are set between that spread and a fault's signature
# (docs/how-to/real-robots.md,
# "Localization over the loopback"). The simulator scores 2.2 % large error, 96.4 % accurate
# and a 0.024 m median here, and spans 0.8-15.5 % large error over arenas 0-9. Live runs on a
# quiet 2-core machine: 27 runs at 1.9-9.6 %, 83.1-95.1 % and 0.029-0.038 m; the tail seen in
# CI: 12.0 % / 70.8 % (seed hardware model) and 15.6 % large error (2026-12-04). A frame or sign
# error in the bridge gives ~40 % large error and a ~0.13 m median, so its median error fails
# at less than half its size, and its large error at about half (22 % against 40 %).
MARGIN_LARGE_ERROR_PCT = 20.0  # percentage points of (neighbour, step) pairs with error > 0.3 m
MARGIN_MEDIAN_ERROR_M = 0.03
# Percentage points within 0.1 m. The bound stays above 50 %, so any fault that puts the median
# error above 0.1 m fails it.
MARGIN_ACCURATE_PCT = 35.0


class _SameArenaSim(SimWorld):
    """The simulator with the loopback server's arena: reset from ``default_rng(seed)``."""

    def __init__(self, config, seed):
        super().__init__(config)
        self._seed = seed

    def reset(self, rng):
        return super().reset(np.random.default_rng(self._seed))


@pytest.fixture(scope="module")
def bridge_episode(tmp_path_factory):
    # The robots in a process of their own, as real robots are: in this process their
    # real-time sim shared the GIL with the bridge and the filters, the likely cause of a CI
    # run with 12 of 80 steps without a fresh mocap pose (docs/how-to/real-robots.md).
    server = LoopbackProcess("seed-lab", seed=SEED)
    server.start()
    bag = tmp_path_factory.mktemp("bridge") / "episode"
    env = real_env(
        port=server.port,
        preset="seed-lab",
        record=str(bag),
        max_steps=10_000,
        phd=make_config("seed-lab").phd,  # as the simulator episode's filter
    )
    stale_at: dict[int, dict[str, tuple[str, ...]]] = {}  # step -> {robot: stale sensors}

    def note_stale(k, infos):
        stale = {a: tuple(i["stale"]) for a, i in infos.items() if i.get("stale")}
        if stale:
            stale_at[k] = stale

    try:
        result = run_episode(
            env,
            WanderPolicy.for_env(env, seed=SEED),
            N_STEPS,
            seed=SEED,
            trace=True,
            on_step=note_stale,
        )
        counters = env.world.counters_snapshot()
        timing = dict(env.world.timing)
    finally:
        env.close()
        robots = server.close()
    return {
        "result": result,
        "counters": counters,
        "timing": timing,
        "bag": bag,
        "robots": robots,
        "stale_at": stale_at,
    }


@pytest.fixture(scope="module")
def sim_episode():
    config = make_config("seed-lab", max_steps=10_000)
    env = SwarmEnv(config=config, world=_SameArenaSim(config, SEED))
    try:
        return run_episode(env, WanderPolicy.for_env(env, seed=SEED), N_STEPS, seed=SEED)
    finally:
        env.close()


@pytest.mark.timeout(60)
def test_bridge_runs_the_scripted_policy_and_localizes_like_the_simulator(
    bridge_episode, sim_episode
):
    live = bridge_episode["result"]
    counters = bridge_episode["counters"]
    robots = bridge_episode["robots"]  # the loopback's own figures: how late it ran
    # Scored = every robot had a mocap pose <= 0.5 s old; on a loaded 2-core machine the
    # loopback's real-time sim can fall behind for a step or two.
    assert live.steps == N_STEPS and live.scored_steps >= N_STEPS - 4, (live.scored_steps, robots)
    # The same hiccup leaves every sensor of the starved robots > 0.5 s old for that step (CI,
    # 2026-12-05: odometry, camera and mocap stale in one step, 79 of 80 scored). A broken link
    # or a silent sensor is stale step after step (tests/hardware_bridge/test_faults.py), so
    # staleness is allowed in as many steps as scoring allows to go unscored.
    stale_at = bridge_episode["stale_at"]
    assert len(stale_at) <= 4, f"sensors went stale on a healthy link: {stale_at}"
    assert sum(live.stale_steps.values()) == sum(
        len(s) for step in stale_at.values() for s in step.values()
    )
    # The data really flowed: ~7 scans/s and 10 odometry/s per robot over 8 s.
    expected_scans = N_STEPS * 0.1 * 7 * 4
    assert counters["lidar.accepted"] >= 0.8 * expected_scans
    assert counters["odometry.accepted"] >= 0.8 * N_STEPS * 4
    assert counters.get("transport.malformed", 0) == 0
    assert robots["sim_steps"] >= N_STEPS  # the robots' process ran the episode and reported
    assert not any(k.endswith(".invalid") for k in counters)
    # Honest timing: each step took the control period (no early return, no step that
    # oversleeps by habit). A loaded 2-core machine (load average ~9 seen) wakes a sleeping step
    # up to ~0.15 s late, and once in a while (CI, 2026-12-05) a starved process wakes one step
    # 0.49 s late. So a few steps may overrun (late by more than half the period), as a few may
    # go unscored, and none may hang for a second; a loop late by habit overruns step after step.
    timing = bridge_episode["timing"]
    assert timing["steps"] >= N_STEPS and timing["overruns"] <= 4, timing
    assert timing["max_late_s"] < 1.0, timing

    sim = sim_episode.metrics
    got = live.metrics
    assert got["percent_large_error"] <= sim["percent_large_error"] + MARGIN_LARGE_ERROR_PCT, (
        got,
        sim,
        robots,
    )
    assert got["median_error_m"] <= sim["median_error_m"] + MARGIN_MEDIAN_ERROR_M, (got, sim)
    assert sim["percent_accurate"] - MARGIN_ACCURATE_PCT > 50.0  # the margin's own premise
    assert got["percent_accurate"] >= sim["percent_accurate"] - MARGIN_ACCURATE_PCT, (got, sim)


@pytest.mark.timeout(60)
def test_recorded_bag_replays_to_the_same_filter_output(bridge_episode):
    live = bridge_episode["result"]
    world = ReplayWorld(bridge_episode["bag"])
    assert world.robot_ids == ("ugv_0", "ugv_1", "ugv_2", "ugv_3")
    assert world.n_episodes == 1 and world.n_steps() == N_STEPS
    env = replay_env(bridge_episode["bag"])
    replayed = run_episode(env, None, N_STEPS, seed=None, trace=True)
    assert replayed.steps == N_STEPS
    assert len(replayed.trace) == len(live.trace)
    for k, (a, b) in enumerate(zip(live.trace, replayed.trace, strict=True)):
        for agent in a:
            assert np.array_equal(a[agent][0], b[agent][0]), (k, agent, "weights")
            assert np.array_equal(a[agent][1], b[agent][1]), (k, agent, "means")
    assert replayed.metrics == live.metrics
    # The replay env truncates at the recorded length; the world itself refuses to go past it.
    assert not env.agents
    with pytest.raises(EOFError):
        env.world.step(np.zeros((4, 2)))


@pytest.mark.timeout(60)
def test_exported_sim_episode_replays_through_the_env_api(tmp_path):
    bag = tmp_path / "sim"
    summary = export_sim_episode(bag, preset="seed-lab", duration_s=2.0, seed=3)
    assert summary["steps"] == 20
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:  # the reported count is what the bag holds
        assert reader.message_count == summary["messages"] + summary["markers"]
    assert summary["markers"] == 21  # the reset and 20 steps
    env = replay_env(bag)
    replayed = run_episode(env, None, 20, seed=None, trace=True)
    assert replayed.steps == 20 and replayed.scored_steps == 20
    # Same inputs up to the float32 fields of the messages: the filters agree closely.
    worst = 0.0
    for k, (a, b) in enumerate(zip(summary["trace"], replayed.trace, strict=True)):
        for agent in a:
            assert a[agent][0].shape == b[agent][0].shape, (k, agent)
            worst = max(
                worst,
                np.abs(a[agent][1] - b[agent][1]).max(initial=0.0),
                np.abs(a[agent][0] - b[agent][0]).max(initial=0.0),
            )
    assert worst < 1e-4
    # Bags are never overwritten.
    with pytest.raises(Exception, match="exists"):
        export_sim_episode(bag, duration_s=0.5)


@pytest.mark.timeout(60)
def test_cli_export_replay_and_loopback_bridge(tmp_path, capsys):
    from swarm_phd.cli import main

    bag = tmp_path / "cli_bag"
    assert main(["export-bag", "--out", str(bag), "--duration", "1.0", "--seed", "2"]) == 0
    assert "10 steps" in capsys.readouterr().out
    assert main(["replay", str(bag), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    episode = out["episodes"][0]
    assert episode["steps"] == 10 and episode["metrics"]["scored_observations"] > 0

    rec = tmp_path / "bridge_bag"
    assert main(["bridge", "--loopback", "--steps", "12", "--json", "--record", str(rec)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["steps"] == 12 and out["rejected_messages"] == 0
    assert out["counters"]["lidar.accepted"] > 0 and out["metrics"]["scored_observations"] > 0
    # The loopback's robots carry the simulator's sensors: the filter has the simulator's model.
    assert out["sensor_model"] == "simulator"
    assert ReplayWorld(rec).config.phd == make_config("lab-3m-4").phd
    assert main(["replay", str(rec)]) == 0
    assert "12 steps" in capsys.readouterr().out

    assert main(["bridge", "--host", "10.1.2.3", "--robots", "ugv_0"]) == 2
    assert "allow-remote" in capsys.readouterr().err
