"""Build :class:`~swarm_env.sensors.scene.Scene` snapshots directly with numpy, without physics.

For controlled sensor experiments (the detection-curve and speed benchmarks) and the tests::

    b = SceneBuilder()
    i = b.add_robot(0.0, 0.0, yaw_rad=0.0)      # housing (lidar) + red strip (camera) circles
    b.add_post(1.0, 0.5)                         # lidar-height decoy post, r = 30 mm
    b.add_red_decoy(2.0, -1.0)                   # red blob, camera only
    b.add_box(3.0, 0.0, 0.4, 0.3)                # 4 segments
    b.add_walls(6.0, 6.0)                        # arena walls centred on the origin
    scene = b.build()

``make_arena_scene(rng, ...)`` draws a random arena like Perera 2021's (6 m x 6 m, 20 robots);
``make_pair_scene(rng, range_m, n_pairs)`` isolated (observer, target) pairs at one range, for
detection-probability measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from swarm_env.sensors.scene import Scene

HOUSING_RADIUS_M = 0.0325  # YDLidar X4 housing, 65 mm diameter (Perera 2021)
STRIP_RADIUS_M = 0.045  # red strip around the camera holder
POST_RADIUS_M = 0.03  # decoy post: slimmer than a housing, so the lidar extractor accepts it
RED_DECOY_RADIUS_M = 0.05


@dataclass
class SceneBuilder:
    """Accumulates robots, circles and segments; :meth:`build` freezes them into a Scene."""

    robot_xy: list = field(default_factory=list)
    robot_yaw: list = field(default_factory=list)
    circles: list = field(default_factory=list)  # (x, y, r, owner, lidar, occluder, red, intens.)
    segments: list = field(default_factory=list)  # (ax, ay, bx, by, intensity)

    def add_robot(
        self,
        x: float,
        y: float,
        yaw_rad: float = 0.0,
        housing: bool = True,
        strip: bool = True,
        intensity: float = 1.0,
        strip_radius_m: float = STRIP_RADIUS_M,
    ) -> int:
        """Add a robot: a lidar housing and a red camera-holder strip, both at its centre."""
        idx = len(self.robot_xy)
        self.robot_xy.append((x, y))
        self.robot_yaw.append(yaw_rad)
        if housing:
            self.add_circle(x, y, HOUSING_RADIUS_M, owner=idx, lidar=True, intensity=intensity)
        if strip:
            self.add_circle(x, y, strip_radius_m, owner=idx, lidar=False, occluder=True, red=True)
        return idx

    def add_circle(
        self,
        x: float,
        y: float,
        radius_m: float,
        owner: int = -1,
        lidar: bool = True,
        occluder: bool = False,
        red: bool = False,
        intensity: float = 1.0,
    ) -> int:
        self.circles.append((x, y, radius_m, owner, lidar, occluder, red, intensity))
        return len(self.circles) - 1

    def add_post(self, x: float, y: float, radius_m: float = POST_RADIUS_M) -> int:
        """A decoy post at lidar height that also blocks the camera."""
        return self.add_circle(x, y, radius_m, lidar=True, occluder=True, intensity=0.8)

    def add_red_decoy(self, x: float, y: float, radius_m: float = RED_DECOY_RADIUS_M) -> int:
        """A red object above lidar height: a camera false positive."""
        return self.add_circle(x, y, radius_m, lidar=False, occluder=True, red=True)

    def add_segment(self, ax: float, ay: float, bx: float, by: float, intensity=0.5) -> int:
        self.segments.append((ax, ay, bx, by, intensity))
        return len(self.segments) - 1

    def add_box(self, cx: float, cy: float, width_m: float, height_m: float, yaw_rad=0.0) -> None:
        hx, hy = 0.5 * width_m, 0.5 * height_m
        corners = np.array([(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)])
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        corners = corners @ np.array([[c, s], [-s, c]]) + (cx, cy)
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]
            self.add_segment(a[0], a[1], b[0], b[1], intensity=0.6)

    def add_walls(self, width_m: float, height_m: float) -> None:
        """Arena walls: a rectangle centred on the world origin."""
        hx, hy = 0.5 * width_m, 0.5 * height_m
        corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]
            self.add_segment(a[0], a[1], b[0], b[1], intensity=0.5)

    def build(self) -> Scene:
        circles = np.array(self.circles, dtype=np.float64).reshape(-1, 8)
        segments = np.array(self.segments, dtype=np.float64).reshape(-1, 5)
        return Scene(
            robot_xy=np.array(self.robot_xy, dtype=np.float64).reshape(-1, 2),
            robot_yaw=np.array(self.robot_yaw, dtype=np.float64).reshape(-1),
            circle_xy=circles[:, 0:2].copy(),
            circle_radius_m=circles[:, 2].copy(),
            circle_owner=circles[:, 3].astype(np.intp),
            circle_lidar=circles[:, 4].astype(bool),
            circle_camera_occluder=circles[:, 5].astype(bool),
            circle_red=circles[:, 6].astype(bool),
            circle_intensity=circles[:, 7].copy(),
            segment_a=segments[:, 0:2].copy(),
            segment_b=segments[:, 2:4].copy(),
            segment_intensity=segments[:, 4].copy(),
        )


def make_arena_scene(
    rng: np.random.Generator,
    n_robots: int = 20,
    n_posts: int = 10,
    n_red_decoys: int = 5,
    n_boxes: int = 4,
    size_m: float = 6.0,
    clearance_m: float = 0.25,
) -> Scene:
    """A random walled arena like Perera 2021's (6 m x 6 m, 20 robots), objects non-overlapping.

    Boxes (0.3-0.6 m sides) are placed first, then robots, posts and red decoys by rejection
    sampling with ``clearance_m`` between centres and from walls and boxes.
    """
    b = SceneBuilder()
    b.add_walls(size_m, size_m)
    half = 0.5 * size_m - clearance_m
    boxes = []
    while len(boxes) < n_boxes:
        cx, cy = rng.uniform(-half + 0.4, half - 0.4, size=2)
        w, h = rng.uniform(0.3, 0.6, size=2)
        if all(
            abs(cx - bx) > 0.5 * (w + bw) + 0.3 or abs(cy - by) > 0.5 * (h + bh) + 0.3
            for bx, by, bw, bh in boxes
        ):
            boxes.append((cx, cy, w, h))
            b.add_box(cx, cy, w, h)
    points: list[tuple[float, float]] = []

    def free_point() -> tuple[float, float]:
        while True:
            x, y = rng.uniform(-half, half, size=2)
            if any(
                abs(x - bx) < 0.5 * bw + clearance_m and abs(y - by) < 0.5 * bh + clearance_m
                for bx, by, bw, bh in boxes
            ):
                continue
            if all((x - px) ** 2 + (y - py) ** 2 > clearance_m**2 for px, py in points):
                points.append((x, y))
                return x, y

    for _ in range(n_robots):
        x, y = free_point()
        b.add_robot(x, y, yaw_rad=rng.uniform(-np.pi, np.pi))
    for _ in range(n_posts):
        b.add_post(*free_point())
    for _ in range(n_red_decoys):
        b.add_red_decoy(*free_point())
    return b.build()


#: Pairs of :func:`make_pair_scene` are this far apart: beyond every sensor's reach.
PAIR_SPACING_M = 25.0


def _bearing_outside(rng: np.random.Generator, centers: np.ndarray, half: np.ndarray) -> float:
    """A uniform bearing (rad) outside the sectors ``centers +/- half`` (rad), by rejection."""
    while True:
        bearing = rng.uniform(-np.pi, np.pi)
        off = np.abs((bearing - centers + np.pi) % (2 * np.pi) - np.pi)
        if not (off <= half).any():
            return bearing


def make_pair_scene(
    rng: np.random.Generator,
    range_m: float,
    n_pairs: int,
    strip_radius_m: float = STRIP_RADIUS_M,
    avoid_centers_deg: tuple[float, ...] = (),
    avoid_half_widths_deg: tuple[float, ...] = (),
    bearings_rad: np.ndarray | None = None,
) -> tuple[Scene, np.ndarray]:
    """``n_pairs`` isolated (observer, target) robot pairs, the target at ``range_m``.

    Robot ``2 p`` observes robot ``2 p + 1``; pairs sit on a grid ``PAIR_SPACING_M`` apart, so
    no sensor sees another pair. Each observer has a random yaw (so a random beam phase) and
    its target a random bearing, uniform outside the robot-frame sectors ``avoid_centers_deg``
    +/- ``avoid_half_widths_deg`` (e.g. the lidar's blind sectors), or the given
    ``bearings_rad`` (n_pairs,) (robot frame, rad).

    Returns
    -------
    scene : Scene
    bearings_rad : ndarray, shape (n_pairs,)
        Each target's true bearing in its observer's frame.
    """
    b = SceneBuilder()
    side = int(math.ceil(math.sqrt(n_pairs)))
    centers = np.deg2rad(np.asarray(avoid_centers_deg, dtype=np.float64))
    half = np.deg2rad(np.asarray(avoid_half_widths_deg, dtype=np.float64))
    if bearings_rad is not None and np.shape(bearings_rad) != (n_pairs,):
        raise ValueError(
            f"bearings_rad must have shape ({n_pairs},), got {np.shape(bearings_rad)}"
        )
    bearings = np.empty(n_pairs)
    for p in range(n_pairs):
        ox, oy = (p % side) * PAIR_SPACING_M, (p // side) * PAIR_SPACING_M
        yaw = rng.uniform(-np.pi, np.pi)
        if bearings_rad is None:
            bearing = _bearing_outside(rng, centers, half)
        else:
            bearing = float(bearings_rad[p])
        bearings[p] = bearing
        b.add_robot(ox, oy, yaw_rad=yaw, strip_radius_m=strip_radius_m)
        b.add_robot(
            ox + range_m * math.cos(yaw + bearing),
            oy + range_m * math.sin(yaw + bearing),
            yaw_rad=rng.uniform(-np.pi, np.pi),
            strip_radius_m=strip_radius_m,
        )
    return b.build(), bearings
