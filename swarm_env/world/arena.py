"""Arena layout: walls, seeded obstacles and non-overlapping spawn poses (no physics here)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm_env.config import ArenaConfig, RobotConfig

_MAX_TRIES = 20_000


@dataclass(frozen=True, slots=True)
class Layout:
    """Static geometry of one episode, world frame, metres.

    Attributes
    ----------
    posts_xy : ndarray, shape (P, 2)
        Decoy posts (robot-sized lidar false positives).
    red_decoys_xy : ndarray, shape (D, 2)
        Red decoys (camera false positives).
    boxes : ndarray, shape (B, 5)
        ``[cx, cy, size_x, size_y, yaw]`` of box obstacles.
    """

    posts_xy: np.ndarray
    red_decoys_xy: np.ndarray
    boxes: np.ndarray

    def box_corners(self) -> np.ndarray:
        """Corners of every box, shape (B, 4, 2), counter-clockwise."""
        if len(self.boxes) == 0:
            return np.zeros((0, 4, 2))
        half = 0.5 * self.boxes[:, 2:4]
        local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float)
        pts = local[None, :, :] * half[:, None, :]
        c, s = np.cos(self.boxes[:, 4]), np.sin(self.boxes[:, 4])
        rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (B,2,2)
        return np.einsum("bij,bkj->bki", rot, pts) + self.boxes[:, None, 0:2]

    def box_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Edges of every box as segment end points, shapes (4B, 2) and (4B, 2)."""
        corners = self.box_corners()
        return corners.reshape(-1, 2), np.roll(corners, -1, axis=1).reshape(-1, 2)


def wall_segments(arena: ArenaConfig) -> tuple[np.ndarray, np.ndarray]:
    """The four inner wall faces as segments (what sensors see), shapes (4, 2), (4, 2)."""
    hx, hy = 0.5 * arena.width_m, 0.5 * arena.height_m
    corners = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return corners, np.roll(corners, -1, axis=0)


def sample_layout(
    arena: ArenaConfig,
    robot: RobotConfig,
    n_robots: int,
    clearance_m: float,
    rng: np.random.Generator,
) -> tuple[Layout, np.ndarray]:
    """Draw obstacles, then robot poses, so that nothing overlaps anything.

    Returns
    -------
    layout : Layout
    poses : ndarray, shape (n_robots, 3)
        ``[x, y, yaw]`` spawn poses.

    Raises
    ------
    ValueError
        If the arena is too crowded to place everything (names the counts).
    """
    low, high = arena.box_size_range_m
    largest = max(
        0.5 * float(np.hypot(high, high)),
        arena.decoy_post_radius_m,
        arena.red_decoy_radius_m,
        robot.footprint_radius_m,
    )
    # A cell list of what is placed (a dict of square cells): a candidate is tested only
    # against objects near enough to touch it, so spawning costs O(n), not O(n^2), and
    # accepts exactly the candidates the test against every placed object would.
    cell_m = 2.0 * largest + clearance_m
    cells: dict[tuple[int, int], list[tuple[float, float, float]]] = {}

    def clear(x: float, y: float, radius: float) -> bool:
        # Nothing placed can overlap beyond `reach` (inflated against rounding).
        reach = (radius + largest + clearance_m) * (1.0 + 1e-9)
        for ix in range(math.floor((x - reach) / cell_m), math.floor((x + reach) / cell_m) + 1):
            for iy in range(
                math.floor((y - reach) / cell_m), math.floor((y + reach) / cell_m) + 1
            ):
                for px, py, pr in cells.get((ix, iy), ()):
                    if (x - px) ** 2 + (y - py) ** 2 < (radius + pr + clearance_m) ** 2:
                        return False
        return True

    def place(radius: float) -> tuple[float, float]:
        hx = 0.5 * arena.width_m - radius - clearance_m
        hy = 0.5 * arena.height_m - radius - clearance_m
        if hx <= 0 or hy <= 0:
            raise ValueError(f"an object of radius {radius:.3f} m does not fit the arena")
        for _ in range(_MAX_TRIES):
            x, y = rng.uniform(-hx, hx), rng.uniform(-hy, hy)
            if clear(x, y, radius):
                key = (math.floor(x / cell_m), math.floor(y / cell_m))
                cells.setdefault(key, []).append((x, y, radius))
                return x, y
        raise ValueError(
            f"could not place {n_robots} robots, {arena.n_boxes} boxes, {arena.n_decoy_posts} "
            f"posts and {arena.n_red_decoys} red decoys without overlap in a "
            f"{arena.width_m} m x {arena.height_m} m arena: lower n_robots, arena.n_boxes, "
            "arena.n_decoy_posts or arena.n_red_decoys"
        )

    boxes = []
    for _ in range(arena.n_boxes):
        size = rng.uniform(low, high, size=2)
        yaw = rng.uniform(-np.pi, np.pi)
        x, y = place(0.5 * float(np.hypot(*size)))
        boxes.append([x, y, size[0], size[1], yaw])
    posts = [place(arena.decoy_post_radius_m) for _ in range(arena.n_decoy_posts)]
    reds = [place(arena.red_decoy_radius_m) for _ in range(arena.n_red_decoys)]
    robots = [place(robot.footprint_radius_m) for _ in range(n_robots)]
    yaws = rng.uniform(-np.pi, np.pi, size=n_robots)
    layout = Layout(
        posts_xy=np.array(posts, dtype=float).reshape(-1, 2),
        red_decoys_xy=np.array(reds, dtype=float).reshape(-1, 2),
        boxes=np.array(boxes, dtype=float).reshape(-1, 5),
    )
    poses = np.column_stack([np.array(robots, dtype=float).reshape(-1, 2), yaws])
    return layout, poses
