"""Synthetic multi-robot scenario for the identity-aware localizers (ID-PHD, PF, UKF).

An observer and ``n_teammates`` unicycles drive in a 6 m x 6 m box (smoothly varying speed and
turn rate, turning back towards the centre near the walls). Every 0.1 s each robot's odometry
increment ``(dx, dy, dpsi)`` (in its frame at the start of the interval) is computed from the
true poses, plus small Gaussian noise; every ``scan_every`` steps the observer gets its
teammates' positions in its body frame, with N(0, 0.05^2 I) noise, missed with probability
``miss`` and only within ``range_m``, plus an optional static false positive.

Everything comes from one seeded generator: a run is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def relative_delta(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """``after`` as seen from ``before`` (world poses ``(x, y, yaw)``): the odometry increment."""
    c, s = math.cos(before[2]), math.sin(before[2])
    d = after[:2] - before[:2]
    dpsi = (after[2] - before[2] + math.pi) % (2 * math.pi) - math.pi
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], dpsi])


def in_frame(observer: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """World poses ``(K, 3)`` expressed in ``observer``'s body frame, ``(K, 3)``."""
    return np.array([relative_delta(observer, p) for p in poses]).reshape(-1, 3)


@dataclass
class Step:
    own_delta: np.ndarray  # (3,)
    team_delta: dict[int, np.ndarray]
    truth: np.ndarray  # (K, 3) teammates in the observer frame, after the step
    points: np.ndarray | None  # (M, 2) anonymous detections, or None (no scan this step)
    ids: np.ndarray | None  # (M,) true identity of each detection (-2: false positive)


def simulate(
    n_teammates: int = 3,
    steps: int = 300,
    seed: int = 0,
    scan_every: int = 1,
    range_m: float = 3.0,
    miss: float = 0.1,
    odo_noise_m: float = 0.002,
    odo_noise_rad: float = 0.005,
    lidar_std_m: float = 0.05,
    static_object: bool = False,
    observer_moves: bool = True,
) -> list[Step]:
    rng = np.random.default_rng(seed)
    n = n_teammates + 1
    angles = rng.uniform(0, 2 * math.pi, n)
    radii = rng.uniform(0.4, 1.4, n)
    poses = np.stack(
        [radii * np.cos(angles), radii * np.sin(angles), rng.uniform(-math.pi, math.pi, n)], 1
    )
    poses[0] = [0.0, 0.0, 0.3]
    static_xy = np.array([0.9, -0.6])
    v = rng.uniform(0.1, 0.3, n)
    w = rng.uniform(-0.6, 0.6, n)
    if not observer_moves:
        v[0] = w[0] = 0.0
    dt = 0.1
    out = []
    for k in range(steps):
        v = np.clip(v + rng.normal(0, 0.02, n), 0.05, 0.3)
        w = np.clip(w + rng.normal(0, 0.15, n), -1.0, 1.0)
        # steer back towards the centre when far from it
        far = np.hypot(poses[:, 0], poses[:, 1]) > 1.8
        to_centre = np.arctan2(-poses[:, 1], -poses[:, 0]) - poses[:, 2]
        to_centre = (to_centre + math.pi) % (2 * math.pi) - math.pi
        w = np.where(far, np.clip(2.0 * to_centre, -1.0, 1.0), w)
        if not observer_moves:
            v[0] = w[0] = 0.0
        new = poses.copy()
        mid = poses[:, 2] + 0.5 * w * dt
        new[:, 0] += v * dt * np.cos(mid)
        new[:, 1] += v * dt * np.sin(mid)
        new[:, 2] = (poses[:, 2] + w * dt + math.pi) % (2 * math.pi) - math.pi
        deltas = [relative_delta(poses[i], new[i]) for i in range(n)]
        noise = np.array([odo_noise_m, odo_noise_m, odo_noise_rad])
        noisy = [d + rng.normal(0, 1, 3) * noise for d in deltas]
        poses = new
        truth = in_frame(poses[0], poses[1:])
        points = ids = None
        if k % scan_every == scan_every - 1:
            ranges = np.hypot(truth[:, 0], truth[:, 1])
            seen = (ranges <= range_m) & (rng.random(n_teammates) >= miss)
            pts = truth[seen, :2] + rng.normal(0, lidar_std_m, (int(seen.sum()), 2))
            pid = np.flatnonzero(seen)
            if static_object:
                sxy = in_frame(poses[0], np.array([[*static_xy, 0.0]]))[0, :2]
                if np.hypot(*sxy) <= range_m and rng.random() >= miss:
                    pts = np.vstack([pts, sxy + rng.normal(0, lidar_std_m, 2)])
                    pid = np.append(pid, -2)
            points, ids = pts.reshape(-1, 2), pid
        out.append(
            Step(
                own_delta=noisy[0],
                team_delta={i: noisy[i + 1] for i in range(n_teammates)},
                truth=truth,
                points=points,
                ids=ids,
            )
        )
    return out
