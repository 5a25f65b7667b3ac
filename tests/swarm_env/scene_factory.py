"""Test helpers around :mod:`swarm_env.sensors.scene_builder` (re-exported here).

``EXACT_LIDAR`` is the noise-free lidar of the analytic tests; ``sight_line_crosses_segments``
a per-segment reference for the compiled camera kernel.
"""

from __future__ import annotations

import numpy as np

from swarm_env.sensors.lidar import LidarConfig
from swarm_env.sensors.scene import Scene
from swarm_env.sensors.scene_builder import (  # noqa: F401  (re-exported for the tests)
    HOUSING_RADIUS_M,
    POST_RADIUS_M,
    RED_DECOY_RADIUS_M,
    STRIP_RADIUS_M,
    SceneBuilder,
    make_arena_scene,
)

# Exact lidar geometry: no noise, thin beams, no blind sectors, no interference.
EXACT_LIDAR = LidarConfig(
    range_noise_std_m=0.0,
    range_noise_quadratic_per_m=0.0,
    beam_footprint_deg=0.0,
    intensity_noise_std=0.0,
    blind_sector_centers_deg=(),
    blind_sector_widths_deg=(),
    interference_tolerance_deg=0.0,
)


def sight_line_crosses_segments(scene: Scene, origin: np.ndarray, d: np.ndarray) -> bool:
    """Whether the sight line ``origin -> origin + d`` properly crosses a wall or box segment
    of ``scene`` (a per-segment reference for the compiled camera kernel)."""
    for s in range(scene.segment_a.shape[0]):
        a, e = scene.segment_a[s], scene.segment_b[s] - scene.segment_a[s]
        den = d[0] * e[1] - d[1] * e[0]
        if den == 0:
            continue
        u = ((a - origin)[0] * e[1] - (a - origin)[1] * e[0]) / den
        v = ((a - origin)[0] * d[1] - (a - origin)[1] * d[0]) / den
        if 0 < u < 1 and 0 < v < 1:
            return True
    return False
