"""Where the scripted formation controller's error comes from: its centroid estimate.

``scripted:formation`` steers each robot to the circle around the swarm's centroid *as the
robot estimates it* (:func:`agents.scripted.estimated_centroid` over the confident components
of its own PHD table). This tool runs that controller on the PHD observation and, for every
robot and step from ``--from-step`` on (the settled formation), compares:

- each true teammate's position with the nearest confident component (how well the robot
  localizes its teammates);
- the controller's centroid estimate with the true centroid (both in the robot's body frame);
- the same estimate from only the components that sit on a true teammate (within
  ``--match-m``; an oracle no robot has), with the controller's weights and with weight 1;
- every confident component that sits on no teammate, by what it sits on
  (:func:`classify_components`): a decoy post, a red decoy, a wall, or nothing known;
- every **lost** teammate (no confident component within ``--match-m`` of it): how far it is
  (beyond the lidar's tracking range or not), whether the camera reported a blob on its bearing
  that step, and what holds that bearing instead (:func:`lost_teammate_cause`): the confident
  component nearest the bearing within ``--bearing-window-deg``, classified as above, or none.
  A decoy post on the bearing is the case a bearing-only camera cannot undo: the lidar reports
  the post as a housing, the teammate behind it lends it every camera frame, and the teammate's
  own bearing is then explained, so no track starts behind the post;
- every teammate within the lidar's range, on one of its blind sectors (the filter's own
  blind-sector factor below 0.5 at the true bearing: behind a camera pillar) or in its view, and
  how often each is lost.

``--policy scripted:formation-sensing`` runs the controller that turns its blind sectors off
its teammates instead.

    python -m agents.formation_diagnosis --preset lab-3m-4 --seeds 200-204 --from-step 150

Figures of ``docs/results.md`` (rounds 3-6); a JSON summary with ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.scripted import (
    estimated_centroid,
    estimated_neighbours,
    lidar_blind_sector_factor,
    split_observation,
)
from swarm_core.world import relative_positions

KINDS = ("post", "red_decoy", "wall", "other")
#: The controllers the diagnosis can run (it reads their estimate the way they do).
FORMATION_CONTROLLERS = ("scripted:formation", "scripted:formation-sensing")
#: What holds a lost teammate's bearing: a confident component on one of :data:`KINDS`, on
#: another teammate, or no confident component at all.
LOST_CAUSES = ("teammate", *KINDS, "none")


def classify_components(
    world_xy: np.ndarray,
    teammates_xy: np.ndarray,
    layout: Any,
    arena_half_m: tuple[float, float],
    match_m: float = 0.15,
    object_m: float = 0.2,
) -> np.ndarray:
    """What each estimated component sits on, shape (M,) of strings.

    ``"teammate"`` within ``match_m`` of a true teammate (``teammates_xy`` (K, 2)); else
    ``"post"`` / ``"red_decoy"`` within ``object_m`` of one (``layout.posts_xy``,
    ``layout.red_decoys_xy``); else ``"wall"`` within ``object_m`` of the arena's walls
    (``|x| = arena_half_m[0]`` or ``|y| = arena_half_m[1]``); else ``"other"``. World frame,
    metres; ``world_xy`` (M, 2)."""
    world_xy = np.asarray(world_xy, dtype=float).reshape(-1, 2)

    def near(points: np.ndarray, radius: float) -> np.ndarray:
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if not len(points):
            return np.zeros(len(world_xy), dtype=bool)
        d = np.linalg.norm(world_xy[:, None, :] - points[None, :, :], axis=2)
        return d.min(axis=1) <= radius

    wall_gap = np.min(np.asarray(arena_half_m) - np.abs(world_xy), axis=1)
    kind = np.full(len(world_xy), "other", dtype=object)
    kind[wall_gap <= object_m] = "wall"
    kind[near(layout.red_decoys_xy, object_m)] = "red_decoy"
    kind[near(layout.posts_xy, object_m)] = "post"
    kind[near(teammates_xy, match_m)] = "teammate"
    return kind


def lost_teammate_cause(
    teammate_body: np.ndarray,
    components_body: np.ndarray,
    component_kinds: np.ndarray,
    bearing_window_rad: float,
) -> str:
    """What holds the bearing of a teammate the robot lost: the kind (one of
    :data:`LOST_CAUSES`) of the confident component whose bearing is nearest the teammate's,
    among those within ``bearing_window_rad`` of it, or ``"none"``.

    ``teammate_body`` (2,) and ``components_body`` (M, 2) are in the observer's body frame (m);
    ``component_kinds`` (M,) from :func:`classify_components` (``"teammate"`` there is another
    teammate: the lost one has no component within the match radius)."""
    components_body = np.asarray(components_body, dtype=float).reshape(-1, 2)
    if not len(components_body):
        return "none"
    bearing = np.arctan2(teammate_body[1], teammate_body[0])
    offset = np.abs(
        np.angle(np.exp(1j * (np.arctan2(components_body[:, 1], components_body[:, 0]) - bearing)))
    )
    nearest = int(np.argmin(offset))
    return str(component_kinds[nearest]) if offset[nearest] <= bearing_window_rad else "none"


def diagnose(
    preset: str,
    seeds: list[int],
    from_step: int,
    max_steps: int = 300,
    match_m: float = 0.15,
    observation: str = "phd",
    env_overrides: dict[str, Any] | None = None,
    bearing_window_deg: float = 3.0,
    policy: str = "scripted:formation",
) -> dict[str, Any]:
    """Run ``policy`` (a formation controller: ``scripted:formation`` or
    ``scripted:formation-sensing``) on ``observation`` (``"phd"``, or ``"truth"`` as a check:
    every component is then a teammate) for ``seeds``, in ``preset`` with ``env_overrides``
    (``parallel_env`` keywords); the module doc's figures (medians and means in metres, counts
    per observer-step)."""
    from agents.policies import load_policy
    from swarm_env import parallel_env

    if policy not in FORMATION_CONTROLLERS:
        raise ValueError(f"--policy must be one of {FORMATION_CONTROLLERS}, got {policy!r}")
    if not 0.0 < bearing_window_deg <= 180.0:
        raise ValueError(f"--bearing-window-deg must be in (0, 180], got {bearing_window_deg}")
    if not 0 <= from_step < max_steps:
        raise ValueError(f"--from-step must be in [0, {max_steps}), got {from_step}")
    fixed = {"preset", "task", "observation", "max_steps"} & set(env_overrides or {})
    if fixed:
        raise ValueError(
            f"--env-overrides may not set {sorted(fixed)}: the diagnosis sets them (use --preset, "
            "--observation, --max-steps)"
        )
    env = parallel_env(
        preset=preset,
        task="formation",
        observation=observation,
        max_steps=max_steps,
        **(env_overrides or {}),
    )
    controller = load_policy(policy, env)
    arena = env.config.arena
    half = (0.5 * arena.width_m, 0.5 * arena.height_m)
    errors: dict[str, list[float]] = {"controller": [], "oracle": [], "oracle_weight_1": []}
    teammate_errors: list[np.ndarray] = []
    counts = dict.fromkeys(KINDS, 0)
    formation: list[float] = []
    observer_steps = 0
    lost = dict.fromkeys(LOST_CAUSES, 0)
    lost_beyond_lidar = dict.fromkeys(LOST_CAUSES, 0)
    lost_camera_seen = 0
    lidar_range_m = env.config.phd.lidar_range_m
    # Teammates within the lidar's range: on a blind sector or in view, and lost or not.
    in_range = {"blind": 0, "in_view": 0}
    in_range_lost = {"blind": 0, "in_view": 0}
    window_rad = np.radians(bearing_window_deg)
    for seed in seeds:
        controller.reset(seed)
        obs, infos = env.reset(seed=seed)
        layout = env.unwrapped.world.layout
        for t in range(max_steps):
            actions = controller(obs, infos)
            if t >= from_step:
                truth = env.last_world_step.truth
                poses = truth.poses[: len(env.possible_agents)]
                centroid = relative_positions(poses, poses[:, :2].mean(axis=0, keepdims=True))
                formation.append(float(env.task.errors(poses[:, :2])[0].mean()))
                for i, agent in enumerate(env.possible_agents):
                    observer_steps += 1
                    table = split_observation(obs[agent], controller.top_k, controller.n_sectors)[
                        0
                    ]
                    pts, w = estimated_neighbours(
                        table, controller.min_weight, reference_variance_m2=0.02
                    )
                    c, s = np.cos(poses[i, 2]), np.sin(poses[i, 2])
                    world = poses[i, :2] + pts @ np.array([[c, s], [-s, c]])
                    others = np.delete(poses[:, :2], i, axis=0)
                    kind = classify_components(world, others, layout, half, match_m)
                    for k in KINDS:
                        counts[k] += int((kind == k).sum())
                    if len(world):
                        gap = np.linalg.norm(others[:, None, :] - world[None, :, :], axis=2)
                        teammate_errors.append(gap.min(axis=1))
                    mate = kind == "teammate"
                    teammates_body = (others - poses[i, :2]) @ np.array([[c, -s], [s, c]])
                    unmatched = _unmatched(teammates_body, pts, match_m)
                    near = np.hypot(*teammates_body.T) <= lidar_range_m
                    bearings = np.arctan2(teammates_body[:, 1], teammates_body[:, 0])
                    blind = lidar_blind_sector_factor(bearings, env.config.phd) < 0.5
                    for name, on in (("blind", near & blind), ("in_view", near & ~blind)):
                        in_range[name] += int(on.sum())
                        in_range_lost[name] += int((on & unmatched).sum())
                    for j in np.flatnonzero(unmatched):
                        cause = lost_teammate_cause(teammates_body[j], pts, kind, window_rad)
                        lost[cause] += 1
                        lost_beyond_lidar[cause] += int(not near[j])
                        lost_camera_seen += int(
                            _blob_on_bearing(infos[agent], teammates_body[j], window_rad)
                        )
                    true_c = centroid[i, 0]
                    for name, value in (
                        ("controller", estimated_centroid(pts, w)),
                        ("oracle", estimated_centroid(pts[mate], w[mate])),
                        ("oracle_weight_1", estimated_centroid(pts[mate], np.ones(mate.sum()))),
                    ):
                        errors[name].append(float(np.linalg.norm(value - true_c)))
            obs, _, _, _, infos = env.step(actions)
    env.close()
    spurious = sum(counts.values())
    n_lost = sum(lost.values())
    return {
        "preset": preset,
        "seeds": seeds,
        "from_step": from_step,
        "formation_error_m": float(np.mean(formation)),
        "teammate_error_m": {
            "median": float(np.median(np.concatenate(teammate_errors or [np.zeros(0)]))),
            "mean": float(np.mean(np.concatenate(teammate_errors or [np.zeros(0)]))),
        },
        "centroid_error_m": {
            name: {"median": float(np.median(v)), "mean": float(np.mean(v))}
            for name, v in errors.items()
        },
        "spurious_per_observer_step": spurious / max(1, observer_steps),
        "spurious_share": {k: counts[k] / max(1, spurious) for k in KINDS},
        "observer_steps": observer_steps,
        "lost_teammates": {
            "per_observer_step": n_lost / max(1, observer_steps),
            "beyond_lidar_range_share": sum(lost_beyond_lidar.values()) / max(1, n_lost),
            "camera_blob_on_bearing_share": lost_camera_seen / max(1, n_lost),
            "bearing_held_by_share": {k: lost[k] / max(1, n_lost) for k in LOST_CAUSES},
            "beyond_lidar_range_share_by_holder": {
                k: lost_beyond_lidar[k] / max(1, lost[k]) for k in LOST_CAUSES
            },
        },
        "teammates_in_lidar_range": {
            "on_blind_sector_share": in_range["blind"] / max(1, sum(in_range.values())),
            "lost_share_on_blind_sector": in_range_lost["blind"] / max(1, in_range["blind"]),
            "lost_share_in_view": in_range_lost["in_view"] / max(1, in_range["in_view"]),
            "lost_share": sum(in_range_lost.values()) / max(1, sum(in_range.values())),
            "losses_on_blind_sector_share": in_range_lost["blind"]
            / max(1, sum(in_range_lost.values())),
        },
    }


def _unmatched(teammates_body: np.ndarray, components_body: np.ndarray, match_m: float):
    """(K,) bool: teammates with no component within ``match_m`` (both body frame, m)."""
    if not len(components_body):
        return np.ones(len(teammates_body), dtype=bool)
    gap = np.linalg.norm(teammates_body[:, None, :] - components_body[None, :, :], axis=2)
    return gap.min(axis=1) > match_m


def _blob_on_bearing(info: dict[str, Any], teammate_body: np.ndarray, window_rad: float) -> bool:
    """Whether a camera frame of this step reported a blob within ``window_rad`` of the
    teammate's bearing (``info["measurements"]["camera"]``: the step's frames, body frame)."""
    bearing = np.arctan2(teammate_body[1], teammate_body[0])
    for frame in info["measurements"].get("camera", ()):
        blobs = np.asarray(frame["bearings_rad"], dtype=float)
        if len(blobs) and np.min(np.abs(np.angle(np.exp(1j * (blobs - bearing))))) <= window_rad:
            return True
    return False


def main(argv: list[str] | None = None) -> int:
    from swarm_phd.sweep import parse_json_object, parse_seeds

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="lab-3m-4")
    parser.add_argument("--seeds", default="200-204")
    parser.add_argument("--from-step", type=int, default=150, help="first step scored")
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument("--match-m", type=float, default=0.15, help="'on a teammate' radius")
    parser.add_argument("--observation", default="phd", choices=["phd", "truth"])
    parser.add_argument("--policy", default="scripted:formation", choices=FORMATION_CONTROLLERS)
    parser.add_argument(
        "--bearing-window-deg",
        type=float,
        default=3.0,
        help="a lost teammate's bearing is held by a component within this angle of it",
    )
    parser.add_argument(
        "--env-overrides",
        default=None,
        help='env keywords as JSON, e.g. \'{"phd": {"scan_evidence": true}}\'',
    )
    parser.add_argument("--out", default=None, help="JSON summary file")
    args = parser.parse_args(argv)
    summary = diagnose(
        args.preset,
        parse_seeds(args.seeds),
        args.from_step,
        args.max_steps,
        args.match_m,
        args.observation,
        parse_json_object(args.env_overrides, "--env-overrides"),
        args.bearing_window_deg,
        args.policy,
    )
    print(json.dumps(summary, indent=2))
    if args.out:
        from swarm_core.atomic_files import write_json_atomically

        write_json_atomically(Path(args.out), summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
