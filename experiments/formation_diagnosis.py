"""Where the scripted formation controller's error comes from, and which teammates it loses.

``scripted:formation`` steers each robot to the circle around the swarm's centroid *as the
robot estimates it* (:func:`agents.scripted.estimated_centroid` over the confident components
of its own PHD table). This tool runs that controller (or ``--policy``) on the PHD observation
and, for every robot and step from ``--from-step`` on (the settled formation), compares:

- each true teammate's position with the nearest confident component (how well the robot
  localizes its teammates);
- the controller's centroid estimate with the true centroid (both in the robot's body frame);
- the same estimate from only the components that sit on a true teammate (within
  ``--match-m``; an oracle no robot has), with the controller's weights and with weight 1,
  each by the controller's own centroid rule (:func:`centroid_estimates`: a ``*-known-n``
  controller's oracle also scales its weights to the swarm size);
- every confident component that sits on no teammate, by what it sits on
  (:func:`classify_components`): a decoy post, a red decoy, a wall, or nothing known;
- every **lost** teammate (no confident component within ``--match-m`` of it): whether it is
  beyond the lidar's range (the filter's range factor of ``P_d`` below 0.5), whether the camera
  reported a blob on its bearing that step, and what holds that bearing instead
  (:func:`bearing_holder`): the confident component nearest the bearing within
  ``--bearing-window-deg``, classified as above and in front of the teammate or behind, or none.
  A decoy post on the bearing is the case a bearing-only camera cannot undo: the lidar reports
  the post as a housing, the teammate behind it lends it every camera frame, and the teammate's
  own bearing is then explained, so no track starts behind the post;
- every teammate within the lidar's range, on one of its blind sectors (the filter's own
  blind-sector factor below 0.5 at the true bearing: behind a camera pillar) or in its view: how
  often each is lost, and how often the lidar detects it against how often the filter expects
  it to (:class:`LostTeammateTally`);
- each robot's signed radial error ``||p_i - c|| - r`` against the true centroid (positive:
  outside the circle), and the confident components' weight sums, raw and after the
  controller's spread discount, by how many there are: a weight sum below the teammates in
  sight shrinks the controller's centroid towards the robot and parks it outside the circle
  (the ``*-known-n`` controllers rescale it);
- every lidar scan against the truth at its own instant (``sensor_stats``): how often a
  teammate within the localization range (2 m) was missed, and why (hidden from the beams,
  nulled by interference, or dropped by the extractor:
  :data:`~swarm_env.world.diagnostics.LIDAR_MISS_CAUSES`).

``--policy`` runs another of :data:`FORMATION_CONTROLLERS` instead: e.g.
``scripted:formation-sensing`` turns its blind sectors off its teammates, the ``*-known-n``
ones scale their centroid to the swarm size. It also runs a learned residual on one of them
(a recurrent student ``.pt`` or a residual ``.zip``), in the env it was trained in: the
estimate is read, and the centroid estimated, as its base controller does, while the learned
policy drives. ``commands`` summarises how each policy drives over the scored steps (mean
speed, turn rate and the turn rate's change per step): what its motion does to the sensors.

    python -m experiments.formation_diagnosis --preset lab-3m-4 --seeds 200-204 --from-step 150 \
        --out runs/diagnosis/formation.json

Prints its tables; ``--out`` writes them as a JSON summary.
"""

from __future__ import annotations

import argparse
import inspect
import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.scripted import estimated_neighbours, split_observation
from localization.detection import DetectionModel
from localization.mixture import ROW_W, ROW_X, ROW_Y
from swarm_core.geometry import wrap_angle
from swarm_core.world import relative_positions
from swarm_env.world.diagnostics import LIDAR_MISS_CAUSES, SensorStats

KINDS = ("post", "red_decoy", "wall", "other")
#: The controllers the diagnosis can run (it reads their estimate the way they do).
FORMATION_CONTROLLERS = (
    "scripted:formation",
    "scripted:formation-sensing",
    "scripted:formation-sensing-hold",
    "scripted:formation-known-n",
    "scripted:formation-sensing-known-n",
    "scripted:formation-sensing-hold-known-n",
    "scripted:formation-known-n-fast",
)
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


def bearing_holder(
    teammate_body: np.ndarray, components_body: np.ndarray, bearing_window_rad: float
) -> int:
    """Index of the component whose bearing is nearest the teammate's, among those within
    ``bearing_window_rad`` (in (0, pi]) of it, or -1: what holds a lost teammate's bearing.

    ``teammate_body`` (2,) and ``components_body`` (M, 2) are in the observer's body frame (m)."""
    if not 0.0 < bearing_window_rad <= np.pi:
        raise ValueError(f"bearing_window_rad must be in (0, pi], got {bearing_window_rad}")
    components_body = np.asarray(components_body, dtype=float).reshape(-1, 2)
    if not len(components_body):
        return -1
    offset = np.abs(
        wrap_angle(
            np.arctan2(components_body[:, 1], components_body[:, 0])
            - np.arctan2(teammate_body[1], teammate_body[0])
        )
    )
    nearest = int(np.argmin(offset))
    return nearest if offset[nearest] <= bearing_window_rad else -1


class LostTeammateTally:
    """Counts, over observer-steps, the teammates each observer lost (what holds their
    bearing, how far they are, whether the camera saw them) and the teammates within its
    lidar's range (on a blind sector or in view: lost how often, detected how often against
    the filter's ``P_d``, and the blind-sector factor measured against the filter's by bearing
    offset from the nearest sector centre). See the module doc; :meth:`summary` gives the
    shares.

    "Within the lidar's range" is the filter's own range factor of ``P_d`` at least 0.5
    (:meth:`~localization.detection.DetectionModel.lidar_range_factor`); "on a blind sector" its
    blind-sector factor below 0.5 at the teammate's true bearing."""

    GROUPS = ("blind", "in_view")
    #: Bins of a teammate's bearing offset from the nearest blind-sector centre (deg).
    OFFSET_BINS_DEG = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 180.0)

    def __init__(
        self, detection: DetectionModel, match_m: float, bearing_window_rad: float
    ) -> None:
        self.detection = detection
        self.match_m = match_m
        self.bearing_window_rad = bearing_window_rad
        self.lost = dict.fromkeys(LOST_CAUSES, 0)
        self.lost_beyond_range = dict.fromkeys(LOST_CAUSES, 0)
        self.lost_holder_in_front = dict.fromkeys(LOST_CAUSES, 0)
        self.lost_camera_seen = 0
        self.in_range = dict.fromkeys(self.GROUPS, 0)
        self.in_range_lost = dict.fromkeys(self.GROUPS, 0)
        self.scans = dict.fromkeys(self.GROUPS, 0)
        self.predicted_detections = dict.fromkeys(self.GROUPS, 0.0)
        self.predicted_with_nulls = dict.fromkeys(self.GROUPS, 0.0)
        self.detections = dict.fromkeys(self.GROUPS, 0)
        # Per offset bin: sum over scans of P_range, of P_range * P_blind, and detections.
        n_bins = len(self.OFFSET_BINS_DEG) - 1
        self.offset_range_weight = np.zeros(n_bins)
        self.offset_predicted = np.zeros(n_bins)
        self.offset_detections = np.zeros(n_bins)
        self._centres_rad = np.radians(np.asarray(detection.config.lidar.blind_sector_centers_deg))

    def add(
        self,
        teammates_body: np.ndarray,
        lost: np.ndarray,
        components_body: np.ndarray,
        component_kinds: np.ndarray,
        info: dict[str, Any],
    ) -> None:
        """One observer-step: its teammates (K, 2) and which of them it lost (K,) bool, its
        confident components (M, 2) (all body frame, m) and their kinds (M,)
        (:func:`classify_components`), and its ``infos`` entry (the step's camera frames and
        lidar scans)."""
        ranges = np.hypot(teammates_body[:, 0], teammates_body[:, 1])
        p_range = self.detection.lidar_range_factor(ranges)
        bearings = np.arctan2(teammates_body[:, 1], teammates_body[:, 0])
        p_blind = self.detection.lidar_blind_sector_factor(bearings, ranges)
        p_d = p_range * p_blind  # a lone component at the true position, no nulls
        near = p_range >= 0.5
        scans = info["measurements"]["lidar"]
        # The filter's whole P_d (range, notch, occlusion among the teammates, and the
        # interference of each scan's null returns) for components of weight 1 at the true
        # positions: what the filter expects when its estimate is right.
        truth_table = components_at(teammates_body)
        detected = np.zeros(len(teammates_body), dtype=int)  # scans with a detection on each
        p_d_scans = np.zeros(len(teammates_body))  # sum over scans of the whole P_d
        for scan in scans:
            detected += _detected(scan["detections"], teammates_body, self.match_m)
            p_d_scans += self.detection.lidar(truth_table, np.asarray(scan["null_bearings_rad"]))
        if len(self._centres_rad) and len(scans):
            offset = np.degrees(
                np.min(np.abs(wrap_angle(bearings[:, None] - self._centres_rad[None, :])), axis=1)
            )
            bins = np.digitize(offset, self.OFFSET_BINS_DEG) - 1
            ok = near & (bins < len(self.offset_predicted))
            np.add.at(self.offset_range_weight, bins[ok], p_range[ok] * len(scans))
            np.add.at(self.offset_predicted, bins[ok], p_d[ok] * len(scans))
            np.add.at(self.offset_detections, bins[ok], detected[ok])
        for group, on in (("blind", near & (p_blind < 0.5)), ("in_view", near & (p_blind >= 0.5))):
            self.in_range[group] += int(on.sum())
            self.in_range_lost[group] += int((on & lost).sum())
            self.scans[group] += int(on.sum()) * len(scans)
            self.predicted_detections[group] += float(p_d[on].sum()) * len(scans)
            self.predicted_with_nulls[group] += float(p_d_scans[on].sum())
            self.detections[group] += int(detected[on].sum())
        for j in np.flatnonzero(lost):
            holder = bearing_holder(teammates_body[j], components_body, self.bearing_window_rad)
            cause = "none" if holder < 0 else str(component_kinds[holder])
            self.lost[cause] += 1
            self.lost_beyond_range[cause] += int(not near[j])
            self.lost_holder_in_front[cause] += int(
                holder >= 0 and np.hypot(*components_body[holder]) < ranges[j]
            )
            self.lost_camera_seen += int(
                _blob_on_bearing(info, teammates_body[j], self.bearing_window_rad)
            )

    def summary(self, observer_steps: int) -> dict[str, dict[str, Any]]:
        """``lost_teammates`` (per observer-step, and shares of the losses) and
        ``teammates_in_lidar_range`` (shares of the in-range teammate-steps; detections per
        scan, predicted by the filter's ``P_d`` of a lone component at the true position
        (range and notch), by its whole ``P_d`` at the true positions (also occlusion among
        the teammates and each scan's null returns), and measured: scans with an extracted
        detection within the match radius)."""
        n_lost = sum(self.lost.values())
        n_near = sum(self.in_range.values())
        weight = self.offset_range_weight
        by_cause = {k: max(1, v) for k, v in self.lost.items()}
        return {
            "lost_teammates": {
                "per_observer_step": n_lost / max(1, observer_steps),
                "beyond_lidar_range_share": sum(self.lost_beyond_range.values()) / max(1, n_lost),
                "camera_blob_on_bearing_share": self.lost_camera_seen / max(1, n_lost),
                "bearing_held_by_share": {k: v / max(1, n_lost) for k, v in self.lost.items()},
                "beyond_lidar_range_share_by_holder": {
                    k: v / by_cause[k] for k, v in self.lost_beyond_range.items()
                },
                "holder_in_front_share_by_holder": {
                    k: v / by_cause[k] for k, v in self.lost_holder_in_front.items()
                },
            },
            "teammates_in_lidar_range": {
                "lidar_range_m": _half_pd_range_m(self.detection),
                "per_observer_step": n_near / max(1, observer_steps),
                "on_blind_sector_share": self.in_range["blind"] / max(1, n_near),
                "lost_share": sum(self.in_range_lost.values()) / max(1, n_near),
                **{
                    f"lost_share_{where}": self.in_range_lost[g] / max(1, self.in_range[g])
                    for g, where in zip(self.GROUPS, ("on_blind_sector", "in_view"), strict=True)
                },
                "losses_on_blind_sector_share": self.in_range_lost["blind"]
                / max(1, sum(self.in_range_lost.values())),
                "lidar_pd_predicted_per_scan": {
                    g: self.predicted_detections[g] / max(1, self.scans[g]) for g in self.GROUPS
                },
                "lidar_pd_predicted_with_nulls_per_scan": {
                    g: self.predicted_with_nulls[g] / max(1, self.scans[g]) for g in self.GROUPS
                },
                "lidar_detected_per_scan": {
                    g: self.detections[g] / max(1, self.scans[g]) for g in self.GROUPS
                },
                # The blind-sector factor by bearing offset from the nearest sector centre:
                # measured (detections / sum of P_range over scans) and the filter's model.
                "blind_sector_factor_by_offset": {
                    "offset_bins_deg": list(self.OFFSET_BINS_DEG),
                    "measured": list(self.offset_detections / np.maximum(weight, 1e-12)),
                    "modelled": list(self.offset_predicted / np.maximum(weight, 1e-12)),
                    "scans_weighted_by_p_range": list(weight),
                },
            },
        }


def diagnose(
    preset: str | None,
    seeds: list[int],
    from_step: int,
    max_steps: int = 300,
    match_m: float = 0.15,
    observation: str | None = None,
    env_overrides: dict[str, Any] | None = None,
    bearing_window_deg: float = 3.0,
    policy: str = "scripted:formation",
) -> dict[str, Any]:
    """Run ``policy`` (one of :data:`FORMATION_CONTROLLERS`, or a ``.pt``/``.zip`` residual
    on one of them) on ``observation`` (``"phd"``, or ``"truth"`` as a check: every component
    is then a teammate; ``None``: a model's own, else ``"phd"``) for ``seeds``, in ``preset``
    (``None``: a model's own, else ``"lab-3m-4"``) with ``env_overrides`` (``parallel_env``
    keywords); the module doc's figures (medians and means in metres, counts per
    observer-step)."""
    from agents.policies import trained_policy_env
    from swarm_env import parallel_env

    learned = policy.endswith((".pt", ".zip"))
    if not learned and policy not in FORMATION_CONTROLLERS:
        raise ValueError(
            f"--policy must be one of {FORMATION_CONTROLLERS} or a .pt/.zip residual on one "
            f"of them, got {policy!r}"
        )
    if learned and not Path(policy).is_file():
        raise ValueError(f"--policy file {policy!r} does not exist")
    if observation not in (None, "phd", "truth"):
        raise ValueError(f"--observation must be 'phd' or 'truth', got {observation!r}")
    if not 0.0 < bearing_window_deg <= 180.0:
        raise ValueError(f"--bearing-window-deg must be in (0, 180], got {bearing_window_deg}")
    if not match_m > 0.0:
        raise ValueError(f"--match-m must be > 0, got {match_m}")
    if not 0 <= from_step < max_steps:
        raise ValueError(f"--from-step must be in [0, {max_steps}), got {from_step}")
    fixed = {"preset", "task", "observation", "max_steps", "sensor_stats"} & set(
        env_overrides or {}
    )
    if fixed:
        raise ValueError(
            f"--env-overrides may not set {sorted(fixed)}: the diagnosis sets them (use --preset, "
            "--observation, --max-steps; sensor_stats is always on)"
        )
    # A learned policy runs in the env it was trained in (its preset, robot count, observation
    # settings and task parameters); the diagnosis's own settings go on top.
    kwargs: dict[str, Any] = {"preset": preset or "lab-3m-4"}
    if learned:
        kwargs = trained_policy_env(policy, preset=preset) or {}  # with the model's own task
        if kwargs["task"] != "formation":
            raise ValueError(
                f"--policy {policy!r} was trained on task {kwargs['task']!r}; the diagnosis "
                "runs the formation task"
            )
        if kwargs["preset"] is None:  # saved without one: trained in parallel_env's default
            kwargs["preset"] = inspect.signature(parallel_env).parameters["preset"].default
    kwargs.update(env_overrides or {})
    kwargs.update(
        task="formation",
        observation=observation or kwargs.get("observation", "phd"),
        max_steps=max_steps,
        sensor_stats=True,  # the lidar's misses against the truth, by cause
    )
    if kwargs["observation"] not in ("phd", "truth"):
        raise ValueError(
            f"--policy {policy!r} reads observation {kwargs['observation']!r}; the diagnosis "
            "reads the PHD table (or the truth)"
        )
    if kwargs["observation"] == "phd":
        kwargs["localize"] = True  # a model trained on the truth was saved without filters
    env = parallel_env(**kwargs)
    try:
        return _diagnose_in(
            env,
            kwargs,
            policy,
            seeds,
            from_step,
            max_steps,
            match_m,
            env_overrides,
            bearing_window_deg,
        )
    finally:
        env.close()


def _diagnose_in(
    env: Any,
    kwargs: dict[str, Any],
    policy: str,
    seeds: list[int],
    from_step: int,
    max_steps: int,
    match_m: float,
    env_overrides: dict[str, Any] | None,
    bearing_window_deg: float,
) -> dict[str, Any]:
    """:func:`diagnose` in ``env``, built from ``kwargs``; the caller closes it."""
    from agents.policies import load_policy

    if env.task.shape != "circle":
        raise ValueError(
            f"the diagnosis scores the circle formation; task_params set shape={env.task.shape!r}"
        )
    driver = load_policy(policy, env)
    controller = estimate_reader(policy, driver)
    top_k, n_sectors, min_weight = controller.top_k, controller.n_sectors, controller.min_weight
    commands = _CommandTally(env.possible_agents)
    arena = env.config.arena
    half = (0.5 * arena.width_m, 0.5 * arena.height_m)
    errors: dict[str, list[float]] = {"controller": [], "oracle": [], "oracle_weight_1": []}
    teammate_errors: list[np.ndarray] = []
    counts = dict.fromkeys(KINDS, 0)
    formation: list[float] = []
    radial: list[np.ndarray] = []  # per step (N,): ||p_i - c|| - r, m
    # Per number of confident components: observer-steps, and their weight sums (raw, and
    # after the controller's spread discount).
    by_count: dict[int, list[float]] = {}
    observer_steps = 0
    tally = LostTeammateTally(
        DetectionModel(env.config.phd), match_m, np.radians(bearing_window_deg)
    )
    lidar_counts = dict.fromkeys(_lidar_count_keys(), 0)
    for seed in seeds:
        driver.reset(seed)
        obs, infos = env.reset(seed=seed)
        world_model = env.unwrapped.world
        layout = world_model.layout
        # The scans the scored observations read: those of the periods that end at steps
        # from_step .. max_steps - 1 (the last period's scans reach no scored observation).
        before = after = _lidar_counts(world_model.stats["lidar"])
        commands.new_episode()
        for t in range(max_steps):
            actions = driver(obs, infos)
            if t >= from_step:
                commands.add(actions)
            if t == from_step - 1:
                before = _lidar_counts(world_model.stats["lidar"])
            if t == max_steps - 1:
                after = _lidar_counts(world_model.stats["lidar"])
            if t >= from_step:
                truth = env.last_world_step.truth
                poses = truth.poses[: len(env.possible_agents)]
                centroid = relative_positions(poses, poses[:, :2].mean(axis=0, keepdims=True))
                bodies = relative_positions(poses, poses[:, :2])  # (N, N, 2): j in i's frame
                formation.append(float(env.task.errors(poses[:, :2])[0].mean()))
                radial.append(centroid_distance(poses) - env.task.radius_m)
                for i, agent in enumerate(env.possible_agents):
                    observer_steps += 1
                    table, _, features = split_observation(obs[agent], top_k, n_sectors)
                    pts, w = estimated_neighbours(table, min_weight, reference_variance_m2=0.02)
                    tally_row = by_count.setdefault(len(pts), [0, 0.0, 0.0])
                    tally_row[0] += 1
                    tally_row[1] += float(estimated_neighbours(table, min_weight)[1].sum())
                    tally_row[2] += float(w.sum())
                    c, s = np.cos(poses[i, 2]), np.sin(poses[i, 2])
                    world = poses[i, :2] + pts @ np.array([[c, s], [-s, c]])
                    others = np.delete(poses[:, :2], i, axis=0)
                    kind = classify_components(world, others, layout, half, match_m)
                    for k in KINDS:
                        counts[k] += int((kind == k).sum())
                    lost = np.ones(len(others), dtype=bool)
                    if len(world):
                        gap = np.linalg.norm(others[:, None, :] - world[None, :, :], axis=2)
                        teammate_errors.append(gap.min(axis=1))
                        lost = gap.min(axis=1) > match_m
                    mate = kind == "teammate"
                    tally.add(np.delete(bodies[i], i, axis=0), lost, pts, kind, infos[agent])
                    true_c = centroid[i, 0]
                    for name, value in centroid_estimates(
                        controller, pts, w, mate, features
                    ).items():
                        errors[name].append(float(np.linalg.norm(value - true_c)))
            obs, _, _, _, infos = env.step(actions)
        for key in lidar_counts:
            lidar_counts[key] += after[key] - before[key]
    in_range = max(1, lidar_counts["targets_in_range"])
    spurious = sum(counts.values())
    return {
        "preset": kwargs["preset"],
        "policy": policy,
        "observation": kwargs["observation"],
        "env_overrides": env_overrides or {},
        # the env as run: a model's own settings included
        "env_kwargs": {k: v for k, v in kwargs.items() if k != "sensor_stats"},
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
        "radial_error_m": _radial_summary(np.concatenate(radial or [np.zeros(0)])),
        "confident_components": {
            str(n): {
                "share": row[0] / max(1, observer_steps),
                "weight_sum": row[1] / row[0],
                "weight_sum_discounted": row[2] / row[0],
            }
            for n, row in sorted(by_count.items())
        },
        "spurious_per_observer_step": spurious / max(1, observer_steps),
        "spurious_share": {k: counts[k] / max(1, spurious) for k in KINDS},
        "observer_steps": observer_steps,
        "commands": commands.summary(),
        **tally.summary(observer_steps),
        # Every scan that the scored observations read, against the truth at its instant, all
        # bearings within the localization range (swarm_env.world.diagnostics): missed, and why.
        "lidar_scans_vs_truth": {
            "range_m": env.config.localization_range_m,
            "targets_in_range": lidar_counts["targets_in_range"],
            "missed_rate": lidar_counts["missed"] / in_range,
            "missed_rate_by_cause": {c: lidar_counts[c] / in_range for c in LIDAR_MISS_CAUSES},
        },
    }


def estimate_reader(spec: str, driver: Any) -> Any:
    """The scripted controller whose reading of the estimate the diagnosis uses: ``driver``
    itself for a scripted ``spec``, a learned residual's base controller for a model.
    ValueError if that is not one of :data:`FORMATION_CONTROLLERS`."""
    if spec in FORMATION_CONTROLLERS:
        return driver
    base = getattr(driver, "base", None)
    if base is None or base.spec not in FORMATION_CONTROLLERS:
        raise ValueError(
            f"--policy {spec!r} is not a residual on a formation controller (its base: "
            f"{getattr(base, 'spec', None)!r}; the diagnosis needs one of "
            f"{FORMATION_CONTROLLERS})"
        )
    return base.policy


class _CommandTally:
    """How a policy drives: per agent-step of the scored window, the magnitudes of its
    commanded speed (m/s), of its turn rate (rad/s) and of the turn rate's change from the
    agent's previous scored step (rad/s per control step)."""

    def __init__(self, agents: list[str]) -> None:
        self.agents = list(agents)
        self.v: list[np.ndarray] = []
        self.omega: list[np.ndarray] = []
        self.d_omega: list[np.ndarray] = []
        self.previous: np.ndarray | None = None

    def new_episode(self) -> None:
        self.previous = None

    def add(self, actions: dict[str, np.ndarray]) -> None:
        cmd = np.array([np.asarray(actions[a], dtype=np.float64) for a in self.agents])
        self.v.append(np.abs(cmd[:, 0]))
        self.omega.append(np.abs(cmd[:, 1]))
        if self.previous is not None:
            self.d_omega.append(np.abs(cmd[:, 1] - self.previous))
        self.previous = cmd[:, 1]

    def summary(self) -> dict[str, float]:
        def mean(parts: list[np.ndarray]) -> float:
            return float(np.concatenate(parts).mean()) if parts else float("nan")

        return {
            "mean_abs_speed_mps": mean(self.v),
            "mean_abs_turn_rate_radps": mean(self.omega),
            "mean_abs_turn_rate_change_radps": mean(self.d_omega),
        }


def centroid_estimates(
    controller: Any, points: np.ndarray, weights: np.ndarray, mate: np.ndarray, features: Any
) -> dict[str, np.ndarray]:
    """The robot's centroid estimate (2,) by ``controller``'s own rule
    (``controller.centroid``), from its confident components ``points`` (M, 2) with
    ``weights`` (M,) (``"controller"``), and from only those on a true teammate (``mate``, (M,)
    bool): with their weights (``"oracle"``) and with weight 1 (``"oracle_weight_1"``). A
    ``*-known-n`` controller's rule scales the weights to the swarm size, so its oracles do."""
    ones = np.ones(int(mate.sum()))
    return {
        "controller": controller.centroid(points, weights, features),
        "oracle": controller.centroid(points[mate], weights[mate], features),
        "oracle_weight_1": controller.centroid(points[mate], ones, features),
    }


def centroid_distance(poses: np.ndarray) -> np.ndarray:
    """Each robot's distance (N,) (m) to the swarm's true centroid; ``poses`` (N, 3)."""
    xy = poses[:, :2]
    return np.linalg.norm(xy - xy.mean(axis=0), axis=1)


def _radial_summary(signed: np.ndarray) -> dict[str, float]:
    """Signed radial errors (m) -> mean, median, mean of the absolute value (the formation
    error), and the 10th and 90th percentiles."""
    if not len(signed):
        return {}
    p10, p90 = np.percentile(signed, [10, 90])
    return {
        "signed_mean": float(signed.mean()),
        "median": float(np.median(signed)),
        "abs_mean": float(np.abs(signed).mean()),
        "p10": float(p10),
        "p90": float(p90),
    }


def _lidar_count_keys() -> tuple[str, ...]:
    return ("targets_in_range", "missed", *LIDAR_MISS_CAUSES)


def _lidar_counts(stats: SensorStats) -> dict[str, int]:
    """The running counts of the simulator's lidar statistics that the diagnosis differences."""
    return {
        "targets_in_range": stats.targets_in_range,
        "missed": stats.missed,
        **{c: stats.missed_by_cause.get(c, 0) for c in LIDAR_MISS_CAUSES},
    }


def components_at(points_body: np.ndarray) -> np.ndarray:
    """A filter's component table (6, K) with weight 1 and no spread at ``points_body``
    (K, 2) (body frame, m): a filter whose estimate is exactly right, for asking its detection
    model what it expects there."""
    table = np.zeros((6, len(points_body)))
    table[ROW_W] = 1.0
    table[[ROW_X, ROW_Y]] = np.asarray(points_body, dtype=float).T
    return table


def _detected(detections: np.ndarray, points: np.ndarray, match_m: float) -> np.ndarray:
    """(K,) bool: whether one of a scan's extracted ``detections`` (D, 2) lies within
    ``match_m`` of each of ``points`` (K, 2) (both body frame, m)."""
    detections = np.asarray(detections, dtype=float).reshape(-1, 2)
    if not len(detections) or not len(points):
        return np.zeros(len(points), dtype=bool)
    gap = np.linalg.norm(points[:, None, :] - detections[None, :, :], axis=2)
    return gap.min(axis=1) <= match_m


def _half_pd_range_m(detection: DetectionModel) -> float:
    """The range (m, to 1 mm) beyond which the filter's lidar range factor falls below 0.5."""
    ranges = np.arange(0.0, 50.0, 0.001)
    below = np.flatnonzero(detection.lidar_range_factor(ranges) < 0.5)
    return float(ranges[below[0]]) if len(below) else float("inf")


def _blob_on_bearing(info: dict[str, Any], teammate_body: np.ndarray, window_rad: float) -> bool:
    """Whether a camera frame of this step reported a blob within ``window_rad`` of the
    teammate's bearing (``info["measurements"]["camera"]``: the step's frames, body frame)."""
    bearing = np.arctan2(teammate_body[1], teammate_body[0])
    for frame in info["measurements"].get("camera", ()):
        blobs = np.asarray(frame["bearings_rad"], dtype=float)
        if len(blobs) and np.min(np.abs(wrap_angle(blobs - bearing))) <= window_rad:
            return True
    return False


def main(argv: list[str] | None = None) -> int:
    from swarm_core.inputs import parse_json_object, parse_seeds

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default=None, help="default: a model's own, else lab-3m-4")
    parser.add_argument("--seeds", default="200-204")
    parser.add_argument("--from-step", type=int, default=150, help="first step scored")
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument("--match-m", type=float, default=0.15, help="'on a teammate' radius")
    parser.add_argument(
        "--observation",
        default=None,
        choices=["phd", "truth"],
        help="default: a model's own, else phd",
    )
    parser.add_argument(
        "--policy",
        default="scripted:formation",
        help=f"one of {', '.join(FORMATION_CONTROLLERS)}, or a .pt/.zip residual on one of them",
    )
    parser.add_argument(
        "--bearing-window-deg",
        type=float,
        default=3.0,
        help="a lost teammate's bearing is held by a component within this angle of it",
    )
    parser.add_argument(
        "--env-overrides",
        default=None,
        help='env keywords as JSON, e.g. \'{"phd": {"lidar": {"noise_std_m": 0.04}}}\'',
    )
    parser.add_argument("--out", default=None, help="JSON summary file")
    args = parser.parse_args(argv)
    try:
        summary = diagnose(
            args.preset,
            parse_seeds(args.seeds),
            from_step=args.from_step,
            max_steps=args.max_steps,
            match_m=args.match_m,
            observation=args.observation,
            env_overrides=parse_json_object(args.env_overrides, "--env-overrides"),
            bearing_window_deg=args.bearing_window_deg,
            policy=args.policy,
        )
    except ValueError as err:
        parser.error(str(err))
    print(json.dumps(summary, indent=2))
    if args.out:
        from swarm_core.atomic_files import write_json_atomically

        write_json_atomically(Path(args.out), summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
