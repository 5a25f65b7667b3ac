"""Perception shared by the simulator, the hardware bridge and the replay.

The code that turns raw sensor data into the filter's measurements runs identically on simulated
and real robots: :mod:`.lidar_features` (robot-sized clusters of a scan, null-return bearings)
and :mod:`.blind_sectors` (which beams the camera pillars hide).
"""

from swarm_core.perception.blind_sectors import blind_mask
from swarm_core.perception.lidar_features import (
    LidarDetections,
    LidarFeatureConfig,
    extract_clusters,
    extract_detections,
    null_beams,
    null_bearings,
)

__all__ = [
    "LidarDetections",
    "LidarFeatureConfig",
    "blind_mask",
    "extract_clusters",
    "extract_detections",
    "null_beams",
    "null_bearings",
]
