"""``swarm-phd mutual``: Stegagno 2012's mutual localization in the simulator, with the radio on.

Every robot (or ``--observer``) runs the chosen method(s) (``p-multireg``, ``fastslam``,
``p-multibeareg``: :mod:`localization.mutual`) on its own wheel odometry, its own
anonymous lidar detections (P-MultiBeaReg: its camera's bearings, or with ``--bearings lidar``
the lidar detections' bearings) and what its teammates broadcast (their dead-reckoned odometry
and their anonymous detections and camera bearings, :mod:`swarm_env.comms`), and estimates
every teammate's relative pose. ``--no-scale-search``: P-MultiBeaReg's scale-free fitness test
instead of eq. 18's scale search (with ``--bearings lidar``, the first figures).
The estimates are scored against the simulator's ground truth with the thesis's metrics
(tables 2-5): % of time with distance error < 0.1 m, bearing error < 7 deg, orientation error
< 7 deg, plus RMSE and the time to the first correct estimate / registration.

Scenarios (``--scenario``), after the thesis's experiments on 4 Khepera III in a 3.7 m x 1.9 m
arena (chapter 9); here 4 robots in ``lab-3m-4``'s 3 m x 3 m arena:

- ``square`` (Table 2): the robots start on a 1 m square (rotationally symmetric: ambiguous),
  three stand still and ``ugv_3`` drives one closed circle and stops where it started;
- ``lattice`` (Table 3): a 2 x 3 lattice of the 4 robots and 2 robot-like decoy posts (the
  thesis's "deceiving obstacles"), symmetric of order 2, everyone wanders;
- ``square-wander`` (Table 3 without the lattice): the square start, everyone wanders, with the
  arena's two decoy posts and red decoy at random places;
- ``kidnap`` (Table 4): a random (non-ambiguous) start, everyone wanders, ``ugv_3`` is moved to a
  random free place at half time without its odometry noticing;
- ``partial`` (Table 5): a clustered start at the left of a 6 m x 3 m arena, scripted waypoints
  (:data:`PARTIAL_WAYPOINTS`) that keep ``ugv_2`` and ``ugv_3`` beyond the thesis's lidar range
  (4.095 m) from ``ugv_0`` for about 100 s;
- ``wander``: any ``--preset`` (e.g. ``sim-6m-20``), random start, everyone wanders.

``--compare phd-lc,id-phd`` runs registry localizers on the same feed, scored alike.

``--symmetry`` runs instead the anti-symmetry experiment of chapter 12.1 (the law of
:class:`agents.scripted.AntiSymmetryPolicy` against random motion, see
:func:`symmetry_experiment` and :func:`symmetry_sim_experiment`).

Scenario setup moves the simulated bodies directly (:func:`_place`: the start formation and the
kidnapping, through the SimWorld's pymunk bodies; :func:`_place_posts`: the lattice's posts,
through the SimWorld's layout and space).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from localization.mutual.pmultireg import PMultiRegConfig, PMultiRegLocalizer
from localization.mutual.se2 import inverse_compose
from swarm_core import inputs
from swarm_core.geometry import wrap_angle
from swarm_core.inputs import parse_seeds

#: The thesis's thresholds (tables 2-5).
DIST_THRESHOLD_M = 0.10
ANGLE_THRESHOLD_DEG = 7.0
SCENARIOS = ("square", "lattice", "square-wander", "kidnap", "partial", "wander")
METHODS = ("p-multireg", "fastslam", "p-multibeareg")
#: The registry's names of the methods (``swarm-phd evaluate --localizer``), accepted here too.
ALIASES = {"fastslam-mc": "fastslam"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=SCENARIOS, default="square")
    parser.add_argument(
        "--methods", default="p-multireg,fastslam", help=f"comma-separated, from {METHODS}"
    )
    parser.add_argument("--preset", default=None, help="env preset (default: lab-3m-4)")
    parser.add_argument("--observer", default=None, help="one observer (default: every robot)")
    parser.add_argument("--duration", type=float, default=None, help="simulated seconds")
    parser.add_argument("--speed", type=float, default=0.1, help="robots' max speed (m/s)")
    parser.add_argument("--seeds", default="0", help="comma-separated integers or ranges (0-4)")
    parser.add_argument(
        "--particles", type=int, default=None, help="per filter, >= 2 (default: each method's)"
    )
    parser.add_argument("--loss", type=float, default=0.1, help="radio loss probability")
    parser.add_argument("--latency", type=float, default=0.05, help="radio latency (s)")
    parser.add_argument(
        "--compare",
        default="",
        help="comma-separated registry localizers (e.g. phd-lc,id-phd) run on the same feed "
        "and scored alike (orientation only where they estimate it)",
    )
    parser.add_argument(
        "--bearings",
        choices=("camera", "lidar"),
        default="camera",
        help="P-MultiBeaReg's feature sets: the camera's red-blob bearings (default) or the "
        "lidar detections' bearings (the thesis's experiment)",
    )
    parser.add_argument(
        "--no-scale-search",
        action="store_true",
        help="P-MultiBeaReg: the scale-free fitness test instead of eq. 18's scale search "
        "(with --bearings lidar: the first figures)",
    )
    parser.add_argument("--out", default=None, help="write metrics.json here")
    parser.add_argument(
        "--symmetry",
        action="store_true",
        help="run the anti-symmetry vs random-motion experiment (ch. 12) instead",
    )


def run(args: argparse.Namespace) -> int:
    seeds = parse_seeds(str(args.seeds))
    if args.duration is not None:
        inputs.duration("--duration", args.duration)
    if args.particles is not None:  # every method's filter needs two (its config's minimum)
        inputs.integer("--particles", args.particles, minimum=2)
    if args.out:
        inputs.output_dir("--out", args.out)
    if args.symmetry:
        result = symmetry_experiment(seeds=seeds)
        sim = symmetry_sim_experiment(seeds=seeds)
        result["formations"].update(sim["formations"])
        result["sim"] = {k: sim[k] for k in ("alpha_mps", "duration_s")}
        print_symmetry(result)
    else:
        methods = tuple(
            ALIASES.get(m.strip(), m.strip()) for m in str(args.methods).split(",") if m.strip()
        )
        compare = tuple(c.strip() for c in str(args.compare).split(",") if c.strip())
        result = run_mutual(
            scenario=args.scenario,
            methods=methods,
            seeds=seeds,
            preset=args.preset,
            observer=args.observer,
            duration_s=args.duration,
            speed_mps=args.speed,
            n_particles=args.particles,
            loss=args.loss,
            latency_s=args.latency,
            compare=compare,
            bearing_features=args.bearings,
            scale_search=not args.no_scale_search,
        )
        print_table(result)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(json.dumps(result, indent=2))
        print(f"wrote {out / 'metrics.json'}")
    return 0


# ---------------------------------------------------------------------------------- scenarios
def _place(env, poses: np.ndarray) -> None:
    """Move the simulated robots to ``poses`` (N, 3) (world frame), at rest. Their odometry does
    not notice: this is how a scenario sets a start formation, and how kidnapping happens."""
    env.world.place_robots(poses)


def _square_start(rng: np.random.Generator, side_m: float = 1.0) -> np.ndarray:
    """Four poses on a square of side ``side_m`` about the origin; ``ugv_3`` faces outwards along
    the diagonal (its circle then stays clear of the others), the others at random yaws."""
    h = 0.5 * side_m
    xy = np.array([[-h, -h], [h, -h], [-h, h], [h, h]])
    yaw = rng.uniform(-np.pi, np.pi, 4)
    yaw[3] = math.atan2(xy[3, 1], xy[3, 0])
    return np.column_stack([xy, yaw])


#: Table 3's lattice: 2 x 3 points this far apart (m), 4 robots and 2 posts.
LATTICE_SPACING_M = 0.8


def _lattice(spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Table 3's start (the thesis's second experiment): a 2 x 3 lattice (rotationally
    symmetric, order 2) of four robots, completed by two robot-like posts (the "deceiving
    obstacles") on the two lattice points opposite each other through the centre. Robots (4, 2)
    and posts (2, 2), world frame."""
    s, h = spacing_m, 0.5 * spacing_m
    robots = np.array([[0.0, -h], [s, -h], [-s, h], [0.0, h]])
    posts = np.array([[-s, -h], [s, h]])
    return robots, posts


def _place_posts(env, posts_xy: np.ndarray) -> None:
    """Move the arena's decoy posts to ``posts_xy`` (P, 2) right after ``reset`` (the SimWorld's
    layout and pymunk space rebuilt with the robots where they are; the lidar reads the new
    static scene). Uses SimWorld internals: a scenario's staging, as :func:`_place`."""
    import dataclasses

    world = env.world
    posts_xy = np.asarray(posts_xy, dtype=np.float64).reshape(-1, 2)
    if posts_xy.shape != world.layout.posts_xy.shape:
        raise ValueError(f"posts_xy must be {world.layout.posts_xy.shape}, got {posts_xy.shape}")
    world.layout = dataclasses.replace(world.layout, posts_xy=posts_xy)
    poses = np.array([[b.position.x, b.position.y, b.angle] for b in world.bodies])
    world._build_space(poses)
    world._static_scene = world._static_geometry()
    world._scene_cache = {}


#: Table 5 (the thesis's fourth experiment): the team starts clustered at the left of a
#: 6 m x 3 m arena and crosses it; world frame (m).
PARTIAL_START_XY = np.array([[-2.2, 0.4], [-2.2, -0.4], [-2.7, 0.6], [-2.7, -0.6]])
#: Per robot: ``(from time s, goal x, goal y)``. ``ugv_0`` (the thesis's A_1) and ``ugv_1``
#: (A_2) cross to the right end; ``ugv_2`` and ``ugv_3`` (A_3, A_4) go back to the left end at
#: 60 s. From 90 to 150 s all four keep moving at their ends (so that odometry drifts, as the
#: thesis's robots did), more than 4.1 m (the lidar's range) from the other end; then
#: ``ugv_2`` and ``ugv_3`` come back (the thesis: out of sight between 120 and 220 s).
PARTIAL_WAYPOINTS = (
    ((0.0, -0.5, 0.4), (50.0, 2.2, 0.3), (90.0, 2.3, 1.0), (110.0, 2.2, -0.2), (130.0, 2.3, 0.8),
     (170.0, 1.0, 0.4)),
    ((0.0, -0.9, -0.4), (50.0, 1.9, -0.5), (90.0, 2.0, -1.1), (110.0, 1.9, -0.6),
     (130.0, 2.0, -1.0), (170.0, 0.6, -0.6)),
    ((0.0, -1.4, 0.9), (60.0, -2.5, 0.9), (90.0, -2.6, 0.3), (110.0, -2.5, 1.1),
     (130.0, -2.6, 0.4), (150.0, 0.2, 1.0)),
    ((0.0, -1.5, -0.9), (60.0, -2.5, -1.0), (90.0, -2.6, -0.4), (110.0, -2.5, -1.2),
     (130.0, -2.6, -0.5), (150.0, -0.2, -1.0)),
)  # fmt: skip


def _partial_actions(env, ids, time_s: float, speed_mps: float) -> dict[str, np.ndarray]:
    """Drive each robot to its current waypoint (:data:`PARTIAL_WAYPOINTS`), as the thesis's
    operator did: turn toward it (gain 2 /s, at most 0.6 rad/s), advance at ``speed_mps``
    times the cosine of the heading error, stop within 5 cm."""
    poses = env.last_world_step.truth.poses
    out = {}
    for k, a in enumerate(ids):
        goal = [w for w in PARTIAL_WAYPOINTS[k] if w[0] <= time_s + 1e-9][-1]
        dx, dy = goal[1] - poses[k, 0], goal[2] - poses[k, 1]
        if math.hypot(dx, dy) < 0.05:
            out[a] = np.zeros(2, np.float32)
            continue
        e = float(wrap_angle(math.atan2(dy, dx) - poses[k, 2]))
        v = speed_mps * max(0.0, math.cos(e))
        out[a] = np.array([v, float(np.clip(2.0 * e, -0.6, 0.6))], np.float32)
    return out


def _make_methods(
    methods: tuple[str, ...],
    ids: tuple[str, ...],
    observers,
    n_particles,
    seed: int,
    bearing_features: str = "camera",
    scale_search: bool = True,
) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    sized = {} if n_particles is None else {"n_particles": n_particles}  # None: each default
    for m_idx, m in enumerate(methods):
        if m not in METHODS:
            raise ValueError(f"--methods: {m!r} is not one of {METHODS}")
        out[m] = {}
        for o_idx, obs in enumerate(observers):
            rng = np.random.default_rng([seed, 1001, m_idx, o_idx])
            if m == "p-multireg":
                cfg = PMultiRegConfig(**sized)
                out[m][obs] = PMultiRegLocalizer(obs, ids, cfg, rng)
            elif m == "fastslam":
                from localization.mutual.fastslam import FastSLAMConfig, FastSLAMLocalizer

                cfg = FastSLAMConfig(**sized)
                out[m][obs] = FastSLAMLocalizer(obs, ids, cfg, rng)
            else:
                from localization.mutual.pmultibeareg import (
                    PMultiBeaRegConfig,
                    PMultiBeaRegLocalizer,
                )

                cfg = PMultiBeaRegConfig(
                    **sized,
                    features=bearing_features,
                    scale_search=scale_search,
                )
                out[m][obs] = PMultiBeaRegLocalizer(obs, ids, cfg, rng)
    return out


def run_episode(
    scenario: str,
    methods: tuple[str, ...],
    seed: int,
    preset: str | None = None,
    observer: str | None = None,
    duration_s: float | None = None,
    speed_mps: float = 0.1,
    n_particles: int | None = None,
    loss: float = 0.1,
    latency_s: float = 0.05,
    compare: tuple[str, ...] = (),
    bearing_features: str = "camera",
    scale_search: bool = True,
) -> dict[str, Any]:
    """One episode; returns per method, observer and teammate the error traces' summaries.

    ``bearing_features`` (``"camera"`` or ``"lidar"``) and ``scale_search``: P-MultiBeaReg's
    feature source and eq. 18's scale search (:class:`PMultiBeaRegConfig`).

    ``compare``: registry localizers (``phd-lc``, ``id-phd``, ...) run on the same
    :class:`~localization.feed.SwarmFeed` and scored alike: a localizer with identities by its
    estimate of each teammate (orientation where it has one), an anonymous one by its extracted
    estimate nearest to the teammate (distance and bearing only)."""
    from agents.scripted import WanderPolicy
    from localization.feed import SwarmFeed
    from localization.registry import LOCALIZERS, make_localizer
    from swarm_env.env import SwarmEnv

    if scenario not in SCENARIOS:
        raise ValueError(f"scenario must be one of {SCENARIOS}, got {scenario!r}")
    methods = tuple(ALIASES.get(m, m) for m in methods)
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"--methods: {m!r} is not one of {METHODS}")
    for c in compare:
        if c not in LOCALIZERS:
            raise ValueError(f"--compare: {c!r} is not one of {sorted(LOCALIZERS)}")
        if c in methods or compare.count(c) > 1:
            raise ValueError(f"--compare: {c!r} is named twice (--methods runs it already)")
    if not (math.isfinite(speed_mps) and speed_mps > 0):
        raise ValueError(f"speed must be > 0 m/s, got {speed_mps!r}")
    defaults = {
        "square": 60.0,
        "lattice": 120.0,
        "square-wander": 120.0,
        "kidnap": 120.0,
        "partial": 220.0,
        "wander": 60.0,
    }
    duration_s = defaults[scenario] if duration_s is None else float(duration_s)
    inputs.duration("--duration", duration_s)
    overrides: dict[str, Any] = {
        "comms": {"enabled": True, "loss_probability": loss, "latency_s": latency_s},
        "observation": "truth",
        "localize": False,
        "max_steps": int(round(duration_s / 0.05)) + 10,
    }
    if scenario != "wander":
        preset = preset or "lab-3m-4"
        overrides["n_robots"] = 4
        if scenario == "square":  # the thesis's first experiment has no deceiving obstacles
            overrides["arena"] = {"n_decoy_posts": 0, "n_red_decoys": 0, "n_boxes": 0}
        elif scenario == "lattice":  # two robot-like posts complete the lattice (placed below)
            overrides["arena"] = {"n_decoy_posts": 2, "n_red_decoys": 0, "n_boxes": 0}
        elif scenario == "partial":
            # A 6 m x 3 m arena crossed from left to right, and the thesis's lidar (Hokuyo
            # URG-04LX: 4.095 m range), so that robots at opposite ends do not see each other;
            # no posts, which both ends could see and register through.
            overrides["arena"] = {
                "width_m": 6.0,
                "height_m": 3.0,
                "n_decoy_posts": 0,
                "n_red_decoys": 0,
                "n_boxes": 0,
            }
            overrides["lidar"] = {"range_max_m": 4.095}
    env = SwarmEnv(preset or "lab-3m-4", **overrides)
    dt = env.config.control_period_s
    n_steps = inputs.steps_in(env, "--duration", duration_s)
    ids = tuple(env.possible_agents)
    observers = ids if observer is None else (observer,)
    if observer is not None and observer not in ids:
        raise ValueError(f"observer must be one of {ids}, got {observer!r}")
    filters = _make_methods(
        tuple(methods), ids, observers, n_particles, seed, bearing_features, scale_search
    )
    others = {c: make_localizer(c, len(ids), env.config.phd, seed) for c in compare}
    range_m = env.config.localization_range_m
    # Turn rate capped as for the IR-UKF study's small robots (0.6 rad/s): the Khepera III of the
    # thesis are slow, and the scans being compared are up to a lidar period apart.
    policy = WanderPolicy(
        max_speed_mps=speed_mps, max_turn_rate_radps=0.6, avoid_distance_m=0.35, seed=seed
    )
    obs, infos = env.reset(seed=seed)
    rng = np.random.default_rng([seed, 77])
    if scenario in ("square", "square-wander"):
        _place(env, _square_start(rng))
    elif scenario == "lattice":
        robots_xy, posts_xy = _lattice(LATTICE_SPACING_M)
        _place_posts(env, posts_xy)
        _place(env, np.column_stack([robots_xy, rng.uniform(-np.pi, np.pi, 4)]))
    elif scenario == "partial":
        _place(env, np.column_stack([PARTIAL_START_XY, rng.uniform(-0.3, 0.3, 4)]))
    kidnap_step = n_steps // 2 if scenario == "kidnap" else -1
    # Circle of ugv_3 (square): starts at 5 s, one full turn of radius 0.3 m at speed_mps.
    circle_r = 0.3
    circle_t = 2 * math.pi * circle_r / speed_mps
    names = [(m, o, t) for m in [*filters, *others] for o in observers for t in ids if t != o]
    err = {key: {"d": [], "b": [], "o": [], "t": [], "r": []} for key in names}
    first_reg: dict[tuple, float] = {}
    cost_s = {m: 0.0 for m in [*filters, *others]}
    kidnap_s = math.nan
    for k in range(n_steps):
        t_now = k * dt
        if scenario == "square":
            actions = {a: np.zeros(2, np.float32) for a in ids}
            if 5.0 <= t_now < 5.0 + circle_t:
                actions[ids[3]] = np.array([speed_mps, speed_mps / circle_r], np.float32)
        elif scenario == "partial":
            actions = _partial_actions(env, ids, t_now, speed_mps)
        else:
            actions = policy(obs, infos)
        if k == kidnap_step:
            poses = env.last_world_step.truth.poses.copy()
            free = env.config.arena.width_m * 0.35
            for _ in range(100):
                cand = rng.uniform(-free, free, 2)
                if np.min(np.hypot(*(poses[:, :2] - cand).T)) > 0.6:
                    break
            poses[3] = [cand[0], cand[1], rng.uniform(-np.pi, np.pi)]
            _place(env, poses)
            kidnap_s = t_now
        obs, _, _, _, infos = env.step(actions)
        step = env.last_world_step
        truth = step.truth.poses
        for m, per_obs in filters.items():
            t0 = time.perf_counter()
            for o, loc in per_obs.items():
                loc.step(step.time_s, step.measurements[o], step.comms.get(o, []))
            cost_s[m] += time.perf_counter() - t0
            for o, loc in per_obs.items():
                i = ids.index(o)
                est = loc.estimates()
                hyps = getattr(loc, "last_hypotheses", {})
                for t, e in est.items():
                    true_rel = inverse_compose(truth[ids.index(t)], truth[i])
                    _record(err[(m, o, t)], step.time_s, e, true_rel, range_m)
                    h = hyps.get(t)
                    if (m, o, t) not in first_reg and h is not None and len(h) == 1:
                        if _correct(h[0], true_rel):
                            first_reg[(m, o, t)] = step.time_s
        if others:
            feed = SwarmFeed.from_world_step(step, ids)
        for c, loc in others.items():
            t0 = time.perf_counter()
            loc.step(feed)
            cost_s[c] += time.perf_counter() - t0
            for o in observers:
                i = ids.index(o)
                known = loc.identities(i) if loc.has_identities else None
                means = None if loc.has_identities else loc.estimate(i)[0]
                for j, t in enumerate(ids):
                    if j == i:
                        continue
                    true_rel = inverse_compose(truth[j], truth[i])
                    if known is not None:
                        e = known.get(j)
                    elif len(means):  # anonymous: the extracted estimate nearest the teammate
                        e = means[np.argmin(np.hypot(*(means - true_rel[:2]).T))]
                    else:
                        e = None
                    _record(err[(c, o, t)], step.time_s, e, true_rel, range_m)
    env.close()
    out: dict[str, Any] = {
        "seed": seed,
        "scenario": scenario,
        "duration_s": duration_s,
        "kidnap_s": kidnap_s,
        "methods": {},
    }
    for m in [*filters, *others]:
        rows = {}
        for o in observers:
            for t in ids:
                if t == o:
                    continue
                rec = err[(m, o, t)]
                rows[f"{o}->{t}"] = _summary(rec, first_reg.get((m, o, t)), kidnap_s)
        out["methods"][m] = {
            "pairs": rows,
            "mean": _mean_rows(rows),
            # The compared localizers run every robot's filter: their cost is per robot.
            "cost_ms_per_step_per_observer": 1000.0
            * cost_s[m]
            / n_steps
            / (len(ids) if m in others else len(observers)),
        }
    return out


def _correct(pose: np.ndarray, true_rel: np.ndarray) -> bool:
    """A registration hypothesis within the thresholds: a pose ``(x, y, theta)`` within 0.1 m
    and 7 deg, or a bearing-orientation ``(bearing, theta)`` within 7 deg on both."""
    thr = math.radians(ANGLE_THRESHOLD_DEG)
    if len(pose) == 2:
        bearing = math.atan2(true_rel[1], true_rel[0])
        return bool(
            abs(float(wrap_angle(pose[0] - bearing))) < thr
            and abs(float(wrap_angle(pose[1] - true_rel[2]))) < thr
        )
    return bool(
        np.hypot(*(pose[:2] - true_rel[:2])) < DIST_THRESHOLD_M
        and abs(float(wrap_angle(pose[2] - true_rel[2]))) < thr
    )


def _record(rec: dict[str, list], time_s: float, e, true_rel: np.ndarray, range_m: float):
    """Append one step's errors of estimate ``e`` (``(x, y[, theta])`` or ``None``: no estimate
    counts as an error) against the true relative pose; ``o`` is ``nan`` for an estimate without
    a heading; ``r``: the teammate within ``range_m`` (the lidar tracking range)."""
    rec["t"].append(time_s)
    rec["r"].append(bool(np.hypot(*true_rel[:2]) <= range_m))
    if e is None:
        rec["d"].append(math.inf)
        rec["b"].append(math.pi)
        rec["o"].append(math.pi)
        return
    rec["d"].append(float(np.hypot(*(e[:2] - true_rel[:2]))))
    bearing = math.atan2(e[1], e[0]) - math.atan2(true_rel[1], true_rel[0])
    rec["b"].append(abs(float(wrap_angle(bearing))))
    rec["o"].append(abs(float(wrap_angle(e[2] - true_rel[2]))) if len(e) > 2 else math.nan)


def _summary(rec: dict[str, list[float]], first_reg_s: float | None, kidnap_s: float):
    d, b, o, t, r = (np.array(rec[k]) for k in ("d", "b", "o", "t", "r"))
    thr = math.radians(ANGLE_THRESHOLD_DEG)
    ok = np.isfinite(d)
    has_o = bool(np.isfinite(o[ok]).any())  # the localizer estimates headings
    good = ok & (d < DIST_THRESHOLD_M) & ((o < thr) if has_o else True)
    first = float(t[np.argmax(good)]) if good.any() else math.nan
    nan = math.nan
    row = {
        "pct_distance": 100.0 * float(np.mean(d < DIST_THRESHOLD_M)),
        "pct_bearing": 100.0 * float(np.mean(b < thr)),
        "pct_orientation": 100.0 * float(np.mean(o < thr)) if has_o else nan,
        # The same over the steps with the teammate within the lidar tracking range (2 m).
        "pct_distance_in_range": 100.0 * float(np.mean(d[r] < DIST_THRESHOLD_M))
        if r.any()
        else nan,
        "pct_bearing_in_range": 100.0 * float(np.mean(b[r] < thr)) if r.any() else nan,
        "pct_orientation_in_range": 100.0 * float(np.mean(o[r] < thr))
        if has_o and r.any()
        else nan,
        "rmse_distance_m": float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else math.nan,
        "rmse_bearing_deg": float(np.degrees(np.sqrt(np.mean(b[ok] ** 2))))
        if ok.any()
        else math.nan,
        "rmse_orientation_deg": float(np.degrees(np.sqrt(np.nanmean(o[ok] ** 2))))
        if ok.any() and has_o
        else math.nan,
        "first_correct_estimate_s": first,
        "first_correct_registration_s": math.nan if first_reg_s is None else first_reg_s,
    }
    if math.isfinite(kidnap_s):  # time to recover after the kidnapping
        after = t > kidnap_s + 0.05  # strictly after the kidnapped step (float clock)
        rec_ok = good & after
        row["recovery_s"] = float(t[np.argmax(rec_ok)] - kidnap_s) if rec_ok.any() else math.nan
    return row


def _nanmean(values: list[float]) -> float:
    """Mean of the finite values (``nan`` if none: e.g. a registration that never came)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else math.nan


def _mean_rows(rows: dict[str, dict[str, float]]) -> dict[str, float]:
    keys = next(iter(rows.values())).keys() if rows else []
    return {k: _nanmean([r[k] for r in rows.values()]) for k in keys}


def run_mutual(
    scenario: str,
    methods: tuple[str, ...],
    seeds: list[int],
    **kwargs: Any,
) -> dict[str, Any]:
    """Every seed's episode, and the mean over seeds of each method's mean row."""
    start = time.perf_counter()
    episodes = [run_episode(scenario, methods, s, **kwargs) for s in seeds]
    summary = {}
    methods = tuple(ALIASES.get(m, m) for m in methods)
    for m in [*methods, *kwargs.get("compare", ())]:
        rows = [e["methods"][m]["mean"] for e in episodes]
        summary[m] = {k: _nanmean([r[k] for r in rows]) for k in rows[0]}
        summary[m]["cost_ms_per_step_per_observer"] = float(
            np.mean([e["methods"][m]["cost_ms_per_step_per_observer"] for e in episodes])
        )
    return {
        "scenario": scenario,
        "seeds": seeds,
        "summary": summary,
        "episodes": episodes,
        "wall_s": time.perf_counter() - start,
    }


def print_table(result: dict[str, Any]) -> None:
    """Per method: the mean over observers, teammates and seeds, and per teammate of seed 0."""
    print(f"scenario {result['scenario']}, seeds {result['seeds']}")
    cols = [
        ("pct_distance", "%d<0.1m"),
        ("pct_bearing", "%b<7deg"),
        ("pct_orientation", "%o<7deg"),
        ("pct_distance_in_range", "%d rng2m"),
        ("rmse_distance_m", "RMSE m"),
        ("rmse_bearing_deg", "RMSE b deg"),
        ("rmse_orientation_deg", "RMSE o deg"),
        ("first_correct_estimate_s", "1st est s"),
        ("first_correct_registration_s", "1st reg s"),
    ]
    head = f"{'method / pair':<22}" + "".join(f"{c[1]:>11}" for c in cols)
    print(head)
    ep = result["episodes"][0]
    for m, s in result["summary"].items():
        print(f"{m + ' (mean)':<22}" + "".join(f"{s.get(k, math.nan):>11.2f}" for k, _ in cols))
        for pair, row in ep["methods"][m]["pairs"].items():
            print(
                f"{'  ' + pair:<22}" + "".join(f"{row.get(k, math.nan):>11.2f}" for k, _ in cols)
            )
        print(f"  cost {s['cost_ms_per_step_per_observer']:.2f} ms per env step per observer")
    print(f"wall time {result['wall_s']:.1f} s")


# ---------------------------------------------------------------------------------- chapter 12
#: Symmetric start formations of the anti-symmetry experiment: name -> (points (n, 2), order l).
def _formations(spacing_m: float) -> dict[str, np.ndarray]:
    ang6 = np.arange(6) * np.pi / 3
    return {
        # The thesis's 9-robot lattice, proper symmetry group G_4 (Fig. 53).
        "lattice-3x3": spacing_m
        * np.array([[i, j] for i in (-1, 0, 1) for j in (-1, 0, 1)], float),
        # Its G_6 case (Fig. 56): a regular hexagon with a robot at the centre.
        "hexagon+centre": np.vstack(
            [[0.0, 0.0], spacing_m * np.column_stack([np.cos(ang6), np.sin(ang6)])]
        ),
        # The four robots of the thesis's experiments on a square (G_4).
        "square": spacing_m * np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]),
    }


def symmetry_experiment(
    seeds: list[int],
    alpha_mps: float = 0.1,
    dt_s: float = 0.1,
    duration_s: float = 10.0,
    spacing_m: float = 0.8,
    broken_m2: tuple[float, ...] = (0.01, 0.04),
    turn_std_rad: float = 0.3,
    formations: tuple[str, ...] | None = None,
) -> dict[str, Any]:
    """Anti-symmetry law versus random motion, from rotationally symmetric starts (ch. 12.1).

    As in the thesis, the robots are omnidirectional points (``z_dot = u``) at speed
    ``alpha_mps``. Under the **law**, each robot's velocity is what
    :class:`agents.scripted.AntiSymmetryPolicy` (eq. 46, robot-centric) commands from its true
    neighbours expressed in its own (randomly oriented) frame; when the law is undefined (an
    exactly symmetric set) it moves in a random direction, as the thesis prescribes. Under
    **random** motion each robot keeps a random heading that turns by ``N(0, turn_std_rad)``
    per step (a persistent random walk at the same speed: a fair, fast-spreading competitor).

    The symmetry measure is the internal minimum of ``gamma_Z`` per robot,
    ``gamma_min / n`` (m^2, :func:`agents.scripted.internal_minimum`); the formation counts as
    broken once it exceeds a threshold of ``broken_m2`` (0.01 m^2: the best internal rotation
    leaves the points 0.1 m RMS from the set, P-MultiReg's inlier gate; 0.04 m^2: 0.2 m, the
    policy's own stop level). Returns, per formation and law, the time to each threshold
    (``nan`` if not within ``duration_s``) and ``gamma_min / n`` at the end, per seed.
    """
    from agents.scripted import TABLE_COLUMNS, AntiSymmetryPolicy, internal_minimum
    from swarm_env.observation import ESTIMATE_COLUMNS

    col = {c: ESTIMATE_COLUMNS.index(c) for c in ESTIMATE_COLUMNS}
    n_steps = int(round(duration_s / dt_s))
    out: dict[str, Any] = {
        "alpha_mps": alpha_mps,
        "duration_s": duration_s,
        "broken_m2": list(broken_m2),
        "seeds": seeds,
        "formations": {},
    }
    starts = _formations(spacing_m)
    for name in formations or tuple(starts):
        if name not in starts:
            raise ValueError(f"formation must be one of {tuple(starts)}, got {name!r}")
        start = starts[name]
        n = len(start)
        res: dict[str, dict[str, list[float]]] = {}
        for law in ("anti-symmetry", "random"):
            t_break: dict[str, list[float]] = {str(b): [] for b in broken_m2}
            final = []
            for seed in seeds:
                rng = np.random.default_rng([seed, 12])
                yaw = rng.uniform(-np.pi, np.pi, n)  # each robot's own frame
                heading = rng.uniform(-np.pi, np.pi, n)
                pos = start.copy()
                policy = AntiSymmetryPolicy(
                    max_speed_mps=alpha_mps, alpha_mps=alpha_mps, gamma_stop_m2=None, seed=seed
                )
                broke = {b: math.nan for b in broken_m2}
                for k in range(n_steps):
                    if law == "anti-symmetry":
                        vel = np.zeros((n, 2))
                        for i in range(n):  # one policy call per robot, as on the robots
                            c, s = math.cos(yaw[i]), math.sin(yaw[i])
                            rel = (pos - pos[i]) @ np.array([[c, -s], [s, c]])
                            rel = np.delete(rel, i, axis=0)
                            table = np.zeros((n - 1, TABLE_COLUMNS))
                            table[:, col["w"]] = 1.0
                            table[:, [col["x_m"], col["y_m"]]] = rel
                            table[:, col["sxx_m2"]] = table[:, col["syy_m2"]] = 1e-3
                            table[:, col["valid"]] = 1.0
                            u = policy.desired_velocity(f"r{i}", table, None, None)
                            vel[i] = np.array([[c, -s], [s, c]]) @ u
                    else:
                        heading += turn_std_rad * rng.standard_normal(n)
                        vel = alpha_mps * np.column_stack([np.cos(heading), np.sin(heading)])
                    pos = pos + dt_s * vel
                    _, g = internal_minimum(pos)
                    for b in broken_m2:
                        if math.isnan(broke[b]) and g / n >= b:
                            broke[b] = (k + 1) * dt_s
                for b in broken_m2:
                    t_break[str(b)].append(broke[b])
                final.append(internal_minimum(pos)[1] / n)
            res[law] = {"time_to_break_s": t_break, "final_gamma_per_robot_m2": final}
        out["formations"][name] = res
    return out


def print_symmetry(result: dict[str, Any]) -> None:
    print(
        f"anti-symmetry law vs random motion: speed {result['alpha_mps']} m/s, "
        f"{result['duration_s']} s, seeds {result['seeds']}; time until gamma_min/n >= b"
    )
    head = "".join(f"{f'broken@{b}':>13}{'median s':>10}" for b in result["broken_m2"])
    print(f"{'formation':<16}{'law':<15}{head}{'end gamma/n':>13}")
    for name, res in result["formations"].items():
        for law, r in res.items():
            line = f"{name:<16}{law:<15}"
            for b in result["broken_m2"]:
                t = np.array(r["time_to_break_s"][str(b)])
                ok = np.isfinite(t)
                med = float(np.median(np.where(ok, t, np.inf)))
                line += f"{f'{ok.sum()}/{len(t)}':>13}{med:>10.1f}"
            print(line + f"{np.mean(r['final_gamma_per_robot_m2']):>13.4f}")
    if "sim" in result:
        print(
            f"'square (sim)': simulated UGVs at {result['sim']['alpha_mps']} m/s for "
            f"{result['sim']['duration_s']} s, the law against the project's wander policy"
        )


def symmetry_sim_experiment(
    seeds: list[int],
    speed_mps: float = 0.1,
    duration_s: float = 20.0,
    broken_m2: tuple[float, ...] = (0.01, 0.04),
) -> dict[str, Any]:
    """The same comparison in the simulator: four differential-drive UGVs on a 1 m square
    (``lab-3m-4``, no decoys), each driven by :class:`agents.scripted.AntiSymmetryPolicy` on its
    true neighbours (``observation="truth"``, never stopping) or by the project's
    :class:`agents.scripted.WanderPolicy` cruising at the same speed. Measure: ``gamma_min / n``
    of the true positions, as in :func:`symmetry_experiment`."""
    from agents.scripted import AntiSymmetryPolicy, WanderPolicy, internal_minimum
    from swarm_env.env import SwarmEnv

    out: dict[str, Any] = {
        "alpha_mps": speed_mps,
        "duration_s": duration_s,
        "broken_m2": list(broken_m2),
        "seeds": seeds,
        "formations": {},
    }
    res: dict[str, Any] = {}
    for law in ("anti-symmetry", "wander"):
        t_break: dict[str, list[float]] = {str(b): [] for b in broken_m2}
        final = []
        for seed in seeds:
            env = SwarmEnv(
                "lab-3m-4",
                n_robots=4,
                observation="truth",
                localize=False,
                arena={"n_decoy_posts": 0, "n_red_decoys": 0, "n_boxes": 0},
                max_steps=int(round(duration_s / 0.05)) + 10,
            )
            if law == "anti-symmetry":
                policy = AntiSymmetryPolicy.for_env(
                    env, alpha_mps=speed_mps, gamma_stop_m2=None, seed=seed
                )
            else:  # cruises at 0.6 of its max speed: the same speed as the law
                policy = WanderPolicy(
                    max_speed_mps=speed_mps / 0.6, max_turn_rate_radps=0.6, seed=seed
                )
            env.reset(seed=seed)
            _place(env, _square_start(np.random.default_rng([seed, 77])))
            obs, _, _, _, infos = env.step({a: np.zeros(2, np.float32) for a in env.agents})
            broke = {b: math.nan for b in broken_m2}
            n_steps = int(round(duration_s / env.config.control_period_s))
            g = 0.0
            for k in range(n_steps):
                obs, _, _, _, infos = env.step(policy(obs, infos))
                xy = env.last_world_step.truth.poses[:, :2]
                g = internal_minimum(xy)[1] / len(xy)
                for b in broken_m2:
                    if math.isnan(broke[b]) and g >= b:
                        broke[b] = (k + 1) * env.config.control_period_s
            env.close()
            for b in broken_m2:
                t_break[str(b)].append(broke[b])
            final.append(g)
        res[law] = {"time_to_break_s": t_break, "final_gamma_per_robot_m2": final}
    out["formations"]["square (sim)"] = res
    return out
