"""Where a localizer's surplus estimates come from: why lidar + camera reports more false
teammates than lidar only.

Runs ``sim-6m-20`` with the Perera 2021 study's wander motion and, every step after a warm-up,
takes each observer's estimates with weight >= 0.5 within the 2 m scoring range (what GOSPA
scores). An estimate with no teammate within 0.5 m is **false**, classed by what is there: a decoy
post (within 0.2 m), a red decoy (within 0.3 m), the ray of a teammate (bearing within 4 deg;
farther or nearer than it), a red decoy's ray, or other. Teammates with more than one estimate
within 0.3 m are **duplicates** (two estimates for one teammate). Per observer-step rates.

    python -m experiments.diagnose_false_estimates --localizer phd-lc --steps 600

Prints the rates per observer-step.
"""

from __future__ import annotations

import argparse
import collections

import numpy as np

from agents.policies import load_policy
from swarm_env.env import SwarmEnv


def _to_body(pose: np.ndarray, xy: np.ndarray) -> np.ndarray:
    if not len(xy):
        return np.zeros((0, 2))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = xy - pose[:2]
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], -1)


def _angle(a: np.ndarray) -> np.ndarray:
    return np.abs((a + np.pi) % (2 * np.pi) - np.pi)


def diagnose(localizer: str, steps: int, seed: int, warmup: int = 50) -> dict:
    env = SwarmEnv("sim-6m-20", localizer=localizer, observation="measurements")
    policy = load_policy("scripted:wander", env)
    obs, infos = env.reset(seed=seed)
    policy.reset(seed)
    layout = env.world.layout
    classes: collections.Counter = collections.Counter()
    n_obs = n_est = duplicates = 0
    ray = np.deg2rad(4.0)
    for k in range(steps):
        obs, _, _, _, infos = env.step(policy(obs, infos))
        if k < warmup:
            continue
        truth = env.last_world_step.truth
        for i in range(env.config.n_robots):
            n_obs += 1
            means, _ = env.localizer.estimate(i, 0.5)
            means = means[np.hypot(means[:, 0], means[:, 1]) <= 2.0] if len(means) else means
            if not len(means):
                continue
            rel = np.delete(truth.relative_xy[i], i, axis=0)
            posts = _to_body(truth.poses[i], layout.posts_xy)
            reds = _to_body(truth.poses[i], layout.red_decoys_xy)
            dist = np.linalg.norm(means[:, None] - rel[None], axis=-1)
            duplicates += int(((dist < 0.3).sum(axis=0) > 1).sum())
            team_b = np.arctan2(rel[:, 1], rel[:, 0])
            team_r = np.hypot(rel[:, 0], rel[:, 1])
            for e, m in zip(dist.min(axis=1), means, strict=True):
                n_est += 1
                if e < 0.5:
                    continue
                b, r = np.arctan2(m[1], m[0]), np.hypot(m[0], m[1])
                on_ray = _angle(team_b - b) < ray
                if len(posts) and np.linalg.norm(posts - m, axis=1).min() < 0.2:
                    classes["decoy post"] += 1
                elif len(reds) and np.linalg.norm(reds - m, axis=1).min() < 0.3:
                    classes["red decoy"] += 1
                elif on_ray.any():
                    j = np.argmin(np.where(on_ray, np.abs(team_r - r), np.inf))
                    classes["teammate ray, teammate farther" if team_r[j] > r else
                            "teammate ray, teammate nearer"] += 1  # fmt: skip
                elif len(reds) and (_angle(np.arctan2(reds[:, 1], reds[:, 0]) - b) < ray).any():
                    classes["red decoy ray"] += 1
                else:
                    classes["other"] += 1
    return {
        "localizer": localizer,
        "observer_steps": n_obs,
        "estimates": n_est / n_obs,
        "false": sum(classes.values()) / n_obs,
        "duplicates": duplicates / n_obs,
        "false_by_class": {k: v / n_obs for k, v in classes.most_common()},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--localizer", default="phd-lc,phd-lo")
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    for name in args.localizer.split(","):
        d = diagnose(name, args.steps, args.seed)
        print(
            f"{name}: {d['estimates']:.2f} estimates, {d['false']:.2f} false, "
            f"{d['duplicates']:.2f} duplicated teammates per observer-step"
        )
        for k, v in d["false_by_class"].items():
            print(f"  {k:32s} {v:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
