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
world through a :class:`~swarm_env.sensors.scene.Scene` snapshot built from the bodies.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pymunk
import pymunk.batch
from numba import njit, prange

from swarm_core.perception.lidar_features import extract_detections, null_beams
from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements
from swarm_core.world import GroundTruth, WorldStep, relative_positions, truth_from_poses
from swarm_env.comms import SwarmRadio
from swarm_env.config import SwarmConfig
from swarm_env.sensors.camera import CameraSensor
from swarm_env.sensors.detection_fade import thin_bearings, thin_points
from swarm_env.sensors.lidar import LidarSensor
from swarm_env.sensors.odometry import WheelEncoders
from swarm_env.sensors.scene import Scene
from swarm_env.world.arena import Layout, sample_layout, wall_segments
from swarm_env.world.diagnostics import LidarScanObserver, LidarScanTruth, SensorStats

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
# Ground truth through the compiled kernel from this many robots on (bit-identical to numpy;
# below it the call overhead costs more: 41 us against 29 us at 20 robots, 53 against 141 at
# 100).
_TRUTH_KERNEL_MIN_ROBOTS = 50


def robot_names(n: int) -> tuple[str, ...]:
    return tuple(f"ugv_{i}" for i in range(n))


class SimWorld:
    """The simulated World (see :class:`swarm_core.world.World`).

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
        self._next_camera_s = np.zeros(self.n_agents)
        self._next_odometry_s = 0.0
        self._lidar_visible = np.zeros((self.n_agents, n_total), dtype=bool)
        self._camera_visible = np.zeros((self.n_agents, n_total), dtype=bool)
        self.last_lidar: dict[int, LidarRecord] = {}
        self.last_camera: dict[int, CameraRecord] = {}
        self._scene_cache = {}  # Scene constants of this layout (see _scene_constants)
        self.stats = self._new_stats()
        #: Called with every period's :class:`LidarScanTruth` (calibration and diagnostics;
        #: none by default, when the truth per scan is not computed). Not kept by pickling:
        #: an env rebuilds its world when unpickled.
        self.lidar_scan_observers: list[LidarScanObserver] = []
        self.radio = SwarmRadio(config.comms, self.robot_ids) if config.comms.enabled else None
        # Wall-clock seconds spent per part and lidar scans run (for the benchmark).
        self.timing = {"physics_s": 0.0, "lidar_s": 0.0, "camera_s": 0.0, "lidar_scans": 0}
        #: Run the brute-force reference paths (every sensor reading against every shape, the
        #: numpy ground truth) instead of the grid-indexed and compiled ones: bit-identical
        #: results at O(N^2) cost per step (benchmarks/bench_scaling.py compares them).
        self.brute_force = False

    def _new_stats(self) -> dict[str, SensorStats]:
        # Lidar: matched within 0.15 m, counted within the tracking range. Camera: within 5 deg
        # (a blob centroid stays inside its strip: half its width is < 5 deg beyond 0.6 m) plus
        # 3 sigma of any extra bearing noise.
        camera = self.config.camera
        return {
            "lidar": SensorStats(range_m=self.config.localization_range_m, gate=0.15),
            "camera": SensorStats(
                range_m=camera.range_max_m,
                gate=np.deg2rad(5.0 + 3.0 * camera.bearing_noise_std_deg),
            ),
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
        self._next_camera_s = rng.uniform(0.0, 1.0 / cfg.camera.rate_hz, self.n_agents)
        self._next_odometry_s = 1.0 / cfg.odometry.rate_hz
        self._lidar_visible[:] = False
        self._camera_visible[:] = False
        self.last_lidar.clear()
        self.last_camera.clear()
        self.stats = self._new_stats()
        self._static_scene = self._static_geometry()
        self._scene_cache = {}  # Scene constants of this layout (see _scene_constants)
        if self.radio is not None:  # its own child stream: the radio never shifts sensor noise
            self.radio.reset(rng.spawn(1)[0])
        empty = {rid: RobotMeasurements() for rid in self.robot_ids}
        return WorldStep(time_s=0.0, measurements=empty, truth=self.ground_truth())

    def place_robots(self, poses: np.ndarray) -> None:
        """Move the robots to ``poses`` ``(N, 3)`` (world frame, ``[x_m, y_m, yaw_rad]``) with
        zero body velocity, between steps: a scenario's start formation, or a kidnapping (the
        motors keep their speeds, as a picked-up robot's wheels do). Their odometry does not
        notice, and the env's replay log does not record it (an env pickled after a placement
        re-simulates without it).

        Raises
        ------
        ValueError
            ``poses`` is not ``(n_agents, 3)`` finite numbers (nothing moves).
        """
        if self.space is None:
            raise RuntimeError("SimWorld.place_robots() called before reset()")
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (self.n_agents, 3) or not np.isfinite(poses).all():
            raise ValueError(
                f"poses must be {self.n_agents} finite rows [x_m, y_m, yaw_rad], got "
                f"shape {poses.shape}"
            )
        for k, (x, y, yaw) in enumerate(poses.tolist()):
            for body in (self.bodies[k], self._drives[k]):
                body.position = (x, y)
                body.angle = yaw
                body.velocity = (0.0, 0.0)
                body.angular_velocity = 0.0
            self.space.reindex_shapes_for_body(self.bodies[k])

    def halt(self) -> None:
        """Nothing to stop in simulation (see :meth:`swarm_core.world.World.halt`)."""

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
        buffer = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(space, pymunk.batch.BodyFields.BODY_ID, buffer)
        row_of = {int(i): r for r, i in enumerate(np.frombuffer(buffer.int_buf(), np.int64))}
        self._robot_rows = np.array([row_of[b.id] for b in self.bodies], dtype=np.intp)
        self._drive_rows = np.array([row_of[d.id] for d in self._drives], dtype=np.intp)

    # ------------------------------------------------------------------ stepping
    def step(self, commands: np.ndarray, extra_commands: np.ndarray | None = None) -> WorldStep:
        """Run one control period.

        Physics and encoders advance substep by substep; every sensor reading that falls due
        is noted with the substep it belongs to, and after the period all lidar scans and all
        camera frames are computed in one vectorised call each, against a scene that stacks the
        robots' poses at every substep. Each reading therefore sees the world exactly as it was
        at its own instant, at a fraction of the cost of one sensor call per substep.

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
            target[self.n_agents :] = extra_commands
        limits = np.array([cfg.robot.max_accel_mps2, cfg.robot.max_turn_accel_radps2])
        dt = cfg.physics_dt_s
        n_sub = cfg.physics_substeps
        poses = np.empty((n_sub, self.n_agents + self.n_extra, 3))
        stamps = np.empty(n_sub)
        odometry: list[list[OdometryRecord]] = [[] for _ in range(self.n_agents)]
        start_s = self.time_s
        t0 = time.perf_counter()
        # The motors slew towards the (constant) command at the acceleration limits, so the
        # speed after substep s is in closed form: all substeps at once, encoders included.
        reach = np.arange(1, n_sub + 1)[:, None, None] * (limits * dt)
        speeds = self.motor_speeds + np.clip(target - self.motor_speeds, -reach, reach)
        self.motor_speeds = speeds[-1].copy()
        wheel_angles = self.encoders.advance(speeds, dt, self._rng)  # (n_sub, R, 2)
        state = self._body_state()
        for sub in range(n_sub):
            self._set_body_velocities(
                _drive_velocities(state, self._robot_rows, self._drive_rows, speeds[sub], dt)
            )
            self.space.step(dt)
            self.time_s += dt
            state = self._body_state()
            poses[sub] = state[self._robot_rows, 0:3]
            stamps[sub] = t = self.time_s
            if self._next_odometry_s <= t + _EPS_S:
                # One shared encoder clock: all robots sample together at the odometry rate.
                delta, velocity = self.encoders.sample(t, wheel_angles[sub])
                delta.setflags(write=False)  # records hold row views (see records.py)
                velocity.setflags(write=False)
                make = OdometryRecord._make
                # Iterating the rows yields read-only row views, faster than indexing them.
                # The agents' rows come first (extras have no records): zip stops there.
                for rows, d, v in zip(odometry, delta, velocity, strict=False):
                    rows.append(make(t, d, v))
                self._next_odometry_s += 1.0 / cfg.odometry.rate_hz
        # Camera frames fall due on substep boundaries, each robot with its own phase.
        cam_robots, cam_substep = _due_readings(
            self._next_camera_s, stamps, 1.0 / cfg.camera.rate_hz, _EPS_S
        )
        self.timing["physics_s"] += time.perf_counter() - t0

        # A scan is due when a head completes a revolution (its own phase and spin rate, which
        # the interference model uses too); it sees the world of the substep that ends next.
        scanners, scan_stamps = self.lidar.scan_stamps(start_s, self.time_s)
        scan_substep = np.minimum(np.searchsorted(stamps, scan_stamps - _EPS_S), n_sub - 1)
        scene = self.scene(poses)  # one time-stacked scene serves every reading of the period
        lidar = self._read_lidars(scene, poses, scanners, scan_substep, scan_stamps)
        camera = self._read_cameras(scene, poses, stamps, cam_robots, cam_substep)
        make = RobotMeasurements._make
        measurements = {
            rid: make(o, li, c)
            for rid, o, li, c in zip(self.robot_ids, odometry, lidar, camera, strict=True)
        }
        truth = self.ground_truth(poses[-1])
        comms = {}
        if self.radio is not None:
            comms = self.radio.step(self.time_s, measurements, poses[-1, : self.n_agents, :2])
        return WorldStep(time_s=self.time_s, measurements=measurements, truth=truth, comms=comms)

    @property
    def _indexed(self) -> bool | None:
        """The sensors' ``indexed`` argument: the reference paths, or their own choice."""
        return False if self.brute_force else None

    # pymunk.batch reads and writes every body of the space in one C call, instead of four
    # Python property accesses per body per substep. Rows follow the space's body order (which
    # pickling keeps); ``_robot_rows`` and ``_drive_rows`` locate our bodies in it.
    _STATE_FIELDS = (
        pymunk.batch.BodyFields.POSITION
        | pymunk.batch.BodyFields.ANGLE
        | pymunk.batch.BodyFields.VELOCITY
        | pymunk.batch.BodyFields.ANGULAR_VELOCITY
    )
    _VELOCITY_FIELDS = pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY

    def _body_state(self) -> np.ndarray:
        """``[x, y, angle, vx, vy, omega]`` of every body in space order, shape (B, 6)."""
        buffer = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(self.space, self._STATE_FIELDS, buffer)
        return np.frombuffer(buffer.float_buf(), dtype=np.float64).reshape(-1, 6).copy()

    def _set_body_velocities(self, velocities: np.ndarray) -> None:
        """Write ``[vx, vy, omega]`` (B, 3) to every body, in space order."""
        buffer = pymunk.batch.Buffer()
        buffer.set_float_buf(np.ascontiguousarray(velocities, dtype=np.float64).ravel())
        pymunk.batch.set_space_bodies(self.space, self._VELOCITY_FIELDS, buffer)

    def _read_lidars(self, scene, poses, robots, when, scan_stamps) -> list[list[LidarRecord]]:
        """All scans of the period in one call: ``robots``, their substeps ``when`` and the
        revolution ends ``scan_stamps``, each (K,) in time order."""
        out: list[list[LidarRecord]] = [[] for _ in range(self.n_agents)]
        if robots.size == 0:
            return out
        t0 = time.perf_counter()
        batch = self.lidar.scan(
            scene, robots, scan_stamps, self._rng, time_index=when, indexed=self._indexed
        )
        detections = extract_detections(
            batch.angles_rad, batch.ranges_m, self.config.lidar_features
        )
        if self.config.lidar_fade is not None:  # a stated range curve (the Perera 2021 study's)
            detections = thin_points(detections, self.config.lidar_fade, self._rng)
        # Null bearings of every scan in one compiled pass, then sliced per scan.
        bounds, null_beam = null_beams(batch.ranges_m, batch.intensities, self.lidar.blind_mask)
        null_bearings = batch.angles_rad[null_beam]
        null_bearings.setflags(write=False)
        bounds = bounds.tolist()
        # Records keep read-only views: freezing the batch once makes every row view read-only.
        batch.ranges_m.setflags(write=False)
        batch.intensities.setflags(write=False)
        n_total = self.n_agents + self.n_extra
        # Later scans of a robot overwrite earlier ones: the mask is the last scan's.
        self._lidar_visible[robots] = batch.owner_beam_counts(n_total) > 0
        make, angles = LidarRecord._make, batch.angles_rad
        stamps = scan_stamps.tolist()
        rows = zip(robots.tolist(), stamps, batch.ranges_m, batch.intensities, strict=True)
        records = []
        for k, (i, stamp, ranges, intensities) in enumerate(rows):
            record = make(
                stamp,
                angles,
                ranges,
                intensities,
                detections[k],
                null_bearings[bounds[k] : bounds[k + 1]],
            )
            out[i].append(record)
            records.append(record)
            self.last_lidar[i] = record
        self.timing["lidar_s"] += time.perf_counter() - t0
        self.timing["lidar_scans"] += int(robots.size)
        if self.config.sensor_stats or self.lidar_scan_observers:
            arrays = {
                "robots": robots.copy(),
                "relative_xy": self._relative_at(poses)[when, robots],  # (K, N+E, 2)
                "beams_reaching": batch.owner_beam_counts(n_total, after_interference=False),
                "beams_returned": batch.owner_beam_counts(n_total, after_interference=True),
            }
            for array in arrays.values():
                array.setflags(write=False)
            truth = LidarScanTruth(**arrays, records=tuple(records))
            if self.config.sensor_stats:
                min_beams = self.config.lidar_features.min_beams
                for k, i in enumerate(robots.tolist()):
                    self.stats["lidar"].add_points(
                        detections[k],
                        np.delete(truth.relative_xy[k], i, axis=0),
                        np.delete(truth.beams_reaching[k], i),
                        np.delete(truth.beams_returned[k], i),
                        min_beams=min_beams,
                    )
            for observer in self.lidar_scan_observers:
                observer(truth)
        return out

    def _read_cameras(self, scene, poses, stamps, robots, when) -> list[list[CameraRecord]]:
        """All frames of the period in one call: ``robots`` and their substeps ``when`` (K,)."""
        out: list[list[CameraRecord]] = [[] for _ in range(self.n_agents)]
        if robots.size == 0:
            return out
        t0 = time.perf_counter()
        batch = self.camera.observe(
            scene, robots, self._rng, time_index=when, indexed=self._indexed
        )
        frames = batch.bearings
        if self.config.camera_fade is not None:  # a stated range curve (the Perera 2021 study's)
            origins, _ = scene.observer_poses(robots, when)
            frames, _ = thin_bearings(
                frames, batch.sources, scene.circle_xy, origins, self.config.camera_fade, self._rng
            )
            for bearings in frames:
                bearings.setflags(write=False)
        make = CameraRecord._make
        frame_stamps = stamps[when].tolist()
        for i, stamp, bearings in zip(robots.tolist(), frame_stamps, frames, strict=True):
            record = make(stamp, bearings)
            out[i].append(record)
            self.last_camera[i] = record
        # Later frames of a robot overwrite earlier ones: the mask is the last frame's.
        self._camera_visible[robots] = batch.visible
        self.timing["camera_s"] += time.perf_counter() - t0
        if self.config.sensor_stats:
            rel = self._relative_at(poses)
            for k, (i, sub) in enumerate(zip(robots.tolist(), when.tolist(), strict=True)):
                self.stats["camera"].add_bearings(frames[k], _others(rel[sub], i))
        return out

    def _relative_at(self, poses: np.ndarray) -> np.ndarray:
        """(T, N, N+E, 2): every body in every agent's frame at each substep (diagnostics)."""
        return np.stack([relative_positions(p[: self.n_agents], p) for p in poses])

    # ------------------------------------------------------------------ geometry
    def poses(self) -> np.ndarray:
        """``[x, y, yaw]`` of every body (agents first, then extras), shape (N+E, 3)."""
        return self._body_state()[self._robot_rows, 0:3]

    def _static_geometry(self) -> dict[str, np.ndarray]:
        cfg, layout = self.config, self.layout
        assert layout is not None
        n_post, n_red = len(layout.posts_xy), len(layout.red_decoys_xy)
        wall_a, wall_b = wall_segments(cfg.arena)
        box_a, box_b = layout.box_edges()
        return {
            "circle_xy": np.concatenate([layout.posts_xy, layout.red_decoys_xy]),
            "circle_radius_m": np.concatenate(
                [
                    np.full(n_post, cfg.arena.decoy_post_radius_m),
                    np.full(n_red, cfg.arena.red_decoy_radius_m),
                ]
            ),
            "circle_lidar": np.ones(n_post + n_red, dtype=bool),
            "circle_camera_occluder": np.r_[np.zeros(n_post, bool), np.ones(n_red, bool)],
            "circle_red": np.r_[np.zeros(n_post, bool), np.ones(n_red, bool)],
            "circle_intensity": np.r_[
                np.full(n_post, _INTENSITY_POST), np.full(n_red, _INTENSITY_OBSTACLE)
            ],
            "segment_a": np.concatenate([wall_a, box_a]),
            "segment_b": np.concatenate([wall_b, box_b]),
            "segment_intensity": np.r_[
                np.full(4, _INTENSITY_WALL), np.full(len(box_a), _INTENSITY_OBSTACLE)
            ],
        }

    def scene(self, poses: np.ndarray | None = None) -> Scene:
        """Geometry snapshot: static obstacles, then each robot's lidar housing and camera holder.

        Parameters
        ----------
        poses : ndarray, shape (N+E, 3) or (T, N+E, 3), optional
            Body poses at one instant (default: now) or at T instants (a time-stacked scene in
            which each robot's circles exist once per instant).
        """
        poses = self.poses() if poses is None else poses
        stacked = poses.ndim == 3
        p = poses if stacked else poses[None]
        xy = p[:, :, :2].reshape(-1, 2)
        fixed = self._scene_constants(p.shape[0], p.shape[1], stacked)
        return Scene(
            robot_xy=p[:, : self.n_agents, :2] if stacked else poses[: self.n_agents, :2],
            robot_yaw=p[:, : self.n_agents, 2] if stacked else poses[: self.n_agents, 2],
            circle_xy=np.concatenate([self._static_scene["circle_xy"], xy, xy]),
            **fixed,
        )

    def _scene_constants(self, n_time: int, n: int, stacked: bool) -> dict[str, np.ndarray]:
        """Every Scene field but the poses, for ``n`` bodies at ``n_time`` instants: the same
        at every step, so built once per layout and shape (read-only: scenes share them)."""
        key = (n_time, n, stacked)
        cache = self._scene_cache
        if key in cache:
            return cache[key]
        robot = self.config.robot
        static = self._static_scene
        n_static = len(static["circle_xy"])
        ids = np.tile(np.arange(n), n_time)
        m = n * n_time
        fixed = {
            "circle_radius_m": np.concatenate(
                [
                    static["circle_radius_m"],
                    np.full(m, robot.housing_radius_m),
                    np.full(m, robot.camera_holder_radius_m),
                ]
            ),
            "circle_owner": np.concatenate([np.full(n_static, -1), ids, ids]),
            "circle_lidar": np.concatenate(
                [static["circle_lidar"], np.ones(m, bool), np.zeros(m, bool)]
            ),
            "circle_camera_occluder": np.concatenate(
                [static["circle_camera_occluder"], np.zeros(m, bool), np.ones(m, bool)]
            ),
            "circle_red": np.concatenate(
                [static["circle_red"], np.zeros(m, bool), np.ones(m, bool)]
            ),
            "circle_intensity": np.concatenate(
                [static["circle_intensity"], np.full(2 * m, _INTENSITY_HOUSING)]
            ),
            "segment_a": static["segment_a"],
            "segment_b": static["segment_b"],
            "segment_intensity": static["segment_intensity"],
            "circle_time": (
                np.concatenate(
                    [
                        np.full(n_static, -1),
                        np.repeat(np.arange(n_time), n),
                        np.repeat(np.arange(n_time), n),
                    ]
                )
                if stacked
                else None
            ),
        }
        for value in fixed.values():
            if value is not None:
                value.setflags(write=False)
        cache[key] = fixed
        return fixed

    def ground_truth(self, poses: np.ndarray | None = None) -> GroundTruth:
        """True poses, relative positions, and per-sensor range and visibility masks.

        ``poses`` (N+E, 3) are the current body poses if the caller already has them.
        """
        poses = self.poses() if poses is None else poses
        if self.brute_force or self.n_agents < _TRUTH_KERNEL_MIN_ROBOTS:
            return self.ground_truth_reference(poses)
        agents = poses[: self.n_agents]
        # truth_from_poses's arrays in one compiled pass (its numpy temporaries cost ~0.1 s
        # per step at 1000 robots); the cosines stay numpy's so every value is the same.
        rel, lidar, camera = _truth_kernel(
            np.ascontiguousarray(agents[:, :2]),
            np.cos(agents[:, 2]),
            np.sin(agents[:, 2]),
            float(self.config.localization_range_m),
            float(self.config.camera.range_max_m),
        )
        return GroundTruth(
            poses=agents,
            relative_xy=rel,
            in_range={"lidar": lidar, "camera": camera},
            visible={
                "lidar": self._lidar_visible[:, : self.n_agents].copy(),
                "camera": self._camera_visible[:, : self.n_agents].copy(),
            },
            extra_xy=poses[self.n_agents :, :2].copy(),
        )

    def ground_truth_reference(self, poses: np.ndarray | None = None) -> GroundTruth:
        """:meth:`ground_truth` through :func:`swarm_core.world.truth_from_poses` (numpy): the
        reference of the compiled path (``tests/swarm_env/test_spatial_index.py``)."""
        poses = self.poses() if poses is None else poses
        return truth_from_poses(
            poses[: self.n_agents],
            self.config.localization_range_m,
            self.config.camera.range_max_m,
            visible={
                "lidar": self._lidar_visible[:, : self.n_agents].copy(),
                "camera": self._camera_visible[:, : self.n_agents].copy(),
            },
            extra_xy=poses[self.n_agents :, :2].copy(),
        )


@njit(cache=True, inline="always")
def _in_range(x, y, d2, lo, hi, range_m):
    """``hypot(x, y) <= range_m`` (m) given ``d2 = x^2 + y^2`` and ``lo < range_m^2 < hi``:
    the libm ``hypot`` only where ``d2`` is within ``[lo, hi]`` (see :func:`_truth_kernel`)."""
    if d2 < lo:
        return True
    if d2 > hi:
        return False
    return math.hypot(x, y) <= range_m


@njit(cache=True, parallel=True)
def _truth_kernel(xy, cos_yaw, sin_yaw, lidar_range_m, camera_range_m):
    """Relative positions (N, N, 2) and in-range masks (N, N) of robots at ``xy`` (N, 2) m with
    headings given by ``cos_yaw``, ``sin_yaw`` (N,): the expressions of
    :func:`swarm_core.world.relative_positions` and :func:`~swarm_core.world.truth_from_poses`
    (``hypot <= range``, off the diagonal), element by element.

    ``hypot`` (a libm call) is evaluated only where ``x^2 + y^2`` lies within 1e-12 of the
    squared range: elsewhere the two agree on the side of the range (both are within a few
    ulps of the true distance), so the masks are the numpy ones bit for bit, ~5x faster.
    """
    n = xy.shape[0]
    rel = np.empty((n, n, 2))
    lidar = np.empty((n, n), dtype=np.bool_)
    camera = np.empty((n, n), dtype=np.bool_)
    lidar_lo, lidar_hi = lidar_range_m**2 * (1.0 - 1e-12), lidar_range_m**2 * (1.0 + 1e-12)
    cam_lo, cam_hi = camera_range_m**2 * (1.0 - 1e-12), camera_range_m**2 * (1.0 + 1e-12)
    for i in prange(n):
        c, s = cos_yaw[i], sin_yaw[i]
        xi, yi = xy[i, 0], xy[i, 1]
        for j in range(n):
            dx = xy[j, 0] - xi
            dy = xy[j, 1] - yi
            x = c * dx + s * dy
            y = c * dy - s * dx
            rel[i, j, 0] = x
            rel[i, j, 1] = y
            d2 = x * x + y * y
            lidar[i, j] = _in_range(x, y, d2, lidar_lo, lidar_hi, lidar_range_m) and i != j
            camera[i, j] = _in_range(x, y, d2, cam_lo, cam_hi, camera_range_m) and i != j
    return rel, lidar, camera


@njit(cache=True)
def _drive_velocities(state, robot_rows, drive_rows, speeds, dt):
    """Body velocities ``[vx, vy, omega]`` (B, 3) for one substep: every body keeps its own,
    except the drive bodies, which move at the commanded ``speeds`` (R, 2) ``[v, omega]``
    along the chord of the substep's arc (the heading half a substep ahead). ``state`` is
    ``_body_state()`` (B, 6); ``dt`` in seconds."""
    out = state[:, 3:6].copy()
    for r in range(robot_rows.shape[0]):
        v, omega = speeds[r, 0], speeds[r, 1]
        heading = state[robot_rows[r], 2] + 0.5 * omega * dt
        d = drive_rows[r]
        out[d, 0] = v * np.cos(heading)
        out[d, 1] = v * np.sin(heading)
        out[d, 2] = omega
    return out


@njit(cache=True)
def _due_readings(next_s, stamps, period_s, eps_s):
    """Readings due at the substep ends ``stamps`` (S,), s: robot i reads when
    ``next_s[i] <= t + eps_s``, which then advances by ``period_s`` (in place).

    Returns ``robots`` (K,) and their substep indices (K,), in time order, robots ascending
    within a substep.
    """
    n = next_s.shape[0]
    robots = np.empty(n * stamps.shape[0], dtype=np.intp)
    substep = np.empty(n * stamps.shape[0], dtype=np.intp)
    k = 0
    for s in range(stamps.shape[0]):
        for i in range(n):
            if next_s[i] <= stamps[s] + eps_s:
                next_s[i] += period_s
                robots[k] = i
                substep[k] = s
                k += 1
    return robots[:k].copy(), substep[:k].copy()


def _others(rel: np.ndarray, i: int) -> np.ndarray:
    """Row i of a (N, N+E, 2) relative-position array without robot i itself."""
    return np.delete(rel[i], i, axis=0)
