"""The rendered frame shows what it claims: robots at their true positions (in metres), lidar
returns, the PHD estimate as ellipses; a legend, axis labels and a title that fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swarm_env import parallel_env
from swarm_env.render import SensorMemory, comparison_figure, draw_scene, ellipse_params


@pytest.fixture(scope="module")
def env():
    env = parallel_env("lab-3m-4", render_mode="rgb_array", max_steps=200)
    env.reset(seed=1)
    action = {a: np.array([0.15, 0.4], np.float32) for a in env.agents}
    for _ in range(60):
        env.step(action)
        has_scan = bool(env.last_world_step.measurements["ugv_0"].lidar)
        if has_scan and env.time_s > 3.0 and env.localizers[0].mixture.weights.sum() > 1.0:
            break
    assert env.last_world_step.measurements["ugv_0"].lidar, "no scan in the chosen step"
    yield env
    env.close()


def _draw(env, **kwargs):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 6), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.1, 0.1, 0.8, 0.8))
    draw_scene(ax, env, legend=False, **kwargs)
    canvas.draw()
    img = np.asarray(canvas.buffer_rgba())[..., :3].astype(float) / 255.0
    height = img.shape[0]

    def pixel(xy):
        x, y = ax.transData.transform(np.asarray(xy, dtype=float))
        return img[int(round(height - y)), int(round(x))]

    return img, pixel


def _orange(img):
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 0.8) & (g > 0.35) & (g < 0.8) & (b < 0.45) & (r - b > 0.4)


def _purple(img):
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (b > g + 0.08) & (r > g + 0.04)


def test_robots_are_drawn_at_their_true_positions_in_metres(env):
    img, pixel = _draw(env, show_estimate=False, show_sensors=False)
    poses = env.last_world_step.truth.poses
    length = env.config.robot.length_m
    for i, (x, y, yaw) in enumerate(poses):
        inside = (x - 0.25 * length * np.cos(yaw), y - 0.25 * length * np.sin(yaw))
        r, g, b = pixel(inside)
        if i == 0:  # the focus robot: blue
            assert b > r + 0.2 and b > g + 0.05, (i, (r, g, b))
        else:  # teammates: green
            assert g > r + 0.2 and g > b + 0.2, (i, (r, g, b))
    # A point in free space away from every robot is background (white or a faint grid line).
    free = np.array([1.3, -1.3])
    if np.min(np.hypot(*(poses[:, :2] - free).T)) > 0.4:
        assert pixel(free).min() > 0.75


def test_lidar_returns_are_drawn_only_with_the_sensors(env):
    with_sensors, _ = _draw(env, show_estimate=False)
    without, _ = _draw(env, show_estimate=False, show_sensors=False)
    # Returns add orange pixels; without them only antialiased edges of other marks remain.
    assert (_orange(with_sensors) & ~_orange(without)).sum() > 40
    assert _orange(without).sum() < 20


def test_estimate_ellipses_are_drawn_where_the_components_are(env):
    with_est, pixel = _draw(env, show_sensors=False)
    without, pixel_without = _draw(env, show_sensors=False, show_estimate=False)
    assert (_purple(with_est) & ~_purple(without)).sum() > 100
    assert _purple(without).sum() < 20
    mixture = env.localizers[0].mixture
    pose = env.last_world_step.truth.poses[0]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    heavy = np.argmax(mixture.weights)
    world = pose[:2] + np.array([[c, -s], [s, c]]) @ mixture.means[heavy]
    # At the heaviest component's mean (often on top of the teammate it tracks), the ellipse
    # tints the pixel toward purple: less green, relatively more blue.
    (r, g, b), (r0, g0, b0) = pixel(world), pixel_without(world)
    assert g < g0 - 0.02 and (b - g) > (b0 - g0) + 0.02, ((r, g, b), (r0, g0, b0))


def test_ellipse_params_match_a_hand_case():
    # Variances 0.04 along 30 deg and 0.01 across: 2-sigma axes 2*2.448*[0.2, 0.1].
    a = np.radians(30.0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    cov = rot @ np.diag([0.04, 0.01]) @ rot.T
    w, h, angle = ellipse_params(cov)
    np.testing.assert_allclose([w, h], [2 * 2.4477 * 0.2, 2 * 2.4477 * 0.1], rtol=1e-4)
    assert angle % 180.0 == pytest.approx(30.0)


def test_full_frame_has_legend_labels_and_uncut_title(env):
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    renderer = env._renderer
    ax = renderer.ax
    assert ax.get_legend() is not None
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    for needed in ("ugv_0 (focus)", "teammate (truth)", "lidar detection", "body x (forward)"):
        assert needed in labels, labels
    assert any("PHD component" in t for t in labels)
    assert any("lidar return" in t for t in labels)
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    assert renderer.title_text.get_text().startswith("t = ")
    assert "lidar scan" in renderer.caption_text.get_text()
    # The title, the caption and the legend lie inside the canvas (nothing cut off).
    canvas_box = renderer.fig.bbox
    for artist in (renderer.title_text, renderer.caption_text, ax.get_legend()):
        box = artist.get_window_extent(renderer.canvas.get_renderer())
        assert box.x0 >= 0 and box.y0 >= 0
        assert box.x1 <= canvas_box.x1 and box.y1 <= canvas_box.y1


def test_blitted_frame_matches_a_full_redraw(env):
    """The renderer redraws only the moving marks over a cached background; a full draw of the
    same figure (every artist, in z-order) must look the same."""
    fast = env.render()
    renderer = env._renderer
    renderer.canvas.draw()  # the last frame's marks are still attached: a full redraw
    full = np.asarray(renderer.canvas.buffer_rgba())[..., :3]
    differ = np.any(np.abs(fast.astype(int) - full.astype(int)) > 24, axis=-1)
    # Only z-order ties differ (faint rays drawn over vs under the walls): a few pixels.
    assert differ.mean() < 0.01, differ.mean()


def test_sensor_memory_keeps_the_last_scan(env):
    memory = SensorMemory()
    memory.update(env, "ugv_0")
    assert memory.lidar is not None
    scan = memory.lidar
    env_step = env.last_world_step
    # A step without records keeps the previous scan.
    env._last_step = dataclasses.replace(env_step, measurements={})
    memory.update(env, "ugv_0")
    assert memory.lidar is scan
    env._last_step = env_step


def test_comparison_figure_has_three_panels(env, tmp_path):
    mix = env.localizers[0].mixture
    fig = comparison_figure(
        env, {"lidar only": mix, "lidar + camera": mix}, path=tmp_path / "c.png"
    )
    assert len(fig.axes) == 3
    assert [a.get_title() for a in fig.axes][1:] == [
        "estimate: lidar only",
        "estimate: lidar + camera",
    ]
    assert (tmp_path / "c.png").stat().st_size > 10_000
