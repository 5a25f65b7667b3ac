"""The filter's lidar detection probability against the simulated lidar, scan by scan, in a swarm.

``bench_detection_curves.py`` measures each factor of the lidar's ``P_d`` alone (an isolated
pair: range, the blind sectors' notch). This one checks the whole product where the robots
live: a formation controller runs in ``lab-3m-4`` and, for every scan and every teammate within
the filter's lidar range (range factor >= 0.5) and off the notch (blind-sector factor >= 0.5 at
its true bearing), it compares

* **expected**: the filter's whole ``P_d`` (:meth:`localization.detection.DetectionModel.lidar`)
  for components of weight 1 at the teammates' true positions at the scan's instant, with that
  scan's null returns (interference) and the teammates' occlusion of each other: what the
  filter expects when its estimate is right;
* **detected**: the scan's extracted detections hold one within 0.15 m of the teammate;
* **cause** of each miss, from the simulator's own beam counts on the housing
  (:data:`swarm_env.world.diagnostics.LIDAR_MISS_CAUSES`).

It prints the means, the split by cause, and the expected-vs-detected rate per bin of the
interference factor and of range. No timing. The truth comes through
``SimWorld.lidar_scan_observers``.

Run: ``.venv/bin/python benchmarks/bench_lidar_pd_calibration.py --seeds 100-109`` (~10 s).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from agents.policies import load_policy  # noqa: E402
from experiments.formation_diagnosis import components_at  # noqa: E402
from localization.detection import DetectionModel  # noqa: E402
from swarm_core.inputs import parse_seeds  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from swarm_env.world.diagnostics import LIDAR_MISS_CAUSES, LidarScanTruth  # noqa: E402

MATCH_M = 0.15
INTERFERENCE_BINS = (0.0, 0.1, 0.3, 0.6, 0.9, 0.99, 1.0 + 1e-9)
RANGE_BINS_M = (0.0, 1.0, 1.5, 1.8, 1.9, 2.0, 2.1, 2.5)


class Calibration:
    """Collects one row per (scan, teammate in view): range (m), expected ``P_d``, its
    interference factor, detected (0/1) and the miss cause's index (-1 when detected)."""

    def __init__(self, detection: DetectionModel, n_agents: int, min_beams: int) -> None:
        self.detection = detection
        self.n_agents = n_agents
        self.min_beams = min_beams
        self.rows: list[np.ndarray] = []
        self.recording = False

    def __call__(self, truth: LidarScanTruth) -> None:
        if not self.recording:
            return
        for k, robot in enumerate(truth.robots.tolist()):
            mates = np.delete(np.arange(self.n_agents), robot)
            xy = truth.relative_xy[k, mates]  # (M, 2)
            ranges = np.hypot(xy[:, 0], xy[:, 1])
            bearings = np.arctan2(xy[:, 1], xy[:, 0])
            p_range = self.detection.lidar_range_factor(ranges)
            p_blind = self.detection.lidar_blind_sector_factor(bearings, ranges)
            table = components_at(xy)
            record = truth.records[k]
            expected = self.detection.lidar(table, np.asarray(record.null_bearings_rad))
            # The interference factor alone: the same P_d without the nulls divides it out.
            quiet = self.detection.lidar(table, None)
            nulled = np.divide(expected, quiet, out=np.ones_like(quiet), where=quiet > 0)
            found = np.zeros(len(mates), dtype=bool)
            detections = np.asarray(record.detections).reshape(-1, 2)
            if len(detections):
                gap = np.linalg.norm(xy[:, None, :] - detections[None, :, :], axis=2)
                found = gap.min(axis=1) <= MATCH_M
            reaching = truth.beams_reaching[k, mates]
            returned = truth.beams_returned[k, mates]
            cause = np.where(
                reaching < self.min_beams, 0, np.where(returned < self.min_beams, 1, 2)
            )
            cause = np.where(found, -1, cause)
            view = (p_range >= 0.5) & (p_blind >= 0.5)
            self.rows.append(np.stack((ranges, expected, nulled, found, cause), axis=1)[view])

    def summary(self) -> dict:
        rows = np.concatenate(self.rows) if self.rows else np.zeros((0, 5))
        ranges, expected, nulled, found, cause = rows.T
        out = {
            "pair_scans": len(rows),
            "expected": float(expected.mean()) if len(rows) else None,
            "detected": float(found.mean()) if len(rows) else None,
            "missed_by_cause": {
                c: float((cause == i).mean()) if len(rows) else None
                for i, c in enumerate(LIDAR_MISS_CAUSES)
            },
        }
        for name, value, bins in (
            ("by_interference_factor", nulled, INTERFERENCE_BINS),
            ("by_range_m", ranges, RANGE_BINS_M),
        ):
            out[name] = []
            for lo, hi in zip(bins[:-1], bins[1:], strict=True):
                where = (value >= lo) & (value < hi)
                if where.sum():
                    out[name].append(
                        {
                            "bin": [lo, min(hi, 1.0) if name != "by_range_m" else hi],
                            "pair_scans": int(where.sum()),
                            "expected": float(expected[where].mean()),
                            "detected": float(found[where].mean()),
                        }
                    )
        return out


def calibrate(preset: str, seeds: list[int], policy: str, from_step: int, max_steps: int):
    """Run ``policy`` on ``preset`` for ``seeds`` and collect :class:`Calibration` from
    ``from_step`` on (the settled formation)."""
    env = parallel_env(preset=preset, task="formation", observation="phd", max_steps=max_steps)
    controller = load_policy(policy, env)
    calibration = Calibration(
        DetectionModel(env.config.phd), env.config.n_robots, env.config.lidar_features.min_beams
    )
    for seed in seeds:
        controller.reset(seed)
        obs, infos = env.reset(seed=seed)
        world = env.unwrapped.world
        if calibration not in world.lidar_scan_observers:
            world.lidar_scan_observers.append(calibration)
        for t in range(max_steps):
            calibration.recording = t >= from_step
            obs, _, _, _, infos = env.step(controller(obs, infos))
    env.close()
    return calibration.summary()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="lab-3m-4")
    parser.add_argument("--seeds", default="100-109")
    parser.add_argument("--policy", default="scripted:formation")
    parser.add_argument("--from-step", type=int, default=150)
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    if not 0 <= args.from_step < args.max_steps:
        parser.error(
            f"--from-step must be in [0, --max-steps={args.max_steps}), got {args.from_step}"
        )
    t0 = time.perf_counter()
    out = calibrate(
        args.preset, parse_seeds(args.seeds), args.policy, args.from_step, args.max_steps
    )
    print(
        f"bench_lidar_pd_calibration: {args.preset}, {args.policy}, seeds {args.seeds}, from "
        f"step {args.from_step}, {platform.machine()}, {time.strftime('%Y-%m-%d')}, "
        f"{time.perf_counter() - t0:.0f} s"
    )
    if not out["pair_scans"]:
        print("no teammate in the lidar's view in the scored steps: nothing to compare")
        return 1
    print(
        f"in view: {out['pair_scans']} pair-scans, expected {out['expected']:.3f}, detected "
        f"{out['detected']:.3f}; missed by cause "
        + ", ".join(f"{c} {v:.3f}" for c, v in out["missed_by_cause"].items())
    )
    for name in ("by_interference_factor", "by_range_m"):
        print(f"| {name} | pair-scans | expected | detected |\n|---|---|---|---|")
        for row in out[name]:
            lo, hi = row["bin"]
            print(
                f"| {lo:.2f}-{hi:.2f} | {row['pair_scans']} | {row['expected']:.3f} | "
                f"{row['detected']:.3f} |"
            )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"args": vars(args) | {"json": str(args.json)}, **out}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
