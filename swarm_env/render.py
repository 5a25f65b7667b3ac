"""Rendering: a top-down view of the arena drawn with matplotlib (headless, Agg canvas).

One frame shows, in world metres (REP-103: x right/forward, y up/left, yaw CCW):

- the walls, boxes, decoy posts and red decoys; every robot's footprint and heading;
- for the focus robot (``render_agent``): its body frame (x arrow red, y arrow green), its last
  lidar scan (rays to the measured range of each valid return, every 2nd beam; returns as
  dots; no-return beams are not drawn), its lidar detections (crosses), its camera bearings
  (dashed, to the camera's range: a bearing has no range), and its PHD estimate as 2-sigma
  covariance ellipses whose opacity is the component weight (clipped to [0.1, 1]), placed at its
  true pose so each ellipse sits next to the teammate it estimates;
- a legend, axes in metres with labels, a title with the time, and a caption line.

The scan and frame drawn are the newest ones the renderer has seen (lidar runs at 7 Hz, the env
at 10 Hz: a step without a scan shows the previous one, with its age in the caption).

``"rgb_array"`` returns the frame; ``"human"`` also shows it in a pygame-ce window
(``pip install swarm-phd[render]``), which runs headless with ``SDL_VIDEODRIVER=dummy``.
:func:`draw_scene` draws the same picture into any matplotlib axes (the demo's side-by-side
truth / lidar-only / lidar + camera figure uses it).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv

#: 2-sigma ellipse of a 2-D Gaussian: sqrt of the 95 % chi-square quantile with 2 dof.
ELLIPSE_SCALE = float(np.sqrt(5.991464547107979))
FOCUS_COLOR = "tab:blue"
TEAM_COLOR = "tab:green"
ESTIMATE_COLOR = (0.55, 0.0, 0.75)  # purple: distinct from robots, rays and bearings
RAY_COLOR = "tab:orange"
BEARING_COLOR = "tab:red"


def _rot(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def ellipse_params(cov: np.ndarray, scale: float = ELLIPSE_SCALE) -> tuple[float, float, float]:
    """Width, height (m, full axes) and angle (deg, CCW from x) of ``scale``-sigma ellipse of
    the 2x2 covariance ``cov`` (m^2)."""
    vals, vecs = np.linalg.eigh(np.asarray(cov, dtype=float))
    vals = np.clip(vals, 0.0, None)
    major = vecs[:, 1]
    angle = float(np.degrees(np.arctan2(major[1], major[0])))
    return 2 * scale * float(np.sqrt(vals[1])), 2 * scale * float(np.sqrt(vals[0])), angle


class SensorMemory:
    """The newest lidar scan and camera frame of one robot seen so far (see module doc)."""

    def __init__(self) -> None:
        self.agent: str | None = None
        self.lidar: Any = None
        self.camera: Any = None

    def update(self, env: SwarmEnv, agent: str) -> None:
        if agent != self.agent:
            self.agent, self.lidar, self.camera = agent, None, None
        step = env.last_world_step
        if step is None:
            self.lidar = self.camera = None
            return
        records = step.measurements.get(agent)
        if records is not None and records.lidar:
            self.lidar = records.lidar[-1]
        if records is not None and records.camera:
            self.camera = records.camera[-1]


def draw_scene(
    ax: Any,
    env: SwarmEnv,
    focus: str | None = None,
    mixture: Any = None,
    sensors: SensorMemory | None = None,
    show_sensors: bool = True,
    show_estimate: bool = True,
    title: str | None = None,
    legend: bool = True,
) -> list[str]:
    """Draw ``env``'s current state into ``ax``; return caption fragments.

    ``mixture`` (robot frame of ``focus``) defaults to the env's own estimate of ``focus``.
    ``sensors`` carries the newest scan/frame across calls (default: this step's only).
    """
    draw_static(ax, env)
    if title is not None:
        ax.set_title(title, fontsize=9)
    if legend:
        add_legend(ax, env)
    return draw_dynamic(ax, env, focus, mixture, sensors, show_sensors, show_estimate)


def draw_static(ax: Any, env: SwarmEnv) -> None:
    """What does not move during an episode: limits, labels, grid, walls, boxes, decoys."""
    from matplotlib.patches import Polygon

    world = env.world
    ax.set_aspect("equal")
    arena = env.config.arena
    hx, hy = 0.5 * arena.width_m, 0.5 * arena.height_m
    margin = 0.15
    ax.set_xlim(-hx - margin, hx + margin)
    ax.set_ylim(-hy - margin, hy + margin)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.tick_params(labelsize=7)
    ax.grid(True, lw=0.3, alpha=0.4)
    ax.plot([hx, -hx, -hx, hx, hx], [hy, hy, -hy, -hy, hy], color="k", lw=2.5, label="wall")
    layout = getattr(world, "layout", None)
    if layout is not None:
        for k, corners in enumerate(layout.box_corners()):
            ax.add_patch(
                Polygon(corners, closed=True, color="0.5", label="box" if k == 0 else None)
            )
        if len(layout.posts_xy):
            ax.scatter(*layout.posts_xy.T, s=14, color="tab:brown", marker="o", label="decoy post")
        if len(layout.red_decoys_xy):
            ax.scatter(
                *layout.red_decoys_xy.T, s=30, color="tab:red", marker="s", label="red decoy"
            )


def legend_handles(env: SwarmEnv, focus: str | None = None) -> tuple[list[Any], list[str]]:
    """One proxy handle per kind of mark :func:`draw_scene` can draw (a fixed legend: the same
    entries on every frame, whether or not a detection or a component is present)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    focus = env.render_agent if focus is None else focus
    reach = float(getattr(env.config.camera, "range_max_m", 2.0))
    entries = [
        (Line2D([], [], color="k", lw=2.5), "wall"),
        (Patch(color="0.5"), "box"),
        (Line2D([], [], ls="", marker="o", ms=4, color="tab:brown"), "decoy post"),
        (Line2D([], [], ls="", marker="s", ms=5, color="tab:red"), "red decoy"),
        (Patch(facecolor=FOCUS_COLOR, edgecolor="k", alpha=0.8), f"{focus} (focus)"),
        (Patch(facecolor=TEAM_COLOR, edgecolor="k", alpha=0.8), "teammate (truth)"),
        (Line2D([], [], color="red", lw=1.5), "body x (forward)"),
        (Line2D([], [], color="green", lw=1.5), "body y (left)"),
        (Line2D([], [], ls="", marker="o", ms=2, color=RAY_COLOR), "lidar return (ray to range)"),
        (Line2D([], [], ls="", marker="x", ms=6, color="k"), "lidar detection"),
        (Line2D([], [], ls="--", lw=0.9, color=BEARING_COLOR), f"camera bearing (to {reach:g} m)"),
        (
            Patch(facecolor=(*ESTIMATE_COLOR, 0.25), edgecolor=ESTIMATE_COLOR),
            "PHD component (2σ, opacity = weight)",
        ),
    ]
    step = env.last_world_step
    if step is not None and step.truth is not None and len(step.truth.extra_xy):
        entries.append((Line2D([], [], ls="", marker="*", ms=9, color="tab:purple"), "intruder"))
    return [h for h, _ in entries], [label for _, label in entries]


def add_legend(ax: Any, env: SwarmEnv) -> None:
    handles, labels = legend_handles(env)
    ax.legend(
        handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False
    )


def draw_dynamic(
    ax: Any,
    env: SwarmEnv,
    focus: str | None = None,
    mixture: Any = None,
    sensors: SensorMemory | None = None,
    show_sensors: bool = True,
    show_estimate: bool = True,
) -> list[str]:
    """What moves: robots, the focus robot's frame, scan, detections, bearings and estimate.
    Returns caption fragments."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Ellipse, Polygon

    focus = env.render_agent if focus is None else focus
    caption: list[str] = []
    step = env.last_world_step
    truth = step.truth if step is not None else None
    if truth is None:
        return caption
    i_focus = env.possible_agents.index(focus)
    robot = env.config.robot
    half = 0.5 * np.array([robot.length_m, robot.width_m])
    box = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * half
    heading = 0.6 * robot.length_m
    first_mate = 1 if i_focus == 0 else 0
    for i, (x, y, yaw) in enumerate(truth.poses):
        is_focus = i == i_focus
        pts = box @ _rot(yaw).T + (x, y)
        label = f"{focus} (focus)" if is_focus else "teammate (truth)" if i == first_mate else None
        ax.add_patch(
            Polygon(
                pts,
                closed=True,
                facecolor=FOCUS_COLOR if is_focus else TEAM_COLOR,
                edgecolor="k",
                lw=0.4,
                alpha=0.8,
                label=label,
                zorder=4,
            )
        )
        if not is_focus:
            ax.plot(
                [x, x + heading * np.cos(yaw)],
                [y, y + heading * np.sin(yaw)],
                "k-",
                lw=0.8,
                zorder=5,
            )
    if len(truth.extra_xy):
        ax.scatter(
            *np.asarray(truth.extra_xy).T,
            s=90,
            color="tab:purple",
            marker="*",
            label="intruder",
            zorder=5,
        )
    pose = truth.poses[i_focus]
    rot, origin = _rot(pose[2]), pose[:2]
    arrow = 2.2 * robot.length_m
    for axis, color in ((0, "red"), (1, "green")):  # REP-103 axis colours
        d = rot[:, axis] * arrow
        ax.annotate(
            "",
            xy=(origin[0] + d[0], origin[1] + d[1]),
            xytext=(origin[0], origin[1]),
            arrowprops={"arrowstyle": "-|>", "color": color, "lw": 1.5},
            zorder=7,
        )
    if show_sensors:
        if sensors is None:
            sensors = SensorMemory()
            sensors.update(env, focus)
        scan, frame = sensors.lidar, sensors.camera
        if scan is not None:
            valid = scan.ranges_m > 0
            unit = np.column_stack([np.cos(scan.angles_rad), np.sin(scan.angles_rad)])
            hits = (unit[valid] * scan.ranges_m[valid, None]) @ rot.T + origin
            rays = np.stack([np.broadcast_to(origin, hits.shape), hits], axis=1)[::2]
            ax.add_collection(
                LineCollection(rays, colors=RAY_COLOR, linewidths=0.25, alpha=0.35, zorder=2)
            )
            ax.scatter(
                hits[:, 0],
                hits[:, 1],
                s=1.5,
                color=RAY_COLOR,
                zorder=3,
                label="lidar return (ray to range)",
            )
            det = scan.detections
            caption.append(f"lidar scan {env.time_s - scan.stamp_s:.2f} s old")
        else:  # no scan seen yet (7 Hz lidar, 10 Hz steps): the env's held detections only
            held = getattr(env, "last_detections", None)
            det = None if held is None else np.asarray(held[i_focus]).reshape(-1, 2)
            caption.append("no lidar scan in this step (rays not drawn)")
        if det is not None and len(det):
            det = det @ rot.T + origin
            ax.scatter(
                det[:, 0],
                det[:, 1],
                marker="x",
                color="k",
                s=28,
                lw=1.0,
                zorder=8,
                label="lidar detection",
            )
        if frame is not None and len(frame.bearings_rad):
            reach = float(getattr(env.config.camera, "range_max_m", 2.0))
            b = np.asarray(frame.bearings_rad)
            ends = (reach * np.column_stack([np.cos(b), np.sin(b)])) @ rot.T + origin
            segs = np.stack([np.broadcast_to(origin, ends.shape), ends], axis=1)
            ax.add_collection(
                LineCollection(
                    segs, colors=BEARING_COLOR, linewidths=0.9, linestyles="--", zorder=6
                )
            )
    if show_estimate:
        if mixture is None:
            mixture = env.localizers[i_focus].mixture
        weights = np.asarray(mixture.weights)
        if len(weights):
            means = np.asarray(mixture.means) @ rot.T + origin
            covs = rot @ np.asarray(mixture.covs) @ rot.T
            order = np.argsort(weights)  # heaviest on top
            for n, k in enumerate(order):
                w, h, angle = ellipse_params(covs[k])
                alpha = float(np.clip(weights[k], 0.1, 1.0))
                ax.add_patch(
                    Ellipse(
                        means[k],
                        max(w, 0.02),
                        max(h, 0.02),
                        angle=angle,
                        facecolor=(*ESTIMATE_COLOR, 0.25 * alpha),
                        edgecolor=(*ESTIMATE_COLOR, alpha),
                        lw=1.2,
                        zorder=6,
                        label="PHD component (2σ, opacity = weight)"
                        if n == len(order) - 1
                        else None,
                    )
                )
            caption.append(f"{len(weights)} components, expected teammates {weights.sum():.1f}")
    return caption


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
        width_px = int(round(1.45 * size_px))  # the legend sits right of the arena
        self.fig = Figure(figsize=(width_px / dpi, size_px / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes((0.08, 0.1, 0.6, 0.82))
        self.sensors = SensorMemory()
        self._background: Any = None
        self._key: tuple | None = None
        self._dynamic: list[Any] = []
        self.title_text: Any = None
        self.caption_text: Any = None
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
            self._window = pygame.display.set_mode((width_px, size_px))
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
        """Blitting: the static layer (axes, ticks, walls, obstacles, legend) is drawn once per
        layout and restored from a pixel buffer; only the moving marks and the texts are drawn
        on each frame (~5x faster than a full redraw; most of a full draw is text)."""
        env, ax, fig = self.env, self.ax, self.fig
        for artist in self._dynamic:  # the previous frame's marks (kept until now: inspectable)
            artist.remove()
        self._dynamic = []
        key = (id(getattr(env.world, "layout", None)), env.render_agent)
        if self._background is None or key != self._key:
            ax.clear()
            draw_static(ax, env)
            add_legend(ax, env)
            self.canvas.draw()
            self._background = self.canvas.copy_from_bbox(fig.bbox)
            self._key = key
        self.canvas.restore_region(self._background)
        self.sensors.update(env, env.render_agent)
        before = set(ax.get_children())
        caption = draw_dynamic(ax, env, sensors=self.sensors)
        marks = sorted(
            (a for a in ax.get_children() if a not in before), key=lambda a: a.get_zorder()
        )
        bbox = ax.get_position()
        texts = [
            fig.text(
                0.5 * (bbox.x0 + bbox.x1),
                bbox.y1 + 0.015,
                f"t = {env.time_s:.1f} s    focus: {env.render_agent}    "
                f"{env.config.n_robots} UGVs",
                ha="center",
                va="bottom",
                fontsize=9,
            ),
            fig.text(
                0.01,
                0.015,
                "; ".join(["world frame, metres"] + caption),
                fontsize=7,
                color="0.25",
            ),
        ]
        for artist in marks:
            ax.draw_artist(artist)
        for text in texts:
            fig.draw_artist(text)
        frame = np.asarray(self.canvas.buffer_rgba())[..., :3].copy()
        self._dynamic = marks + texts
        self.title_text, self.caption_text = texts
        return frame

    def close(self) -> None:
        if self._window is not None:
            self._pygame.display.quit()
            self._window = None


def comparison_figure(
    env: SwarmEnv, estimates: dict[str, Any], focus: str | None = None, path: Any = None
):
    """Side by side: the truth, then one panel per estimate (``{title: mixture}``, each in the
    focus robot's frame), all at the env's current step. Returns the matplotlib figure; writes
    it to ``path`` if given."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    focus = env.render_agent if focus is None else focus
    n = 1 + len(estimates)
    fig = Figure(figsize=(4.2 * n + 2.2, 4.8), dpi=110)
    FigureCanvasAgg(fig)
    axes = [fig.add_axes((0.05 + k * 0.8 / n, 0.16, 0.72 / n, 0.72)) for k in range(n)]
    sensors = SensorMemory()
    sensors.update(env, focus)
    draw_scene(
        axes[0],
        env,
        focus,
        sensors=sensors,
        show_estimate=False,
        title="truth + focus robot's sensors",
        legend=False,
    )
    captions = []
    for k, (name, mixture) in enumerate(estimates.items(), start=1):
        captions += [
            f"{name}: " + c
            for c in draw_scene(
                axes[k],
                env,
                focus,
                mixture=mixture,
                show_sensors=False,
                title=f"estimate: {name}",
                legend=False,
            )
            if "component" in c
        ]
    handles, labels = legend_handles(env, focus)
    fig.legend(
        handles, labels, loc="upper right", fontsize=7, frameon=False, bbox_to_anchor=(0.995, 0.9)
    )
    fig.suptitle(
        f"t = {env.time_s:.1f} s, focus {focus}: truth vs the focus robot's own PHD estimate",
        fontsize=10,
    )
    fig.text(
        0.01,
        0.02,
        "World frame, metres. Ellipses: 2σ of each PHD component, opacity = weight, drawn at "
        "the focus robot's true pose. " + "; ".join(captions),
        fontsize=7,
        color="0.25",
        wrap=True,
    )
    if path is not None:
        fig.savefig(path)
    return fig
