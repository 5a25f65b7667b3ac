"""Rendering: a top-down view of the arena drawn with matplotlib (headless, Agg canvas).

It draws the walls and obstacles, every robot's footprint and heading, and for ``render_agent``
its last lidar scan (rays to valid returns), its lidar detections (crosses), its camera bearings
(dashed lines) and its PHD components (circles, alpha = weight). ``"rgb_array"`` returns the
frame; ``"human"`` also shows it in a pygame-ce window (``pip install swarm-phd[render]``), which
runs headless with ``SDL_VIDEODRIVER=dummy``.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv


def _rot(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


class Renderer:
    """Draws a :class:`SwarmEnv` into an RGB array, optionally mirrored to a window."""

    def __init__(self, env: SwarmEnv, mode: str, size_px: int = 640) -> None:
        import matplotlib

        matplotlib.use("Agg", force=False)
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.env = env
        self.mode = mode
        dpi = 100
        self.fig = Figure(figsize=(size_px / dpi, size_px / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes((0.02, 0.02, 0.96, 0.96))
        self._window = None
        if mode == "human":
            try:
                import pygame
            except ImportError as exc:
                from gymnasium.error import DependencyNotInstalled

                raise DependencyNotInstalled(
                    'render_mode="human" needs pygame-ce: pip install "swarm-phd[render]"'
                ) from exc
            if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
                os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # headless-safe
            pygame.display.init()
            self._window = pygame.display.set_mode((size_px, size_px))
            pygame.display.set_caption("swarm-phd")
            self._pygame = pygame

    def draw(self) -> np.ndarray | None:
        frame = self._draw_frame()
        if self._window is not None:
            pygame = self._pygame
            surface = pygame.surfarray.make_surface(frame.swapaxes(0, 1))
            self._window.blit(surface, (0, 0))
            pygame.event.pump()
            pygame.display.flip()
            return None
        return frame

    def _draw_frame(self) -> np.ndarray:
        env, ax = self.env, self.ax
        world = env.world
        ax.clear()
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        arena = env.config.arena
        hx, hy = 0.5 * arena.width_m, 0.5 * arena.height_m
        ax.set_xlim(-hx - 0.2, hx + 0.2)
        ax.set_ylim(-hy - 0.2, hy + 0.2)
        ax.plot([hx, -hx, -hx, hx, hx], [hy, hy, -hy, -hy, hy], color="k", lw=3)
        truth = env.last_world_step.truth if env.last_world_step is not None else None
        layout = getattr(world, "layout", None)
        if layout is not None:
            for corners in layout.box_corners():
                ax.fill(corners[:, 0], corners[:, 1], color="0.45")
            ax.scatter(*layout.posts_xy.T, s=18, color="tab:brown", marker="o", label="decoy post")
            ax.scatter(
                *layout.red_decoys_xy.T, s=40, color="tab:red", marker="s", label="red decoy"
            )
        if truth is None:
            self.canvas.draw()
            return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()
        robot = env.config.robot
        half = 0.5 * np.array([robot.length_m, robot.width_m])
        box = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1], [1, 1]]) * half
        focus = env.possible_agents.index(env.render_agent)
        for i, (x, y, yaw) in enumerate(truth.poses):
            pts = box @ _rot(yaw).T + (x, y)
            color = "tab:blue" if i == focus else "tab:green"
            ax.fill(pts[:, 0], pts[:, 1], color=color, alpha=0.6)
            ax.plot([x, x + 0.2 * np.cos(yaw)], [y, y + 0.2 * np.sin(yaw)], color="k", lw=1)
        for x, y in truth.extra_xy:
            ax.scatter([x], [y], s=120, color="tab:purple", marker="*")
        self._draw_focus(focus, truth.poses[focus])
        ax.set_title(f"t = {env.time_s:6.1f} s   focus: {env.render_agent}", fontsize=9)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()

    def _draw_focus(self, i: int, pose: np.ndarray) -> None:
        """The focus robot's scan, detections, bearings and PHD, transformed to the world frame."""
        ax, env = self.ax, self.env
        rot, origin = _rot(pose[2]), pose[:2]
        records = env.last_world_step.measurements.get(env.possible_agents[i])
        if records is not None and records.lidar:
            scan = records.lidar[-1]
            valid = scan.ranges_m > 0
            ends = np.column_stack([np.cos(scan.angles_rad), np.sin(scan.angles_rad)])
            ends = (ends[valid] * scan.ranges_m[valid, None]) @ rot.T + origin
            segs = np.stack([np.broadcast_to(origin, ends.shape), ends], axis=1)[::4]
            from matplotlib.collections import LineCollection

            ax.add_collection(LineCollection(segs, colors="tab:orange", linewidths=0.3, alpha=0.5))
            if len(scan.detections):
                det = scan.detections @ rot.T + origin
                ax.scatter(det[:, 0], det[:, 1], marker="x", color="k", s=30, zorder=5)
        if records is not None and records.camera:
            for b in records.camera[-1].bearings_rad:
                end = origin + rot @ (3.0 * np.array([np.cos(b), np.sin(b)]))
                ax.plot([origin[0], end[0]], [origin[1], end[1]], "r--", lw=0.7)
        mixture = env.localizers[i].mixture
        if len(mixture.weights):
            means = mixture.means @ rot.T + origin
            alpha = np.clip(mixture.weights, 0.05, 1.0)
            ax.scatter(
                means[:, 0],
                means[:, 1],
                s=150,
                facecolors="none",
                edgecolors=[(0.1, 0.1, 0.8, a) for a in alpha],
                linewidths=1.5,
                zorder=6,
            )

    def close(self) -> None:
        if self._window is not None:
            self._pygame.display.quit()
            self._window = None
