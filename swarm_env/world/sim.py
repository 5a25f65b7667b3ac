"""SimWorld: pymunk differential-drive UGVs in a walled arena, with their sensors.

pymunk owns the rigid bodies and resolves contacts (robots, walls, obstacles). Every physics
substep the motor controller moves each robot's ``[v, omega]`` towards its command within the
acceleration limits. The wheels drive the chassis the way pymunk's top-down "tank" pattern does:
a kinematic control body moves at the wheel velocity (along the heading: a differential drive
cannot move sideways) and a pivot joint and a gear joint with bounded force and torque drag the
chassis after it. Bounded forces matter: walls and obstacles always win a contact, and a pile of
robots cannot push one of them through a wall. The encoders count the wheels' rotation, so when a
contact blocks or pushes the chassis they slip exactly as on a real robot.

Sensors run at their own rates on substep boundaries, each robot with its own phase, and see the
world through a :class:`~swarm_env.world.scene.Scene` snapshot built from the bodies.
"""

from __future__ import annotations

import time

import numpy as np
import pymunk

from swarm_env.config import SwarmConfig
from swarm_env.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements
from swarm_env.sensors.camera import CameraSensor
from swarm_env.sensors.lidar import LidarSensor
from swarm_env.sensors.lidar_features import extract_detections, null_bearings
from swarm_env.sensors.odometry import WheelEncoders
from swarm_env.world.arena import Layout, sample_layout, wall_segments
from swarm_env.world.base import GroundTruth, WorldStep
from swarm_env.world.diagnostics import SensorStats
from swarm_env.world.scene import Scene

# Lidar return intensity of each surface (arbitrary units, as the YDLidar reports them).
_INTENSITY_WALL = 1000.0
_INTENSITY_HOUSING = 700.0
_INTENSITY_POST = 800.0
_INTENSITY_OBSTACLE = 900.0
_EPS_S = 1e-9
# Wheel traction: the largest linear and angular acceleration the wheels can impose on the
# chassis (~1 g on rubber), which bounds how hard a robot can push.
_TRACTION_MPS2 = 9.0
_TRACTION_RADPS2 = 60.0


def robot_names(n: int) -> tuple[str, ...]:
    return tuple(f"ugv_{i}" for i in range(n))


class SimWorld:
    """The simulated World (see :class:`swarm_env.world.base.World`).

    Parameters
    ----------
    config : SwarmConfig
    n_extra : int
        Non-agent robots (e.g. an intruder) that move on scripted commands, carry a lidar
        housing and a red strip like every robot, but no sensors.
    """

    def __init__(self, config: SwarmConfig, n_extra: int = 0) -> None:
        self.config = config
        self.n_agents = config.n_robots
        self.n_extra = n_extra
        self.robot_ids = robot_names(config.n_robots)
        n_total = self.n_agents + n_extra
        self.lidar = LidarSensor(config.lidar, self.n_agents)
        self.camera = CameraSensor(config.camera)
        self.encoders = WheelEncoders(
            config.odometry, n_total, config.robot.wheel_radius_m, config.robot.axle_width_m
        )
        self.time_s = 0.0
        self.motor_speeds = np.zeros((n_total, 2))  # [v_mps, omega_radps] the motors deliver
        self.layout: Layout | None = None
        self.space: pymunk.Space | None = None
        self.bodies: list[pymunk.Body] = []
        self._rng: np.random.Generator | None = None
        self._next_lidar_s = np.zeros(self.n_agents)
        self._next_camera_s = np.zeros(self.n_agents)
        self._next_odometry_s = np.zeros(self.n_agents)
        self._lidar_visible = np.zeros((self.n_agents, n_total), dtype=bool)
        self._camera_visible = np.zeros((self.n_agents, n_total), dtype=bool)
        self.last_lidar: dict[int, tuple[LidarRecord, np.ndarray]] = {}
        self.last_camera: dict[int, CameraRecord] = {}
        self.stats = self._new_stats()
        # Wall-clock seconds spent per part and lidar scans run (for the benchmark).
        self.timing = {"physics_s": 0.0, "lidar_s": 0.0, "camera_s": 0.0, "lidar_scans": 0}

    def _new_stats(self) -> dict[str, SensorStats]:
        # Lidar: matched within 0.15 m, counted within the tracking range; camera: within 3 sigma.
        return {
            "lidar": SensorStats(range_m=self.config.localization_range_m, gate=0.15),
            "camera": SensorStats(range_m=self.config.camera.range_max_m,
                                  gate=3.0 * np.deg2rad(self.config.camera.bearing_noise_std_deg)),
        }

    # ------------------------------------------------------------------ lifecycle
    def reset(self, rng: np.random.Generator) -> WorldStep:
        """Lay out a new arena, spawn the robots, and return an empty first step."""
        cfg = self.config
        self._rng = rng
        n_total = self.n_agents + self.n_extra
        self.layout, poses = sample_layout(
            cfg.arena, cfg.robot, n_total, cfg.spawn_clearance_m, rng
        )
        self._build_space(poses)
        self.time_s = 0.0
        self.motor_speeds[:] = 0.0
        self.encoders.reset(0.0)
        self.lidar.reset(rng)
        # Each robot's sensors run with their own phase, as unsynchronised hardware does.
        self._next_lidar_s = rng.uniform(0.0, 1.0 / cfg.lidar.rate_hz, self.n_agents)
        self._next_camera_s = rng.uniform(0.0, 1.0 / cfg.camera.rate_hz, self.n_agents)
        self._next_odometry_s = np.full(self.n_agents, 1.0 / cfg.odometry.rate_hz)
        self._lidar_visible[:] = False
        self._camera_visible[:] = False
        self.last_lidar.clear()
        self.last_camera.clear()
        self.stats = self._new_stats()
        self._static_scene = self._static_geometry()
        empty = {rid: RobotMeasurements() for rid in self.robot_ids}
        return WorldStep(time_s=0.0, measurements=empty, truth=self.ground_truth())

    def close(self) -> None:
        """Nothing to release in simulation."""

    def _build_space(self, poses: np.ndarray) -> None:
        cfg, robot = self.config, self.config.robot
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        hx, hy = 0.5 * cfg.arena.width_m, 0.5 * cfg.arena.height_m
        r = 0.5 * cfg.arena.wall_thickness_m
        # Walls: thick segments whose inner faces lie on the arena boundary.
        corners = [(hx + r, hy + r), (-hx - r, hy + r), (-hx - r, -hy - r), (hx + r, -hy - r)]
        static = space.static_body
        shapes: list[pymunk.Shape] = [
            pymunk.Segment(static, corners[i], corners[(i + 1) % 4], r) for i in range(4)
        ]
        assert self.layout is not None
        for x, y in self.layout.posts_xy:
            shapes.append(pymunk.Circle(static, cfg.arena.decoy_post_radius_m, (x, y)))
        for x, y in self.layout.red_decoys_xy:
            shapes.append(pymunk.Circle(static, cfg.arena.red_decoy_radius_m, (x, y)))
        for box in self.layout.box_corners():
            shapes.append(pymunk.Poly(static, [tuple(p) for p in box]))
        for shape in shapes:
            shape.friction = 0.0
            shape.elasticity = 0.0
        space.add(*shapes)
        size = (robot.length_m, robot.width_m)
        moment = pymunk.moment_for_box(robot.mass_kg, size)
        # Traction limits: what the wheels can push with before they slip (friction ~ 1 g).
        max_force_n = robot.mass_kg * _TRACTION_MPS2
        max_torque_nm = moment * _TRACTION_RADPS2
        self.bodies, self._drives = [], []
        for x, y, yaw in poses:
            body = pymunk.Body(robot.mass_kg, moment)
            body.position = (float(x), float(y))
            body.angle = float(yaw)
            shape = pymunk.Poly.create_box(body, size, radius=0.002)
            shape.friction = 0.0
            shape.elasticity = 0.0
            drive = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            drive.position, drive.angle = body.position, body.angle
            pivot = pymunk.PivotJoint(drive, body, (0.0, 0.0), (0.0, 0.0))
            pivot.max_bias = 0.0  # match velocities only; never yank the body to a position
            pivot.max_force = max_force_n
            gear = pymunk.GearJoint(drive, body, 0.0, 1.0)
            gear.error_bias = 0.0
            gear.max_bias = 0.0
            gear.max_force = max_torque_nm
            space.add(body, shape, drive, pivot, gear)
            self.bodies.append(body)
            self._drives.append(drive)
        self.space = space

    # ------------------------------------------------------------------ stepping
    def step(self, commands: np.ndarray, extra_commands: np.ndarray | None = None) -> WorldStep:
        """Run one control period.

        Parameters
        ----------
        commands : ndarray, shape (N, 2)
            ``[v_mps, omega_radps]`` per agent, already validated and clipped by the env.
        extra_commands : ndarray, shape (E, 2), optional
            Commands for the non-agent robots (zeros if omitted).
        """
        if self.space is None:
            raise RuntimeError("SimWorld.step() called before reset()")
        cfg = self.config
        target = np.zeros_like(self.motor_speeds)
        target[: self.n_agents] = commands
        if extra_commands is not None and self.n_extra:
            target[self.n_agents:] = extra_commands
        limits = np.array([cfg.robot.max_accel_mps2, cfg.robot.max_turn_accel_radps2])
        dt = cfg.physics_dt_s
        odometry: list[list[OdometryRecord]] = [[] for _ in range(self.n_agents)]
        lidar: list[list[LidarRecord]] = [[] for _ in range(self.n_agents)]
        camera: list[list[CameraRecord]] = [[] for _ in range(self.n_agents)]
        for _ in range(cfg.physics_substeps):
            self.motor_speeds += np.clip(target - self.motor_speeds, -limits * dt, limits * dt)
            for body, drive, (v, omega) in zip(self.bodies, self._drives, self.motor_speeds):
                # Chord direction of this substep's arc: the heading half a substep ahead.
                heading = body.angle + 0.5 * omega * dt
                drive.velocity = (v * np.cos(heading), v * np.sin(heading))
                drive.angular_velocity = omega
            t0 = time.perf_counter()
            self.space.step(dt)
            self.timing["physics_s"] += time.perf_counter() - t0
            self.encoders.advance(self.motor_speeds, dt, self._rng)
            self.time_s += dt
            self._run_sensors(odometry, lidar, camera)
        measurements = {
            rid: RobotMeasurements(odometry[i], lidar[i], camera[i])
            for i, rid in enumerate(self.robot_ids)
        }
        return WorldStep(time_s=self.time_s, measurements=measurements, truth=self.ground_truth())

    def _run_sensors(self, odometry, lidar, camera) -> None:
        t = self.time_s
        due_odom = np.flatnonzero(self._next_odometry_s <= t + _EPS_S)
        if due_odom.size:
            delta, velocity = self.encoders.sample(t)
            # One shared encoder clock: all robots sample together at the odometry rate.
            for i in due_odom:
                odometry[i].append(OdometryRecord(t, delta[i], velocity[i]))
            self._next_odometry_s[due_odom] += 1.0 / self.config.odometry.rate_hz
        due_lidar = np.flatnonzero(self._next_lidar_s <= t + _EPS_S)
        due_camera = np.flatnonzero(self._next_camera_s <= t + _EPS_S)
        if not (due_lidar.size or due_camera.size):
            return
        scene = self.scene()
        # Truth at this instant, for the sensor diagnostics: every body in each robot's frame.
        poses = self.poses()
        rel = relative_positions(poses[: self.n_agents], poses)
        if due_lidar.size:
            t0 = time.perf_counter()
            self._scan_lidar(scene, due_lidar, t, lidar, rel)
            self.timing["lidar_s"] += time.perf_counter() - t0
            self.timing["lidar_scans"] += int(due_lidar.size)
            self._next_lidar_s[due_lidar] += 1.0 / self.config.lidar.rate_hz
        if due_camera.size:
            t0 = time.perf_counter()
            batch = self.camera.observe(scene, due_camera, self._rng)
            for k, i in enumerate(due_camera):
                record = CameraRecord(t, batch.bearings[k])
                camera[i].append(record)
                self.last_camera[int(i)] = record
                self.stats["camera"].add_bearings(record.bearings_rad, _others(rel, i))
            self._camera_visible[due_camera] = batch.visible
            self.timing["camera_s"] += time.perf_counter() - t0
            self._next_camera_s[due_camera] += 1.0 / self.config.camera.rate_hz

    def _scan_lidar(self, scene: Scene, robots: np.ndarray, t: float, out, rel) -> None:
        stamps = np.full(robots.size, t)
        batch = self.lidar.scan(scene, robots, stamps, self._rng)
        detections = extract_detections(batch.angles_rad, batch.ranges_m, self.config.lidar_features)
        n_total = self.n_agents + self.n_extra
        for k, i in enumerate(robots):
            ranges, intensities = batch.ranges_m[k], batch.intensities[k]
            record = LidarRecord(
                stamp_s=t,
                angles_rad=batch.angles_rad,
                ranges_m=ranges,
                intensities=intensities,
                detections=detections[k],
                null_bearings_rad=null_bearings(batch.angles_rad, ranges, intensities,
                                                exclude=self.lidar.blind_mask),
            )
            out[i].append(record)
            hits = batch.hit_owner[k][(ranges > 0) & (batch.hit_owner[k] >= 0)]
            visible = np.zeros(n_total, dtype=bool)
            visible[hits] = True
            self._lidar_visible[i] = visible
            self.last_lidar[int(i)] = (record, batch.hit_owner[k])
            self.stats["lidar"].add_points(record.detections, _others(rel, i))

    # ------------------------------------------------------------------ geometry
    def poses(self) -> np.ndarray:
        """``[x, y, yaw]`` of every body (agents first, then extras), shape (N+E, 3)."""
        return np.array([(b.position.x, b.position.y, b.angle) for b in self.bodies])

    def _static_geometry(self) -> dict[str, np.ndarray]:
        cfg, layout = self.config, self.layout
        assert layout is not None
        n_post, n_red = len(layout.posts_xy), len(layout.red_decoys_xy)
        wall_a, wall_b = wall_segments(cfg.arena)
        box_a, box_b = layout.box_edges()
        return {
            "circle_xy": np.concatenate([layout.posts_xy, layout.red_decoys_xy]),
            "circle_radius_m": np.concatenate([
                np.full(n_post, cfg.arena.decoy_post_radius_m),
                np.full(n_red, cfg.arena.red_decoy_radius_m),
            ]),
            "circle_lidar": np.ones(n_post + n_red, dtype=bool),
            "circle_camera_occluder": np.r_[np.zeros(n_post, bool), np.ones(n_red, bool)],
            "circle_red": np.r_[np.zeros(n_post, bool), np.ones(n_red, bool)],
            "circle_intensity": np.r_[np.full(n_post, _INTENSITY_POST),
                                      np.full(n_red, _INTENSITY_OBSTACLE)],
            "segment_a": np.concatenate([wall_a, box_a]),
            "segment_b": np.concatenate([wall_b, box_b]),
            "segment_intensity": np.r_[np.full(4, _INTENSITY_WALL),
                                       np.full(len(box_a), _INTENSITY_OBSTACLE)],
        }

    def scene(self) -> Scene:
        """The current geometry snapshot: static obstacles, then each robot's housing and holder."""
        robot = self.config.robot
        poses = self.poses()
        n = len(poses)
        static = self._static_scene
        n_static = len(static["circle_xy"])
        ids = np.arange(n)
        # Per robot: a lidar housing (lidar-visible) and a camera holder (red, occludes).
        return Scene(
            robot_xy=poses[: self.n_agents, :2],
            robot_yaw=poses[: self.n_agents, 2],
            circle_xy=np.concatenate([static["circle_xy"], poses[:, :2], poses[:, :2]]),
            circle_radius_m=np.concatenate([
                static["circle_radius_m"], np.full(n, robot.housing_radius_m),
                np.full(n, robot.camera_holder_radius_m)]),
            circle_owner=np.concatenate([np.full(n_static, -1), ids, ids]),
            circle_lidar=np.concatenate([static["circle_lidar"], np.ones(n, bool),
                                         np.zeros(n, bool)]),
            circle_camera_occluder=np.concatenate([static["circle_camera_occluder"],
                                                   np.zeros(n, bool), np.ones(n, bool)]),
            circle_red=np.concatenate([static["circle_red"], np.zeros(n, bool), np.ones(n, bool)]),
            circle_intensity=np.concatenate([static["circle_intensity"],
                                             np.full(n, _INTENSITY_HOUSING),
                                             np.full(n, _INTENSITY_HOUSING)]),
            segment_a=static["segment_a"],
            segment_b=static["segment_b"],
            segment_intensity=static["segment_intensity"],
        )

    def ground_truth(self) -> GroundTruth:
        """True poses, relative positions, and per-sensor range and visibility masks."""
        poses = self.poses()
        agents = poses[: self.n_agents]
        rel = relative_positions(agents, agents)
        dist = np.linalg.norm(rel, axis=-1)
        off_diag = ~np.eye(self.n_agents, dtype=bool)
        return GroundTruth(
            poses=agents,
            relative_xy=rel,
            in_range={
                "lidar": off_diag & (dist <= self.config.localization_range_m),
                "camera": off_diag & (dist <= self.config.camera.range_max_m),
            },
            visible={
                "lidar": self._lidar_visible[:, : self.n_agents].copy(),
                "camera": self._camera_visible[:, : self.n_agents].copy(),
            },
            extra_xy=poses[self.n_agents:, :2].copy(),
        )


def _others(rel: np.ndarray, i: int) -> np.ndarray:
    """Row i of a (N, N+E, 2) relative-position array without robot i itself."""
    return np.delete(rel[i], i, axis=0)


def relative_positions(observers: np.ndarray, targets_xy: np.ndarray) -> np.ndarray:
    """Targets in each observer's body frame.

    Parameters
    ----------
    observers : ndarray, shape (N, 3)
        ``[x, y, yaw]`` world poses.
    targets_xy : ndarray, shape (M, 2+)
        World positions (extra columns ignored).

    Returns
    -------
    ndarray, shape (N, M, 2)
        ``out[i, j] = R(yaw_i)^T (p_j - p_i)``.
    """
    d = targets_xy[None, :, :2] - observers[:, None, :2]
    c, s = np.cos(observers[:, 2])[:, None], np.sin(observers[:, 2])[:, None]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
