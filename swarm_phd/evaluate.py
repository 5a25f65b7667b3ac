"""``swarm-phd evaluate``: the seed's localization experiment, under scripted or learned motion.

Every robot runs its own filter, for each requested localizer at once (``phd-lc``: Lidar+Camera,
``phd-lo``: Lidar-Only, ``id-phd``: ID-PHD on the lidar with every teammate's odometry as radio
messages, ``ukf`` / ``pf``: the seed ``003`` / ``004`` baselines on identified range-bearing
detections), fed with the same records, so the comparison is paired: same motion,
same measurements. The motion comes from ``--policy`` (default ``scripted:wander``, the seed's
pseudo-random motion with obstacle avoidance; or ``random``, or a trained ``model.zip``).

Metrics (see :mod:`localization.metrics` and ``docs/localization.md``), per observer robot, over
every (step, neighbour within ``localization_range_m``) pair:

- ``pct_time_err_gt_30cm``: % of those pairs where the distance from the neighbour to the closest
  component with weight > 0.1 exceeds 0.30 m (the seed's Fig. 7);
- ``pct_time_within_10cm``: % within 0.10 m (the seed's ``001`` tables);
- ``gospa_mean``: mean GOSPA (c = 1 m, p = 2, alpha = 2) between the neighbours in range and the
  extracted estimates (weight >= 0.5) within the same range;
- ``cardinality_mae``: mean |sum of weights within range - true count in range| (Fig. 8).

The identity-aware localizers (``id-phd``, ``ukf``, ``pf``) also get an ``identity`` block: per
observer, over the same pairs, the error of *that neighbour's own ID estimate*
(:class:`IdentityScorer`). Their records: each robot's odometry records of the step stand for
the radio messages (every teammate's own increment with its ID); ``ukf`` and ``pf`` get each
lidar detection with the identity of the true robot within 0.2 m of it (an oracle standing in
for seed ``003``'s / ``004``'s identifying sensors; other detections are dropped).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from localization import IDPHD, IDPHDConfig, PHDBank, PHDConfig
from localization.baselines import ParticleFilterTracker, UKFTracker
from localization.metrics import LocalizationScorer, extract_estimates
from swarm_core.records import LidarRecord, OdometryRecord
from swarm_env import parallel_env
from swarm_env.env import SwarmEnv, localizer_calls

#: PHD localizers: the ``PHDConfig.mode`` each runs in (one ``PHDBank`` per localizer).
PHD_MODES = {"phd-lc": "lidar-camera", "phd-lo": "lidar-only"}
#: Identity-aware localizers: one instance per robot, fed by :class:`IdentityLocalizers`.
IDENTITY_LOCALIZERS = ("id-phd", "ukf", "pf")
LOCALIZERS = {
    **PHD_MODES,
    "id-phd": "ID-PHD (lidar + teammates' odometry)",
    "ukf": "seed 003 UKF (identified range-bearing)",
    "pf": "seed 004 particle filter (identified range-bearing)",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset", default=None, help="default: the model's preset for a model.zip, else seed-sim"
    )
    parser.add_argument("--duration", type=float, default=300.0, help="simulated seconds")
    parser.add_argument(
        "--localizer", default="phd-lc,phd-lo", help=f"comma-separated, from {sorted(LOCALIZERS)}"
    )
    parser.add_argument("--seeds", default="0", help="comma-separated integers")
    parser.add_argument(
        "--policy",
        default="scripted:wander",
        help="'scripted:NAME', 'random' or a trained model.zip",
    )
    parser.add_argument(
        "--task", default=None, help="default: the model's task for a model.zip, else 'wander'"
    )
    parser.add_argument(
        "--task-params",
        default=None,
        help="JSON dict of task parameters (default: the model's, else {})",
    )
    parser.add_argument(
        "--compare",
        default=None,
        help="a second policy run on the same env and seeds, reported side by "
        "side (e.g. --policy runs/X/model.zip --compare scripted:formation)",
    )
    parser.add_argument("--out", default=None, help="write metrics.json and figures here")


def run(args: argparse.Namespace) -> int:
    localizers = [s.strip() for s in args.localizer.split(",") if s.strip()]
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError as exc:
        raise ValueError(f"--seeds must be comma-separated integers, got {args.seeds!r}") from exc
    overrides: dict[str, Any] = {}
    if args.task_params is not None:
        try:
            overrides["task_params"] = json.loads(args.task_params)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--task-params must be a JSON object: {exc}") from exc
    out_dir = Path(args.out) if args.out else None
    results = evaluate_localization(
        args.preset,
        args.duration,
        localizers,
        seeds,
        policy=args.policy,
        task=args.task,
        out_dir=out_dir,
        **overrides,
    )
    print_table(results)
    if args.compare:
        shared = shared_env_kwargs(args.policy, args.preset, args.task, **overrides)
        other = evaluate_localization(
            shared.pop("preset"),
            args.duration,
            localizers,
            seeds,
            policy=args.compare,
            task=shared.pop("task"),
            out_dir=out_dir / "compare" if out_dir else None,
            **shared,
        )
        print_table(other)
        print_comparison([results, other])
        if out_dir is not None:
            (out_dir / "comparison.json").write_text(
                json.dumps(comparison_rows([results, other]), indent=2)
            )
    return 0


def shared_env_kwargs(
    policy: str, preset: str | None, task: str | None, **overrides: Any
) -> dict[str, Any]:
    """Preset, task, task parameters and config overrides of ``policy``'s evaluation env, minus
    the observation mode (each policy brings its own): what a ``--compare`` run must share."""
    kwargs: dict[str, Any] = {}
    if policy.endswith(".zip"):
        from agents.sb3.policy import read_metadata

        kwargs = dict(read_metadata(policy)["env_kwargs"])
    if task is not None and task != kwargs.get("task", task):
        kwargs.pop("task_params", None)  # the model's parameters belong to its own task
    kwargs.update(overrides)
    for key in ("observation", "localize"):
        kwargs.pop(key, None)
    kwargs["preset"] = preset or kwargs.get("preset") or "seed-sim"
    kwargs["task"] = task or kwargs.get("task") or "wander"
    return kwargs


def _make_env(preset: str | None, task: str | None, policy: str, **overrides: Any) -> SwarmEnv:
    if policy.endswith(".zip"):
        from agents.sb3.policy import read_metadata

        model = dict(read_metadata(policy)["env_kwargs"])
        model_preset = model.pop("preset", None)
        model_task = model.pop("task", "wander")
        model_params = model.pop("task_params", {})
        if task is None or task == model_task:  # the model's observation includes its task
            task = model_task
            model["task_params"] = model_params
        overrides = {**model, **overrides}
        preset = preset or model_preset
    else:
        from agents.policies import policy_observation

        observation = policy_observation(policy)
        if observation is None:
            # Policies that ignore the observation: skip the env's own filters, the evaluation
            # runs its own banks of filters below.
            overrides.setdefault("observation", "measurements")
            overrides.setdefault("localize", False)
        else:  # e.g. scripted:formation acts on the robot's own PHD estimate
            overrides.setdefault("observation", observation)
    return parallel_env(preset or "seed-sim", task=task or "wander", **overrides)


def evaluate_localization(
    preset: str,
    duration_s: float,
    localizers: list[str],
    seeds: list[int],
    policy: str = "scripted:wander",
    task: str = "wander",
    out_dir: Path | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Run the experiment; return (and optionally write) the metrics per localizer.

    Returns
    -------
    dict
        ``{"config": ..., "localizers": {name: {"pct_time_err_gt_30cm": {"per_robot": [...],
        "median": m, "max": M}, "pct_time_within_10cm": ..., "gospa_mean": g,
        "cardinality_mae": c}}, "task": {...}, "wall_time_s": ...}``
    """
    from agents.policies import load_policy

    unknown = [name for name in localizers if name not in LOCALIZERS]
    if unknown or not localizers:
        raise ValueError(f"--localizer must name some of {sorted(LOCALIZERS)}, got {localizers}")
    if duration_s <= 0:
        raise ValueError(f"duration must be > 0 s, got {duration_s}")
    start = time.perf_counter()
    env = _make_env(preset, task, policy, **overrides)
    n_steps = int(round(duration_s / env.config.control_period_s))
    base_phd = env.config.phd
    n_agents = len(env.possible_agents)
    scorers = {name: LocalizationScorer(env.config.n_robots) for name in localizers}
    id_scorers = {
        name: IdentityScorer(env.config.n_robots)
        for name in localizers
        if name in IDENTITY_LOCALIZERS
    }
    trace = {
        name: {"time_s": [], "weight_sum": [], "true_count": [], "gospa": []}
        for name in localizers
    }
    paths: list[np.ndarray] = []
    estimates: dict[str, list[np.ndarray]] = {name: [] for name in localizers}
    task_metrics: list[dict[str, float]] = []
    for seed in seeds:
        # One filter per robot and localizer, fed the same records (a paired comparison).
        banks = {
            name: PHDBank(dataclasses.replace(base_phd, mode=PHD_MODES[name]), n_agents)
            if name in PHD_MODES
            else IdentityLocalizers(name, n_agents, base_phd, seed)
            for name in localizers
        }
        act = load_policy(policy, env)
        if hasattr(act, "reset"):
            act.reset(seed)
        obs, infos = env.reset(seed=seed)
        for _ in range(n_steps):
            if not env.agents:
                break
            obs, _, _, _, infos = env.step(act(obs, infos))
            step = env.last_world_step
            truth = step.truth
            calls = [
                localizer_calls(step.measurements[agent], step.stale.get(agent, ()))
                for agent in env.possible_agents
            ]
            for name in localizers:
                bank = banks[name]
                if name in PHD_MODES:
                    bank.apply(calls)
                else:
                    bank.apply_step(step, env.possible_agents)
                views = bank.views
                for i in range(n_agents):
                    mask = truth.in_range["lidar"][i]
                    scorers[name].add(
                        i,
                        truth.relative_xy[i][mask],
                        views[i].mixture,
                        range_m=env.config.localization_range_m,
                    )
                    if name in id_scorers:
                        id_scorers[name].add(i, truth, mask, views[i].identities())
                if seed == seeds[0]:
                    _trace_step(trace[name], step, views, env.config.localization_range_m)
                    estimates[name].append(_world_estimates(views[0], truth.poses[0]))
            if seed == seeds[0]:
                paths.append(truth.poses[:, :2].copy())
        task_metrics.append(env.task.metrics())
    preset = preset or ("seed-sim" if not policy.endswith(".zip") else _model_preset(policy))
    task = env.task.name
    results = {
        "config": {
            "preset": preset,
            "duration_s": duration_s,
            "seeds": seeds,
            "policy": policy,
            "task": task,
            "n_robots": env.config.n_robots,
            "localization_range_m": env.config.localization_range_m,
        },
        "localizers": {name: scorers[name].summary() for name in localizers},
        **(
            {"identity": {name: sc.summary() for name, sc in id_scorers.items()}}
            if id_scorers
            else {}
        ),
        "task": _mean_dicts(task_metrics),
        "wall_time_s": time.perf_counter() - start,
    }
    env.close()
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "metrics.json").write_text(json.dumps(results, indent=2))
        from swarm_phd.figures import write_localization_figures

        write_localization_figures(out_dir, results, trace, np.array(paths), estimates)
    return results


def _model_preset(policy: str) -> str:
    from agents.sb3.policy import read_metadata

    return read_metadata(policy)["env_kwargs"].get("preset", "seed-sim")


def comparison_rows(all_results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per policy: its task metrics and each localizer's headline metrics."""
    rows = []
    for res in all_results:
        row: dict[str, Any] = {"policy": res["config"]["policy"], **res.get("task", {})}
        for name, m in res["localizers"].items():
            row[f"{name} % err>30cm (median)"] = m["pct_time_err_gt_30cm"]["median"]
            row[f"{name} GOSPA"] = m["gospa_mean"]
            row[f"{name} card. MAE"] = m["cardinality_mae"]
        rows.append(row)
    return rows


def print_comparison(all_results: list[dict[str, Any]]) -> None:
    """Task and localization metrics of several policies, side by side (markdown)."""
    rows = comparison_rows(all_results)
    keys = list(dict.fromkeys(k for row in rows for k in row if k != "policy"))
    print("  | metric | " + " | ".join(str(r["policy"]) for r in rows) + " |")
    print("  |---|" + "---|" * len(rows))
    for key in keys:
        cells = [
            f"{r[key]:.3f}" if isinstance(r.get(key), float) else str(r.get(key, "-"))
            for r in rows
        ]
        print(f"  | {key} | " + " | ".join(cells) + " |")


def _trace_step(trace: dict[str, list], step, bank, range_m: float):
    """Fig. 8 / GOSPA-over-time data for observer ugv_0."""
    from localization.metrics import gospa

    truth = step.truth
    mask = truth.in_range["lidar"][0]
    mixture = bank[0].mixture
    near = np.hypot(mixture.means[:, 0], mixture.means[:, 1]) <= range_m
    est, _ = bank[0].estimate(threshold=0.5)
    est = est[np.hypot(est[:, 0], est[:, 1]) <= range_m] if len(est) else est
    trace["time_s"].append(step.time_s)
    trace["weight_sum"].append(float(mixture.weights[near].sum()))
    trace["true_count"].append(int(mask.sum()))
    trace["gospa"].append(float(gospa(truth.relative_xy[0][mask], est).distance))


def _world_estimates(localizer, pose: np.ndarray) -> np.ndarray:
    est, _ = localizer.estimate(threshold=0.5)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return est @ np.array([[c, s], [-s, c]]) + pose[:2] if len(est) else np.zeros((0, 2))


def _mean_dicts(items: list[dict[str, float]]) -> dict[str, float]:
    keys = {k for d in items for k in d}
    return {k: float(np.mean([d[k] for d in items if k in d])) for k in sorted(keys)}


def print_table(results: dict[str, Any]) -> None:
    cfg = results["config"]
    print(
        f"  {cfg['preset']}, {cfg['n_robots']} robots, {cfg['duration_s']:.0f} s x "
        f"{len(cfg['seeds'])} seed(s), policy {cfg['policy']}, in range = "
        f"{cfg['localization_range_m']:.1f} m"
    )
    print(
        "  | localizer | % time err > 30 cm (median robot) | worst robot | robots > 25 % | "
        "% time < 10 cm | GOSPA mean | cardinality MAE |"
    )
    print("  |---|---|---|---|---|---|---|")
    for name, m in results["localizers"].items():
        per_robot = np.asarray(m["pct_time_err_gt_30cm"]["per_robot"], dtype=float)
        print(
            f"  | {name} | {m['pct_time_err_gt_30cm']['median']:.1f} | "
            f"{m['pct_time_err_gt_30cm']['max']:.1f} | {int((per_robot > 25).sum())} | "
            f"{m['pct_time_within_10cm']['median']:.1f} | {m['gospa_mean']:.3f} | "
            f"{m['cardinality_mae']:.2f} |"
        )
    print_identity_table(results)
    if results.get("task"):
        print("  task: " + ", ".join(f"{k} = {v:.3f}" for k, v in results["task"].items()))
    print(f"  wall time {results['wall_time_s']:.1f} s")


# ---------------------------------------------------------------------- identity localizers
#: A lidar detection within this distance of a true robot is attributed to it (oracle IDs).
ORACLE_GATE_M = 0.2
#: ``id-phd``'s lidar range ``P_d`` matched to the simulated lidar (docs/localization.md, "Notes
#: for the simulator"): with the seed's eq. 19 (``P_d ~ 0`` beyond 1.8 m, while the simulator
#: detects teammates to 3.5 m) and no camera update to pull them back, the weights of teammates
#: at 1.5-3 m grow towards ``1 / P_d`` (seed-sim, 40 s: weight sum 20.1 against 5.7 in range).
IDPHD_DETECTION_OVERRIDES = {"lidar_pd_midpoint_m": 3.0, "lidar_pd_slope_per_m": 4.0}


class _IdentityView:
    """What the scorer, the trace and the figures read of one robot's identity localizer."""

    __slots__ = ("localizer",)

    def __init__(self, localizer: Any) -> None:
        self.localizer = localizer

    @property
    def mixture(self):
        return self.localizer.mixture

    def estimate(self, threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        return extract_estimates(self.mixture, threshold), np.empty(0)

    def identities(self) -> dict[int, np.ndarray]:
        """``{robot index: (x, y[, psi])}`` in the observer frame (ID-PHD: the mean of each
        ID's highest-weight component, whatever its weight, as seed ``002`` defines the
        estimate; static class left out)."""
        loc = self.localizer
        if isinstance(loc, IDPHD):
            return {i: p for i, p in loc.estimate(min_weight=0.0).items() if i >= 0}
        return loc.estimate()


class IdentityLocalizers:
    """One identity-aware localizer per robot (``id-phd``, ``ukf`` or ``pf``), fed per step.

    Robot ``r``'s odometry records drive ``predict(own, {j: teammate j's record})`` (the
    simulated robots sample odometry in lockstep, so the k-th records of a step share a stamp);
    a robot whose odometry is stale sends no message. Lidar records go to ``update_lidar``
    (ID-PHD, anonymous) or, with oracle identities, to ``update({j: (range, bearing)})``.
    Camera records are not used.
    """

    def __init__(self, name: str, n_robots: int, phd: PHDConfig, seed: int = 0) -> None:
        if name not in IDENTITY_LOCALIZERS:
            raise ValueError(f"unknown identity localizer {name!r}")
        self.name = name
        if name == "id-phd":
            cfg = IDPHDConfig(
                detection=dataclasses.replace(phd, **IDPHD_DETECTION_OVERRIDES),
                lidar_noise_std_m=phd.lidar_noise_std_m,
                lidar_clutter_intensity_per_m2=phd.lidar_clutter_intensity,
            )
            self.localizers = [IDPHD(cfg) for _ in range(n_robots)]
        elif name == "ukf":
            self.localizers = [UKFTracker() for _ in range(n_robots)]
        else:
            self.localizers = [
                ParticleFilterTracker(seed=seed * 1000 + r) for r in range(n_robots)
            ]
        self.views = [_IdentityView(loc) for loc in self.localizers]

    def apply_step(self, step, agents: tuple[str, ...] | list[str]) -> None:
        records = [step.measurements[a] for a in agents]
        stale = [step.stale.get(a, ()) for a in agents]
        odometry = [
            [] if "odometry" in stale[r] else [rec.delta for rec in records[r].odometry]
            for r in range(len(agents))
        ]
        identified = self.name != "id-phd"
        for r, loc in enumerate(self.localizers):
            k_odo = 0
            for rec in records[r].in_time_order():
                if isinstance(rec, OdometryRecord):
                    if "odometry" in stale[r]:
                        continue
                    team = {
                        j: odometry[j][k_odo]
                        for j in range(len(agents))
                        if j != r and k_odo < len(odometry[j])
                    }
                    loc.predict(rec.delta, team)
                    k_odo += 1
                elif isinstance(rec, LidarRecord) and "lidar" not in stale[r]:
                    if identified:
                        loc.update(_oracle_range_bearing(rec.detections, step.truth, r))
                    else:
                        loc.update_lidar(rec.detections, rec.null_bearings_rad)


def _oracle_range_bearing(detections: np.ndarray, truth, observer: int) -> dict[int, np.ndarray]:
    """Each detection within :data:`ORACLE_GATE_M` of a true robot, as ``{id: (r, bearing)}``
    (one-to-one, by the Hungarian assignment on distance)."""
    from scipy.optimize import linear_sum_assignment

    det = np.asarray(detections, dtype=float).reshape(-1, 2)
    if not det.shape[0] or truth is None:
        return {}
    rel = truth.relative_xy[observer]
    dist = np.hypot(det[:, None, 0] - rel[None, :, 0], det[:, None, 1] - rel[None, :, 1])
    dist[:, observer] = np.inf
    cost = np.where(np.isfinite(dist), dist, 1e6)
    rows, cols = linear_sum_assignment(cost)
    return {
        int(j): np.array([math.hypot(*det[i]), math.atan2(det[i, 1], det[i, 0])])
        for i, j in zip(rows, cols, strict=True)
        if dist[i, j] <= ORACLE_GATE_M
    }


class IdentityScorer:
    """Per observer: errors of each in-range neighbour's *own ID* estimate.

    For neighbour ``j`` of observer ``i`` the error is ``|est_i[j] - truth|`` (``inf`` if
    ``i`` holds no estimate for ``j``); with a heading estimate, also the wrapped heading error.
    """

    def __init__(self, n_observers: int, error_threshold_m: float = 0.30) -> None:
        self.n_observers = n_observers
        self.error_threshold_m = error_threshold_m
        self.pairs = np.zeros(n_observers)
        self.large = np.zeros(n_observers)
        self.accurate = np.zeros(n_observers)
        self.errors: list[float] = []
        self.heading_errors: list[float] = []

    def add(self, observer: int, truth, mask: np.ndarray, identities: dict) -> None:
        for j in np.flatnonzero(mask).tolist():
            est = identities.get(j)
            if est is None:
                err = math.inf
            else:
                err = math.hypot(*(est[:2] - truth.relative_xy[observer, j]))
                if len(est) > 2:
                    true_psi = truth.poses[j, 2] - truth.poses[observer, 2]
                    d = (est[2] - true_psi + math.pi) % (2 * math.pi) - math.pi
                    self.heading_errors.append(abs(math.degrees(d)))
            self.pairs[observer] += 1
            self.large[observer] += not err <= self.error_threshold_m
            self.accurate[observer] += err <= 0.10
            self.errors.append(err)

    def summary(self) -> dict[str, Any]:
        with np.errstate(invalid="ignore", divide="ignore"):
            pct = 100.0 * self.large / self.pairs
            acc = 100.0 * self.accurate / self.pairs
        finite = [e for e in self.errors if math.isfinite(e)]
        nan = float("nan")

        def dist(values: np.ndarray) -> dict[str, Any]:
            ok = values[np.isfinite(values)]
            return {
                "per_robot": [float(v) for v in values],
                "median": float(np.median(ok)) if ok.size else nan,
                "max": float(ok.max()) if ok.size else nan,
            }

        total = float(self.pairs.sum())
        return {
            "id_pct_time_err_gt_30cm": dist(pct),
            "id_pct_time_within_10cm": dist(acc),
            "id_percent_large_error": 100.0 * float(self.large.sum()) / total if total else nan,
            "id_percent_missing": 100.0 * (len(self.errors) - len(finite)) / total
            if total
            else nan,
            "id_median_error_m": float(np.median(finite)) if finite else nan,
            "id_median_heading_error_deg": float(np.median(self.heading_errors))
            if self.heading_errors
            else nan,
        }


def print_identity_table(results: dict[str, Any]) -> None:
    """The ``identity`` block (ID-aware localizers), if any, as a markdown table."""
    ident = results.get("identity")
    if not ident:
        return
    print(
        "  | localizer (own-ID estimate) | % time err > 30 cm (median robot) | pooled | "
        "% time < 10 cm | no estimate % | median err m | median heading err deg |"
    )
    print("  |---|---|---|---|---|---|---|")
    for name, m in ident.items():
        print(
            f"  | {name} | {m['id_pct_time_err_gt_30cm']['median']:.1f} | "
            f"{m['id_percent_large_error']:.1f} | {m['id_pct_time_within_10cm']['median']:.1f} | "
            f"{m['id_percent_missing']:.1f} | {m['id_median_error_m']:.3f} | "
            f"{m['id_median_heading_error_deg']:.1f} |"
        )
