"""A robot's filter on board (hardware_bridge/onboard.py): the same estimate as the swarm's."""

from __future__ import annotations

import numpy as np
import pytest

from hardware_bridge.estimate import parse_estimate_stamped
from hardware_bridge.messages import (
    bearings_stamped_msg,
    laser_scan_msg,
    odometry_msg,
    parse_bearings_stamped,
    parse_laser_scan,
    parse_odometry,
    s_to_ns,
)
from hardware_bridge.onboard import OnBoardFilter, mixture_arrays
from swarm_env import parallel_env


@pytest.mark.parametrize("family", ["phd-lc", "pmb-lc"])
def test_onboard_filter_matches_the_swarms_filter_for_its_robot(family):
    """Robot-centric filters use only the robot's own records: one robot's filter, stepped
    on its records alone, holds the mixture the swarm's filter bank holds for it."""
    env = parallel_env("lab-3m-4", localizer=family, max_steps=60)
    env.reset(seed=4)
    rng = np.random.default_rng(4)
    robot = 2
    agent = env.possible_agents[robot]
    onboard = OnBoardFilter(agent, env.config, family)
    first = env.last_world_step
    onboard.step_records(first.measurements[agent], s_to_ns(first.time_s))
    compared = 0
    for _ in range(40):
        env.step({a: rng.uniform(-1, 1, 2) * [0.3, 1.5] for a in env.agents})
        step = env.last_world_step
        msg = onboard.step_records(step.measurements[agent], s_to_ns(step.time_s))
        got = parse_estimate_stamped(msg)
        want = env.localizer.mixture(robot)
        np.testing.assert_allclose(got.weights, want.weights, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.means_m, want.means, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.covariances_m2, want.covs, rtol=0, atol=1e-12)
        compared += got.weights.size
    env.close()
    assert compared > 40  # the filter held components to compare
    assert got.frame_id == f"{agent}/base_link" and got.localizer == family
    assert got.weight_kind == ("existence" if family.startswith("pmb") else "intensity")


def test_onboard_filter_reads_the_robots_messages():
    """Odometry, scans and bearings as the robot publishes them (rosbridge JSON, parsed by the
    bridge's validators) drive the filter: a teammate seen by lidar and camera 1 m ahead
    becomes a component there."""
    env = parallel_env("lab-3m-4", localizer="phd-lc", max_steps=5)
    config = env.config
    env.close()
    onboard = OnBoardFilter("ugv_3", config, "phd-lc")
    angles = -np.pi + np.arange(720) * (2 * np.pi / 720)
    t0 = 1_700_000_000_000_000_000
    for k in range(40):
        stamp = t0 + k * 100_000_000
        onboard.add(parse_odometry(odometry_msg(stamp, 0.0, 0.0, 0.0, 0.0, 0.0)))
        # A housing 1 m ahead (exact ray-cylinder ranges) in a round room 3 m away.
        ranges = np.full(720, 3.0)
        lateral = np.sin(angles)
        hit = (np.abs(lateral) < 0.0325) & (np.cos(angles) > 0)
        ranges[hit] = np.cos(angles[hit]) - np.sqrt(0.0325**2 - lateral[hit] ** 2)
        scan = laser_scan_msg(
            stamp,
            angles,
            ranges,
            np.ones(720),
            range_min_m=0.12,
            range_max_m=10.0,
            scan_time_s=1 / 7,
            frame_id="ugv_3/laser",
        )
        onboard.add(parse_laser_scan(scan))
        onboard.add(parse_bearings_stamped(bearings_stamped_msg(stamp, np.array([0.0]))))
        msg = onboard.step(stamp + 1)
    w, m, _ = mixture_arrays(msg)
    assert w.sum() == pytest.approx(1.0, abs=0.3)
    best = m[np.argmax(w)]
    np.testing.assert_allclose(best, [1.0, 0.0], atol=0.05)
    with pytest.raises(TypeError, match="Odom, Scan or Bearings, got dict"):
        onboard.add({"ranges": []})


def test_families_that_need_the_radio_are_refused():
    env = parallel_env("lab-3m-4", max_steps=5)
    config = env.config
    env.close()
    with pytest.raises(ValueError, match="on board .* got 'id-phd'"):
        OnBoardFilter("ugv_0", config, "id-phd")
    with pytest.raises(ValueError, match="robot id must match"):
        OnBoardFilter("3ugv", config)
