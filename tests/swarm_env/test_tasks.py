"""Tasks: parameter checks, rewards on hand-built configurations, and the PettingZoo API."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from swarm_core.world import GroundTruth
from swarm_env import parallel_env
from swarm_env.config import ArenaConfig
from swarm_env.tasks import TASKS, make_task
from swarm_env.tasks.common import collisions, obstacle_distances
from swarm_env.tasks.encirclement import EncirclementTask
from swarm_env.tasks.exploration import ExplorationTask
from swarm_env.tasks.formation import FormationTask
from swarm_env.world.arena import Layout


def truth(xy, yaw=None, extra=None) -> GroundTruth:
    xy = np.asarray(xy, dtype=float)
    yaw = np.zeros(len(xy)) if yaw is None else np.asarray(yaw, dtype=float)
    poses = np.c_[xy, yaw]
    rel = xy[None, :, :] - xy[:, None, :]  # yaw 0 everywhere in these tests but the beacon one
    extra_xy = np.zeros((0, 2)) if extra is None else np.asarray(extra, dtype=float)
    return GroundTruth(poses=poses, relative_xy=rel, extra_xy=extra_xy)


RNG = np.random.default_rng(0)
ARENA = ArenaConfig(width_m=3.0, height_m=3.0)


# ------------------------------------------------------------------ registry and bad input
def test_registry_has_every_task():
    assert {"wander", "formation", "exploration", "encirclement"} <= set(TASKS)


def test_unknown_task_name_lists_the_choices():
    with pytest.raises(ValueError, match="task must be one of"):
        make_task("formaton")
    with pytest.raises(ValueError, match="task must be one of"):
        parallel_env("seed-lab", task="nope")


@pytest.mark.parametrize("name", ["formation", "exploration", "encirclement", "wander"])
def test_unknown_task_parameter_is_named(name):
    with pytest.raises(ValueError, match="radius_typo"):
        make_task(name, radius_typo=1.0)


@pytest.mark.parametrize(
    "name, params, match",
    [
        ("formation", {"radius_m": -1.0}, "radius_m"),
        ("formation", {"radius_m": float("nan")}, "radius_m"),
        ("formation", {"shape": "square"}, "shape"),
        ("formation", {"shape": "lattice", "radius_m": 1.0}, "radius_m"),
        ("formation", {"shape": "circle", "spacing_m": 0.5}, "spacing_m"),
        ("formation", {"progress_weight": -1}, "progress_weight"),
        ("exploration", {"target_coverage": 0.0}, "target_coverage"),
        ("exploration", {"cell_m": 0}, "cell_m"),
        ("encirclement", {"path": "static", "intruder_speed_mps": 0.1}, "static"),
        ("encirclement", {"path": "circle", "intruder_speed_mps": 0.0}, "intruder_speed_mps"),
        ("encirclement", {"beacon": "yes"}, "beacon"),
        ("encirclement", {"radius_m": 0}, "radius_m"),
    ],
)
def test_bad_or_inconsistent_parameters_raise(name, params, match):
    with pytest.raises(ValueError, match=match):
        make_task(name, **params)


def test_env_passes_task_params_and_rejects_bad_ones():
    env = parallel_env("seed-lab", task="formation", task_params={"radius_m": 0.5})
    assert env.task.radius_m == 0.5
    with pytest.raises(ValueError, match="spacing_m"):
        parallel_env("seed-lab", task="formation", task_params={"spacing_m": 0.5})


def test_exploration_cell_larger_than_arena_raises_at_reset():
    task = ExplorationTask(cell_m=5.0)
    with pytest.raises(ValueError, match="cell_m"):
        task.reset(truth([[0.0, 0.0]]), RNG, ARENA)


# ------------------------------------------------------------------ formation rewards
def test_circle_reward_zero_on_the_target_formation():
    task = FormationTask(radius_m=1.0)
    t = truth([[1, 0], [0, 1], [-1, 0], [0, -1]])
    task.reset(t, RNG, ARENA)
    np.testing.assert_allclose(task.rewards(t, np.zeros((4, 2))), 0.0, atol=1e-12)


def test_circle_reward_hand_computed():
    # Square of half-diagonal 1 with r = 0.5: radial error 0.5; chord 2 * 0.5 * sin(pi/4)
    # = 0.70711 vs nearest-neighbour distance sqrt(2): spacing error 0.70711.
    task = FormationTask(radius_m=0.5, spacing_weight=0.5)
    t = truth([[1, 0], [0, 1], [-1, 0], [0, -1]])
    task.reset(t, RNG, ARENA)
    expected = -(0.5 + 0.5 * (math.sqrt(2) - math.sqrt(2) / 2))
    np.testing.assert_allclose(task.rewards(t, np.zeros((4, 2))), expected)
    # Two robots 2 m apart, r = 0.8: centroid between them, radial error 0.2 each;
    # chord for N = 2 is the diameter 1.6, spacing error 0.4 -> r = -(0.2 + 0.5 * 0.4).
    task = FormationTask(radius_m=0.8)
    t = truth([[0, 0], [2, 0]])
    task.reset(t, RNG, ARENA)
    np.testing.assert_allclose(task.rewards(t, np.zeros((2, 2))), [-0.4, -0.4])
    assert task.metrics()["formation_error_m"] == pytest.approx(0.2)


def test_circle_progress_shaping_rewards_the_error_removed():
    task = FormationTask(radius_m=0.8, progress_weight=10.0)
    start = truth([[0, 0], [2, 0]])
    task.reset(start, RNG, ARENA)
    np.testing.assert_allclose(task.rewards(start, np.zeros((2, 2))), [-0.4, -0.4])  # no change
    done = truth([[0.2, 0], [1.8, 0]])  # on the circle, spacing = diameter: error 0
    np.testing.assert_allclose(task.rewards(done, np.zeros((2, 2))), [4.0, 4.0])


def test_lattice_reward_hand_computed():
    # d = 1: robot 0 and 1 are at distance 1 (error 0); robot 2's nearest is robot 1 at 2 m.
    task = FormationTask(shape="lattice", spacing_m=1.0)
    t = truth([[0, 0], [1, 0], [3, 0]])
    task.reset(t, RNG, ARENA)
    np.testing.assert_allclose(task.rewards(t, np.zeros((3, 2))), [0.0, 0.0, -1.0])
    # Robot 1 has two neighbours within 1.5 d: errors |1 - 1| and |1.2 - 1| -> mean 0.1.
    t = truth([[0, 0], [1, 0], [2.2, 0]])
    np.testing.assert_allclose(task.rewards(t, np.zeros((3, 2))), [0.0, -0.1, -0.2])


def test_formation_features():
    task = FormationTask(radius_m=1.0)
    f = task.features(4)
    np.testing.assert_allclose(f, [[1.0, math.sqrt(2)]] * 4)
    low, high = task.feature_bounds()
    assert np.all(f >= low) and np.all(f <= high)
    lattice = FormationTask(shape="lattice", spacing_m=0.7)
    np.testing.assert_allclose(lattice.features(3), [[0.7]] * 3)


# ------------------------------------------------------------------ exploration rewards
def test_exploration_rewards_new_cells_and_penalises_collisions():
    arena = ArenaConfig(width_m=2.0, height_m=2.0)  # 4 cells of 1 m
    task = ExplorationTask(
        cell_m=1.0,
        target_coverage=1.0,
        coverage_reward=1.0,
        collision_penalty=0.1,
        collision_distance_m=0.3,
        wall_margin_m=0.16,
    )
    start = truth([[-0.5, -0.5], [-0.4, -0.5]])  # both in cell (0, 0), 0.1 m apart: colliding
    task.reset(start, RNG, arena)
    assert task.coverage == 0.25
    np.testing.assert_allclose(task.rewards(start, np.zeros((2, 2))), [-0.1, -0.1])
    moved = truth([[0.5, -0.5], [-0.5, 0.5]])  # two new cells, 1.41 m apart
    np.testing.assert_allclose(task.rewards(moved, np.zeros((2, 2))), [2.0, 2.0])
    assert not task.terminated(moved)
    last = truth([[0.5, 0.5], [-0.5, 0.9]])  # one new cell; robot 1 is 0.1 m from the wall
    np.testing.assert_allclose(task.rewards(last, np.zeros((2, 2))), [1.0, 0.9])
    assert task.coverage == 1.0 and task.terminated(last)
    m = task.metrics()
    assert m["coverage"] == 1.0 and m["collision_rate"] == pytest.approx(3 / 6)


def layout(boxes=(), posts=(), reds=()) -> Layout:
    return Layout(
        posts_xy=np.asarray(posts, dtype=float).reshape(-1, 2),
        red_decoys_xy=np.asarray(reds, dtype=float).reshape(-1, 2),
        boxes=np.asarray(boxes, dtype=float).reshape(-1, 5),
    )


def test_obstacle_distances_hand_computed():
    # A 0.4 m square turned by 45 deg at the origin: its corners lie on the axes at 0.2 sqrt 2,
    # its faces 0.2 m from the centre along the diagonals. Post r = 0.03 at (1, 1), red decoy
    # r = 0.06 at (-1, 0).
    arena = ArenaConfig(width_m=3.0, height_m=3.0, decoy_post_radius_m=0.03)
    lay = layout(boxes=[[0, 0, 0.4, 0.4, math.pi / 4]], posts=[[1, 1]], reds=[[-1, 0]])
    xy = np.array([[0.4, 0.0], [0.3, 0.3], [0.0, 0.0], [1.0, 1.2]])
    d = obstacle_distances(xy, lay, arena)
    assert d.shape == (4, 3)
    # (1, 1.2) lies off the face whose normal is the diagonal: 2.2 / sqrt 2 along it.
    box = [0.4 - 0.2 * math.sqrt(2), 0.3 * math.sqrt(2) - 0.2, -0.2, 2.2 / math.sqrt(2) - 0.2]
    np.testing.assert_allclose(d[:, 0], box)
    post = np.array([math.hypot(0.6, 1), 0.7 * math.sqrt(2), math.sqrt(2), 0.2]) - 0.03
    np.testing.assert_allclose(d[:, 1], post)
    red = np.array([1.4, math.hypot(1.3, 0.3), 1.0, math.hypot(2, 1.2)]) - 0.06
    np.testing.assert_allclose(d[:, 2], red)
    # An empty layout has no columns and flags nothing.
    assert obstacle_distances(xy, layout(), arena).shape == (4, 0)
    assert not collisions(xy[:1], 0.3, arena, 0.16, layout=layout()).any()


def test_exploration_penalises_a_robot_against_a_box():
    # Box 0.4 x 0.2 m turned by 90 deg at (0.5, 0.5): it spans x in [0.4, 0.6], y in [0.3, 0.7].
    # Robot 0 is 0.1125 m (half a chassis length: pressed head-on) right of its face; robot 1 is
    # 0.25 m above it (clear of the 0.16 m margin); both far from walls and from each other.
    lay = layout(boxes=[[0.5, 0.5, 0.4, 0.2, math.pi / 2]])
    t = truth([[0.7125, 0.5], [0.5, 0.95]])
    np.testing.assert_allclose(
        obstacle_distances(t.poses[:, :2], lay, ARENA)[:, 0], [0.1125, 0.25]
    )
    task = ExplorationTask(collision_penalty=0.1, wall_margin_m=0.16)
    task.reset(t, RNG, ARENA, layout=lay)
    np.testing.assert_allclose(task.rewards(t, np.zeros((2, 2))), [-0.1, 0.0])
    assert task.metrics()["collision_rate"] == pytest.approx(1 / 2)
    # A post (r = 0.03) 0.15 m from robot 1's centre is 0.12 m from its surface: also a contact.
    task.reset(t, RNG, ARENA, layout=layout(posts=[[0.65, 0.95]]))
    np.testing.assert_allclose(task.rewards(t, np.zeros((2, 2))), [0.0, -0.1])


def test_exploration_collision_with_a_box_in_the_simulator():
    """The env's own layout (rotated boxes from ``SimWorld.layout``, passed to the task by
    ``env.reset``): a robot driven into a box until the physics stops it is penalised; 0.5 m
    away it is not."""
    env = parallel_env(
        "seed-lab",
        task="exploration",
        n_robots=1,
        observation="truth",
        localize=False,
        arena={"n_boxes": 1, "n_decoy_posts": 0, "n_red_decoys": 0},
    )
    env.reset(seed=0)
    lay, arena = env.world.layout, env.config.arena
    assert isinstance(lay, Layout) and lay.boxes.shape == (1, 5)
    np.testing.assert_allclose(obstacle_distances(lay.box_corners()[0], lay, arena), 0, atol=1e-9)
    # Start 0.5 m off the box face that looks most towards the arena centre, facing the box.
    cx, cy, sx, sy, yaw = lay.boxes[0]
    axes = [(yaw + k * math.pi / 2, (sx if k % 2 == 0 else sy) / 2) for k in range(4)]
    angle, half = max(axes, key=lambda a: -(cx * math.cos(a[0]) + cy * math.sin(a[0])))
    start = np.array([cx, cy]) + (half + 0.5) * np.array([math.cos(angle), math.sin(angle)])
    body = env.world.bodies[0]
    body.position, body.angle = tuple(start), angle + math.pi
    t = env.world.ground_truth()
    assert not collisions(t.poses[:, :2], 0.3, arena, env.task.wall_margin_m, layout=lay).any()
    # No manual task.reset: the env's reset must have handed the world's layout to the task.
    for _ in range(40):  # 4 s at 0.2 m/s: 0.8 m, more than the 0.5 m to the box
        _, rewards, *_ = env.step({"ugv_0": np.array([0.2, 0.0], dtype=np.float32)})
    gap = obstacle_distances(env.world.ground_truth().poses[:, :2], lay, arena)[0, 0]
    assert 0.08 < gap < env.task.wall_margin_m  # pressed: about half a chassis length
    assert rewards["ugv_0"] == pytest.approx(-env.task.collision_penalty)


# ------------------------------------------------------------------ encirclement rewards
def test_encirclement_reward_hand_computed():
    task = EncirclementTask(radius_m=0.6, gap_weight=0.5, path="static", beacon=False)
    ring = truth([[0.6, 0], [0, 0.6], [-0.6, 0], [0, -0.6]], extra=[[0.0, 0.0]])
    task.reset(ring, RNG, ARENA)
    np.testing.assert_allclose(task.rewards(ring, np.zeros((4, 2))), 0.0, atol=1e-12)
    # Three robots on a half circle: largest gap pi, even gap 2 pi / 3 -> spread 1/3.
    half = truth([[0.6, 0], [0, 0.6], [-0.6, 0]], extra=[[0.0, 0.0]])
    np.testing.assert_allclose(task.rewards(half, np.zeros((3, 2))), -0.5 / 3)
    # One robot 1 m away (error 0.4), four around: enclosed.
    far = truth([[1.0, 0], [0, 0.6], [-0.6, 0], [0, -0.6]], extra=[[0.0, 0.0]])
    np.testing.assert_allclose(task.rewards(far, np.zeros((4, 2))), [-0.4, 0, 0, 0], atol=1e-12)
    m = task.metrics()
    assert m["enclosed_fraction"] == pytest.approx(2 / 3)


def test_encirclement_beacon_is_the_intruder_in_the_agent_frame():
    task = EncirclementTask(
        beacon=True, beacon_range_std_m=0.0, beacon_bearing_std_deg=0.0, path="static"
    )
    t = truth([[1.0, 0.0]], yaw=[math.pi / 2], extra=[[0.0, 0.0]])
    task.reset(t, RNG, ARENA)
    r, valid, cos_b, sin_b, rho = task.features(1)[0]
    # The intruder is 1 m behind along world -x; the agent faces +y, so it is on its left.
    assert (r, valid, rho) == pytest.approx((0.6, 1.0, 1.0))
    assert (cos_b, sin_b) == pytest.approx((0.0, 1.0), abs=1e-12)
    # Range 0.3-4-5 triangle: intruder at (3.3, 4) seen from (0.3, 0) facing +x -> rho = 5 m.
    t = truth([[0.3, 0.0]], extra=[[3.3, 4.0]])
    task.rewards(t, np.zeros((1, 2)))
    np.testing.assert_allclose(task.features(1), [[0.6, 1.0, 0.6, 0.8, 5.0]], atol=1e-12)
    low, high = task.feature_bounds()
    assert task.n_features == len(low) == len(high) == 5
    assert np.all(task.features(1) >= low) and np.all(task.features(1) <= high)


def test_encirclement_beacon_is_flagged_invalid_without_truth():
    task = EncirclementTask(beacon=True, path="static")
    task.reset(None, RNG, ARENA)  # real robots without motion capture
    np.testing.assert_array_equal(task.features(3), [[0.6, 0.0, 0.0, 0.0, 0.0]] * 3)
    # A valid reading, then the truth disappears: the stale reading is not repeated.
    t = truth([[0.0, 0.0], [1.0, 0.0]], extra=[[0.5, 0.5]])
    task.reset(t, RNG, ARENA)
    assert np.all(task.features(2)[:, 1] == 1.0)
    task.rewards(None, np.zeros((2, 2)))
    np.testing.assert_array_equal(task.features(2), [[0.6, 0.0, 0.0, 0.0, 0.0]] * 2)
    # Truth without the intruder (no extra robot): no reading either.
    task.rewards(truth([[0.0, 0.0], [1.0, 0.0]]), np.zeros((2, 2)))
    np.testing.assert_array_equal(task.features(2), [[0.6, 0.0, 0.0, 0.0, 0.0]] * 2)
    assert EncirclementTask(beacon=False).features(2).shape == (2, 1)


def test_intruder_moves_on_its_loop_and_static_stays():
    static = EncirclementTask(path="static")
    static.reset(truth([[0, 0]], extra=[[1, 1]]), RNG, ARENA)
    np.testing.assert_array_equal(
        static.extra_commands(truth([[0, 0]], extra=[[1, 1]]), 0.1), [[0.0, 0.0]]
    )
    moving = EncirclementTask(path="circle", intruder_speed_mps=0.1)
    t = truth([[0, 0]], extra=[[0.75, 0.0]])
    moving.reset(t, RNG, ARENA)
    v, omega = moving.extra_commands(t, 0.1)[0]
    assert 0.0 < v <= 0.1 and abs(omega) <= 1.0


# ------------------------------------------------------------------ PettingZoo API per task
@pytest.mark.parametrize(
    "task, params",
    [
        ("formation", {}),
        ("formation", {"shape": "lattice", "spacing_m": 0.5}),
        ("exploration", {}),
        ("encirclement", {}),
        ("encirclement", {"beacon": False, "path": "static"}),
    ],
)
def test_parallel_api_per_task(task, params):
    env = parallel_env("seed-lab", task=task, task_params=params, max_steps=30)
    parallel_api_test(env, num_cycles=35)


def test_encirclement_env_has_an_intruder_the_sensors_see():
    env = parallel_env("seed-lab", task="encirclement", max_steps=20)
    env.reset(seed=0)
    for _ in range(5):
        env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
    t = env.last_world_step.truth
    assert t.extra_xy.shape == (1, 2)
    assert env.world.n_extra == 1


# ------------------------------------------------------------------ localization term
def _seen_truth(lidar, camera) -> GroundTruth:
    t = truth([[0, 0], [1, 0], [0, 1]])
    visible = {"lidar": np.asarray(lidar, bool), "camera": np.asarray(camera, bool)}
    return dataclasses.replace(t, visible=visible)


def test_unseen_fraction_hand_computed():
    from swarm_env.tasks.common import unseen_fraction

    # Robot 0 sees 1 with both sensors and 2 with the lidar only: 1 of 2 unseen -> 0.5.
    # Robot 1 sees both with both: 0. Robot 2 sees nobody with the camera: 1. The diagonal
    # (a robot "seeing itself") must not count.
    lidar = [[1, 1, 1], [1, 1, 1], [1, 1, 1]]
    camera = [[1, 1, 0], [1, 0, 1], [0, 0, 1]]
    np.testing.assert_allclose(unseen_fraction(_seen_truth(lidar, camera)), [0.5, 0.0, 1.0])
    # Without a visibility mask (motion capture) the nominal range masks are used.
    near = np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0]], bool)
    t = dataclasses.replace(
        truth([[0, 0], [1, 0], [5, 0]]), in_range={"lidar": near, "camera": near}
    )
    np.testing.assert_allclose(unseen_fraction(t), [0.5, 0.5, 1.0])
    assert unseen_fraction(truth([[0, 0]])).tolist() == [0.0]
    with pytest.raises(ValueError, match="lidar"):
        unseen_fraction(truth([[0, 0], [1, 0]]))


@pytest.mark.parametrize("name", ["formation", "exploration"])
def test_localization_term_subtracts_the_unseen_fraction(name):
    lidar = np.ones((3, 3), bool)
    camera = np.array([[1, 1, 0], [1, 0, 1], [0, 0, 1]], bool)
    t = _seen_truth(lidar, camera)
    plain, weighted = make_task(name), make_task(name, localization_weight=2.0)
    for task in (plain, weighted):
        task.reset(t, RNG, ARENA)
    base = plain.rewards(t, np.zeros((3, 2)))
    np.testing.assert_allclose(
        weighted.rewards(t, np.zeros((3, 2))), base - 2.0 * np.array([0.5, 0, 1])
    )
    assert weighted.metrics()["unseen_fraction"] == pytest.approx(0.5)
    assert "unseen_fraction" not in plain.metrics()  # off by default: metrics as before
    with pytest.raises(ValueError, match="localization_weight"):
        make_task(name, localization_weight=-1.0)


def test_localization_term_in_the_simulator():
    # The simulator's visibility masks reach the task: the term is in [0, w] per agent and the
    # reward differs from the plain task's by exactly -w * unseen_fraction.
    from swarm_env.tasks.common import unseen_fraction

    env = parallel_env(
        "lab-3m-4",
        task="formation",
        task_params={"localization_weight": 1.0},
        observation="truth",
        localize=False,
    )
    env.reset(seed=3)
    _, rewards, _, _, _ = env.step({a: np.array([0.1, 0.2]) for a in env.agents})
    t = env.last_world_step.truth
    shape_err, spacing_err = env.task.errors(t.poses[:, :2])
    expected = -(shape_err + env.task.spacing_weight * spacing_err) - unseen_fraction(t)
    np.testing.assert_allclose([rewards[a] for a in env.possible_agents], expected, rtol=1e-6)
    assert 0.0 <= env.task.metrics()["unseen_fraction"] <= 1.0


# ------------------------------------------------------------------ estimate term
def _table(rows_per_robot, width=3):
    """A padded (6, R, width) table and counts from per-robot ``[(w, x, y), ...]``."""
    table = np.zeros((6, len(rows_per_robot), width))
    counts = np.array([len(rows) for rows in rows_per_robot])
    for r, rows in enumerate(rows_per_robot):
        for k, (w, x, y) in enumerate(rows):
            table[:3, r, k] = w, x, y
    return table, counts


def _estimate_case():
    # Robots at (0, 0) yaw 0, (1, 0) yaw 0 and (0, 1) yaw pi/2. In robot 2's frame (x along
    # world +y), teammate 0 is at (-1, 0) and teammate 1 at (-1, -1).
    t = truth([[0, 0], [1, 0], [0, 1]], yaw=[0, 0, math.pi / 2])
    table, counts = _table(
        [
            # robot 0: teammate 1 exact; teammate 2 (0, 1) 0.4 m off -> 1 of 2 misplaced
            [(1.0, 1.0, 0.0), (1.0, 0.0, 1.4)],
            # robot 1: teammate 0 (-1, 0) only by a light component (0.05 <= 0.1), teammate 2
            # (-1, 1) exact -> 1 of 2
            [(0.05, -1.0, 0.0), (0.5, -1.0, 1.0)],
            # robot 2: 0.1 m and 0.25 m off -> none
            [(0.9, -1.0, 0.1), (1.0, -1.0, -1.25)],
        ]
    )
    table[:3, 1, 2] = 1.0, -1.0, 0.0  # past robot 1's count: padding, must not count
    return t, table, counts


def test_mislocalized_fraction_hand_computed():
    from swarm_env.tasks.localization_term import mislocalized_fraction

    t, table, counts = _estimate_case()
    np.testing.assert_allclose(mislocalized_fraction(t, table, counts), [0.5, 0.5, 0.0])
    # Extra task robots after the R filtered ones are not teammates.
    t_extra = dataclasses.replace(t, poses=np.r_[t.poses, [[0.5, 0.5, 0.0]]])
    np.testing.assert_allclose(mislocalized_fraction(t_extra, table, counts), [0.5, 0.5, 0.0])
    lone_table, lone_counts = _table([[]])
    assert mislocalized_fraction(truth([[0, 0]]), lone_table, lone_counts).tolist() == [0.0]


@pytest.mark.parametrize("name", ["formation", "exploration"])
def test_estimate_term_subtracts_the_mislocalized_fraction(name):
    t, table, counts = _estimate_case()
    plain = make_task(name)
    weighted = make_task(name, localization_weight=2.0, localization_term="estimate")
    assert weighted.needs_estimates and not plain.needs_estimates
    assert not make_task(name, localization_term="estimate").needs_estimates  # weight 0: off
    for task in (plain, weighted):
        task.reset(t, RNG, ARENA)
    base = plain.rewards(t, np.zeros((3, 2)))
    weighted.observe_estimates(table, counts)
    np.testing.assert_allclose(
        weighted.rewards(t, np.zeros((3, 2))), base - 2.0 * np.array([0.5, 0.5, 0.0])
    )
    assert weighted.metrics()["mislocalized_fraction"] == pytest.approx(1 / 3)
    assert "unseen_fraction" not in weighted.metrics()
    # Each reward needs this step's estimate: a stale one is refused, not reused.
    with pytest.raises(RuntimeError, match="estimate"):
        weighted.rewards(t, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="localization_term"):
        make_task(name, localization_weight=1.0, localization_term="gospa")


def test_estimate_term_in_the_simulator():
    # The env hands its localizer's tables to the task after the update: the reward is the
    # plain task's minus w * the fraction the robot's own PHD misplaces.
    from swarm_env.tasks.localization_term import mislocalized_fraction

    params = {"localization_weight": 1.0, "localization_term": "estimate"}
    env = parallel_env("lab-3m-4", task="formation", task_params=params)
    env.reset(seed=3)
    for _ in range(20):
        _, rewards, _, _, _ = env.step({a: np.array([0.1, 0.2]) for a in env.agents})
    t = env.last_world_step.truth
    shape_err, spacing_err = env.task.errors(t.poses[:, :2])
    lost = mislocalized_fraction(t, *env.localizer.padded_tables())
    expected = -(shape_err + env.task.spacing_weight * spacing_err) - lost
    np.testing.assert_allclose([rewards[a] for a in env.possible_agents], expected, rtol=1e-5)
    assert 0.0 <= env.task.metrics()["mislocalized_fraction"] <= 1.0
    with pytest.raises(ValueError, match="localize=False"):
        parallel_env(
            "lab-3m-4", task="formation", task_params=params, observation="truth", localize=False
        )
