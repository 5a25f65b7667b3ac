"""A small synthetic robot-centric scenario, consistent with the filter's sensor models.

A static observer at the origin (heading +x); ``n_targets`` teammates move in a square box
around it (random-walk velocity, bouncing off the walls). Every 0.1 s the observer's filter
gets a time update; a lidar scan arrives at ~7 Hz and a camera frame at 10 Hz.

* Lidar: a teammate is detected with the Perera 2021 study's range probability (eq. 19), never
  inside a hard blind sector of the configured width, never when a nearer teammate is within the
  occlusion angle, with N(0, 0.05^2 I) noise; Poisson clutter (mean ``lidar_clutter``)
  uniform in the 2 m disc.
* Camera: detection with the Perera 2021 study's camera range probability (eq. 30), occlusion as
  above, N(0, (5 deg)^2) bearing noise; Poisson clutter uniform in bearing.

Everything is drawn from one seeded generator, so a run is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from localization import PHDConfig, RobotCentricPHD
from localization.metrics import LocalizationScorer, gospa


@dataclass
class ScenarioResult:
    summary: dict[str, float]
    mean_gospa: float
    scorer: LocalizationScorer = field(repr=False)


def _blind(bearings: np.ndarray, cfg: PHDConfig) -> np.ndarray:
    centres = np.radians(cfg.lidar.blind_sector_centers_deg)
    half = np.radians(cfg.lidar.blind_sector_widths_deg) / 2
    d = np.angle(np.exp(1j * (bearings[:, None] - centres)))
    return (np.abs(d) < half).any(axis=1)


def _occluded(pos: np.ndarray, angle_rad: float) -> np.ndarray:
    r = np.hypot(pos[:, 0], pos[:, 1])
    b = np.arctan2(pos[:, 1], pos[:, 0])
    d = np.abs(np.angle(np.exp(1j * (b[:, None] - b[None, :]))))
    nearer = r[None, :] < r[:, None] - 0.1
    return ((d < angle_rad) & nearer).any(axis=1)


def walk_start(
    rng: np.random.Generator, n_targets: int, half_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The targets' start for :func:`walk_step`: positions (m) uniform in the square
    ``[-half_m, half_m]^2`` and velocities (m/s) N(0, 0.15^2) per axis, each ``(n_targets, 2)``."""
    pos = rng.uniform(-half_m, half_m, size=(n_targets, 2))
    vel = rng.normal(0.0, 0.15, size=(n_targets, 2))
    return pos, vel


def walk_step(
    pos: np.ndarray,
    vel: np.ndarray,
    rng: np.random.Generator,
    dt_s: float,
    half_m: float,
    accel_std_mps: float,
) -> None:
    """One step of the targets' bounded random walk, in place on ``pos`` (m) and ``vel`` (m/s),
    both ``(n_targets, 2)``: a N(0, ``accel_std_mps``^2) velocity kick per axis, speed capped at
    0.3 m/s, ``dt_s`` of motion, and a target past an edge of the square
    ``[-half_m, half_m]^2`` reverses the velocity component across that edge and is clipped back
    to it. Draws ``vel.size`` normals from ``rng``."""
    vel += rng.normal(0.0, accel_std_mps, size=vel.shape)
    speed = np.hypot(vel[:, 0], vel[:, 1])[:, None]
    vel *= np.minimum(1.0, 0.3 / np.maximum(speed, 1e-9))
    pos += vel * dt_s
    out = np.abs(pos) > half_m
    vel[out] *= -1.0
    np.clip(pos, -half_m, half_m, out=pos)


def run_scenario(
    mode: str,
    seed: int = 0,
    n_targets: int = 6,
    box_m: float = 2.2,
    steps: int = 600,
    lidar_clutter: float = 0.3,
    camera_clutter: float = 0.2,
    config: PHDConfig | None = None,
) -> ScenarioResult:
    """Run one filter in ``mode`` on the scenario drawn from ``seed``; score it."""
    cfg = config if config is not None else PHDConfig.perera2021().replace(mode=mode)
    if cfg.mode != mode:
        raise ValueError("config.mode must equal mode")
    rng = np.random.default_rng(seed)  # truth and measurements: identical for LC and LO
    pos, vel = walk_start(rng, n_targets, box_m)
    f = RobotCentricPHD(cfg)
    scorer = LocalizationScorer()
    gospas = []
    dt = 0.1
    occ = math.radians(3.0)
    for k in range(steps):
        walk_step(pos, vel, rng, dt, box_m, accel_std_mps=0.05)
        r = np.hypot(pos[:, 0], pos[:, 1])
        b = np.arctan2(pos[:, 1], pos[:, 0])
        hidden = _occluded(pos, occ)
        lidar_now = math.floor((k + 1) * 0.7) != math.floor(k * 0.7)
        # Draw every random number whether or not this filter uses it: LC and LO see the
        # same world and the same lidar data.
        pd_l = 1.0 / (1.02 + np.exp(8.0 * (r - 1.5)))
        det_l = (rng.random(n_targets) < pd_l) & ~_blind(b, cfg) & ~hidden
        noise_l = rng.normal(0.0, 0.05, size=(n_targets, 2))
        n_clut = rng.poisson(lidar_clutter)
        clut_r = 2.0 * np.sqrt(rng.random(n_clut))
        clut_a = rng.uniform(-math.pi, math.pi, n_clut)
        pd_c = 1.0 / (1.1 + np.exp(5.0 * (r - 4.0)))
        det_c = (rng.random(n_targets) < pd_c) & ~hidden
        noise_c = rng.normal(0.0, math.radians(5.0), size=n_targets)
        n_cc = rng.poisson(camera_clutter)
        clut_b = rng.uniform(-math.pi, math.pi, n_cc)

        f.predict(np.zeros(3))
        if lidar_now:
            z = np.concatenate(
                (
                    pos[det_l] + noise_l[det_l],
                    np.stack((clut_r * np.cos(clut_a), clut_r * np.sin(clut_a)), axis=1),
                )
            )
            f.update_lidar(z)
        f.update_camera(np.concatenate((b[det_c] + noise_c[det_c], clut_b)))
        in_range = r <= 2.0
        scorer.update(pos[in_range], np.flatnonzero(in_range), f.mixture)
        est, _ = f.estimate(0.5)
        est = est[np.hypot(est[:, 0], est[:, 1]) <= 2.0] if est.size else est
        gospas.append(gospa(pos[in_range], est).distance)
    return ScenarioResult(scorer.summary(), float(np.mean(gospas)), scorer)
