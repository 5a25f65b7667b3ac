"""Detection trials of the simulated lidar and cameras on isolated (observer, target) pairs.

The ground truth the filter's lidar detection model is checked against
(``tests/localization/test_blind_sector_notch.py``) and measured from
(``benchmarks/bench_detection_curves.py``): one scan per pair, through the same feature
extractor as the env, with the target at a chosen range and body-frame bearing. With
``fade=True`` the preset's detection fade (``SwarmConfig.lidar_fade`` / ``camera_fade``)
thins them as the env does (``tests/swarm_env/test_detection_fade.py``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from swarm_core.perception.lidar_features import extract_clusters
from swarm_env.config import make_config
from swarm_env.sensors.camera import CameraSensor
from swarm_env.sensors.detection_fade import keep_mask, thin_bearings
from swarm_env.sensors.lidar import LidarSensor
from swarm_env.sensors.scene_builder import make_pair_scene

#: A detection within this distance of the target's centre (m) is the target.
MATCH_GATE_M = 0.15


def lidar_detects(
    range_m: float,
    bearings_rad: np.ndarray,
    rng: np.random.Generator,
    preset: str = "seed-sim",
    interference: bool = False,
    fade: bool = False,
) -> np.ndarray:
    """Whether the lidar and feature extractor of ``preset`` report a teammate's housing at
    ``range_m`` (m) and each of ``bearings_rad`` (N,) (observer's body frame, rad), one pair
    and one scan each (random observer yaw, i.e. random world heading), shape (N,) bool.
    Interference is off unless asked for: the filter models it as a separate factor.
    ``fade``: also thin the detections by the preset's ``lidar_fade`` (if it has one)."""
    cfg = make_config(preset)
    lidar_cfg = cfg.lidar
    if not interference:
        lidar_cfg = dataclasses.replace(lidar_cfg, interference_tolerance_deg=0.0)
    bearings_rad = np.asarray(bearings_rad, dtype=float)
    scene, _ = make_pair_scene(
        rng,
        range_m,
        bearings_rad.size,
        cfg.robot.camera_holder_radius_m,
        bearings_rad=bearings_rad,
    )
    observers = np.arange(0, scene.n_robots, 2)
    batch = LidarSensor(lidar_cfg, scene.n_robots).scan(
        scene, observers, np.ones(observers.size), rng
    )
    dets = extract_clusters(batch.angles_rad, batch.ranges_m, cfg.lidar_features)
    truth = range_m * np.stack([np.cos(bearings_rad), np.sin(bearings_rad)], axis=1)
    ok = np.linalg.norm(dets.xy_m - truth[dets.scan_index], axis=1) <= MATCH_GATE_M
    if fade and cfg.lidar_fade is not None:
        ok &= keep_mask(cfg.lidar_fade, np.hypot(dets.xy_m[:, 0], dets.xy_m[:, 1]), rng)
    found = np.zeros(bearings_rad.size, dtype=bool)
    found[dets.scan_index[ok]] = True
    return found


def camera_bearing_errors(
    range_m: float, n_pairs: int, rng: np.random.Generator, preset: str = "seed-sim"
) -> np.ndarray:
    """The cameras of ``preset`` on ``n_pairs`` isolated pairs, a teammate's strip at
    ``range_m`` (m) and a random bearing, one frame each, thinned by the preset's
    ``camera_fade`` as the env does: per pair, the error (rad, wrapped) of the bearing of the
    teammate's strip, NaN where it was not detected, shape (n_pairs,)."""
    cfg = make_config(preset)
    scene, bearings_rad = make_pair_scene(rng, range_m, n_pairs, cfg.robot.camera_holder_radius_m)
    observers = np.arange(0, scene.n_robots, 2)
    batch = CameraSensor(cfg.camera).observe(scene, observers, rng)
    frames, sources = batch.bearings, batch.sources
    if cfg.camera_fade is not None:
        origins, _ = scene.observer_poses(observers)
        frames, sources = thin_bearings(
            frames, sources, scene.circle_xy, origins, cfg.camera_fade, rng
        )
    errors = np.full(n_pairs, np.nan)
    for k, (bearings, src) in enumerate(zip(frames, sources, strict=True)):
        seen = bearings[src >= 0]
        if seen.size:
            errors[k] = (seen[0] - bearings_rad[k] + np.pi) % (2 * np.pi) - np.pi
    return errors
