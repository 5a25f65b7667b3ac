"""The optional lidar sector block of the observation (``SwarmConfig.lidar_sectors``)."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env import parallel_env
from swarm_env.observation import SECTOR_TABLE, lidar_sector_ranges

KWARGS = {"preset": "lab-3m-4", "task": "formation", "max_steps": 40}


def test_sectors_of_a_hand_built_scan():
    """S = 4 (90 deg each): sector 0 is centred straight ahead, 1 on the left (+y), 2 behind,
    3 on the right; boundaries at +-45 deg and 135 deg belong to the CCW sector."""
    q = np.pi / 4
    angles = np.array([0.0, 0.1, q - 1e-9, q, np.pi / 2, -np.pi, 3 * q, -q, -q - 1e-9, -0.2])
    ranges = np.array([1.0, 0.7, 0.9, 1.5, 0.0, 5.0, np.nan, 0.4, 0.6, 0.8])
    #    sector:        0    0    0    1    1(0: none) 2(clipped) 2(nan)  0    3    0
    out = lidar_sector_ranges([angles], [ranges], 4, 2.0)
    np.testing.assert_allclose(out, [[0.4, 1.5, 2.0, 0.6]])
    # Sector 2 has only a clipped 5 m return and a nan: it reads the max. Sector 1's valid
    # return is 1.5 m (the 0-range "no return" at +90 deg is ignored).


def test_sectors_of_several_robots_and_empty_scans():
    a1 = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    r1 = np.full(360, 3.0)
    r1[a1.size // 2] = 0.25  # straight ahead
    r1[np.argmin(np.abs(a1 - np.pi / 2))] = 0.5  # left
    # Robot 2: 10 beams just past -pi (behind, sector 4), a 1.2 m return, and a 0 ("no
    # return") and a NaN beam that must not count.
    r2 = np.array([1.5, 1.2, 0.0, np.nan, 1.9, 1.7, 1.6, 1.8, 1.4, 1.3])
    out = lidar_sector_ranges([a1, np.zeros(0), a1[:10]], [r1, np.zeros(0), r2], 8, 2.0)
    assert out.shape == (3, 8)
    np.testing.assert_allclose(out[0], [0.25, 2.0, 0.5, 2.0, 2.0, 2.0, 2.0, 2.0])
    np.testing.assert_allclose(out[1], 2.0)  # no scan: nothing seen
    np.testing.assert_allclose(out[2], [2.0, 2.0, 2.0, 2.0, 1.2, 2.0, 2.0, 2.0])
    # Matches a plain per-beam loop (the readable reference).
    ref = np.full(8, 2.0)
    w = 2 * np.pi / 8
    for ang, r in zip(a1, r1, strict=True):
        j = int(np.floor(((ang + w / 2) % (2 * np.pi)) / w)) % 8
        if r > 0:
            ref[j] = min(ref[j], min(r, 2.0))
    np.testing.assert_allclose(out[0], ref)


def _run(sectors: int, steps: int = 25):
    from agents.policies import load_policy

    env = parallel_env(**KWARGS, lidar_sectors=sectors)
    policy = load_policy("scripted:formation", env)
    policy.reset(5)
    obs, infos = env.reset(seed=5)
    history = [(obs, infos)]
    for _ in range(steps):
        obs, _, _, _, infos = env.step(policy(obs, infos))
        history.append((obs, infos))
    return env, history


def test_env_sector_block_is_the_last_scan_and_leaves_the_rest_alone():
    plain_env, plain = _run(0)
    env, with_sectors = _run(8)
    layout = env.encoder.layout
    assert [t[0] for t in layout.tables] == ["estimate", SECTOR_TABLE]
    agent = env.possible_agents[0]
    space = env.observation_space(agent)
    assert space.shape[0] == plain_env.observation_space(agent).shape[0] + 8
    assert np.all(space.low[layout.table_size - 8 : layout.table_size] == 0.0)
    assert np.all(space.high[layout.table_size - 8 : layout.table_size] == np.float32(2.0))
    plain_layout = plain_env.encoder.layout
    seen_scan = held = False
    previous: dict = {}
    for (o0, _), (o1, infos) in zip(plain, with_sectors, strict=True):
        for a in env.possible_agents:
            assert space.contains(o1[a])
            # The neighbour table, the odometry and the task features are unchanged (and the
            # scripted controller, which skips the block, drove both envs the same way).
            np.testing.assert_array_equal(plain_layout.table(o0[a]), layout.table(o1[a]))
            np.testing.assert_array_equal(
                o0[a][plain_layout.odometry_slice], o1[a][layout.odometry_slice]
            )
            np.testing.assert_array_equal(
                o0[a][plain_layout.features_slice], o1[a][layout.features_slice]
            )
            scans = infos[a]["measurements"]["lidar"]
            if scans:
                seen_scan = True
                want = lidar_sector_ranges(
                    [scans[-1]["angles_rad"]], [scans[-1]["ranges_m"]], 8, 2.0
                )[0]
                got = layout.table(o1[a], SECTOR_TABLE)[:, 0]
                np.testing.assert_allclose(got, want.astype(np.float32))
            elif a in previous:  # a step without a scan keeps what the robot last saw
                held = True
                np.testing.assert_array_equal(layout.table(o1[a], SECTOR_TABLE), previous[a])
            previous[a] = layout.table(o1[a], SECTOR_TABLE)
    assert seen_scan and held
    # In the lab arena (3 m walls) some sector always sees a wall within 2 m.
    assert layout.table(with_sectors[-1][0][agent], SECTOR_TABLE).min() < 2.0


def test_bad_sector_config_raises():
    with pytest.raises(ValueError, match="lidar_sectors"):
        parallel_env(**KWARGS, lidar_sectors=-1)
    with pytest.raises(ValueError, match="lidar_sectors"):
        parallel_env(**KWARGS, lidar_sectors=2.5)
    with pytest.raises(ValueError, match="lidar_sector_max_m"):
        parallel_env(**KWARGS, lidar_sectors=4, lidar_sector_max_m=0.0)


def test_set_extractor_reads_the_sector_block():
    torch = pytest.importorskip("torch")
    from agents.sb3.features import NeighbourSetExtractor

    env = parallel_env(**KWARGS, lidar_sectors=8)
    obs, _ = env.reset(seed=1)
    space = env.observation_space(env.possible_agents[0])
    extractor = NeighbourSetExtractor(space, top_k=env.config.top_k)
    x = torch.as_tensor(np.stack(list(obs.values())))
    table_size = env.encoder.layout.table_size
    y = x.clone()
    y[:, table_size - 8 : table_size] = 0.1  # an obstacle all around
    fx, fy = extractor(x), extractor(y)
    changed = (fx - fy).abs().sum(dim=0) > 0
    # Exactly the 8 sector features change (scaled by the 2 m bound), nothing else.
    assert int(changed.sum()) == 8
    np.testing.assert_allclose(fy[:, changed].detach().numpy(), 0.05, rtol=1e-6)


def test_reset_forgets_the_last_episode_sectors():
    env = parallel_env(**KWARGS, lidar_sectors=8)
    fresh, _ = env.reset(seed=3)
    for _ in range(15):
        env.step({a: np.array([0.2, 0.5], dtype=np.float32) for a in env.agents})
    again, _ = env.reset(seed=3)
    for a in env.possible_agents:
        np.testing.assert_array_equal(fresh[a], again[a])
