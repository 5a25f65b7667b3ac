"""One robot's filter on board: its own odometry, scans and bearings in, its estimate out.

On the swarm the bridge runs every robot's filter on one machine. A robot can instead run its
own: :class:`OnBoardFilter` takes the robot's validated messages (the bridge's parsers,
:mod:`hardware_bridge.messages`), turns them into records with the bridge's own
:class:`~hardware_bridge.assembly.RecordAssembler` (the same lidar feature extractor, blind
sectors and odometry increments) and steps a one-robot localizer of any family
(:func:`localization.registry.make_localizer`). Each step gives the robot's mixture in its body
frame as a ``swarm_phd_msgs/EstimateStamped`` (:mod:`hardware_bridge.estimate`).

The robot-centric filters (``phd-*``, ``pmb-*``) use only the robot's own measurements, so the
filter on board computes what the bridge's filter bank computes for that robot from the same
records (``tests/hardware_bridge/test_onboard.py``). Families that need the radio or ground
truth (``id-phd``, ``ukf``, ``pf``, ``fastslam-mc``, ``p-multireg``...) cannot run alone and are
refused.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hardware_bridge.assembly import RecordAssembler
from hardware_bridge.estimate import estimate_stamped_msg, weight_kind_of
from hardware_bridge.messages import Bearings, Odom, Scan, check_robot_id, ns_to_s
from localization.feed import SwarmFeed
from localization.registry import LOCALIZERS, make_localizer
from swarm_core.records import RobotMeasurements
from swarm_env.config import SwarmConfig

#: Families whose robot's filter runs from the robot's own measurements alone.
ONBOARD_FAMILIES = ("phd", "phd-lc", "phd-lo", "pmb", "pmb-lc", "pmb-lo")


class OnBoardFilter:
    """One robot's localizer, fed with its own messages.

    Parameters
    ----------
    robot : str
        The robot's id (``ugv_3``): its estimate's ``frame_id`` is ``<robot>/base_link``.
    config : SwarmConfig
        The sensors' and filter's configuration (``config.phd``, ``config.lidar``,
        ``config.lidar_features``), as the bridge uses it.
    localizer : str
        One of :data:`ONBOARD_FAMILIES`.
    """

    def __init__(self, robot: str, config: SwarmConfig, localizer: str = "phd-lc") -> None:
        self.robot = check_robot_id(robot)
        if localizer not in ONBOARD_FAMILIES:
            known = sorted(LOCALIZERS)
            raise ValueError(
                f"localizer must be one of {list(ONBOARD_FAMILIES)} on board (the others need "
                f"the radio or ground truth; all: {known}), got {localizer!r}"
            )
        self.config = config
        self.localizer_name = localizer
        self.assembler = RecordAssembler([self.robot], config)
        self.localizer = make_localizer(localizer, 1, config.phd)
        self.localizer.reset()
        self._pending: dict[str, list] = {"odometry": [], "lidar": [], "camera": []}
        self.last_stamp_ns = 0

    @property
    def weight_kind(self) -> str:
        return weight_kind_of(getattr(self.localizer, "weight_meaning", "phd-weight"))

    def add(self, message: Odom | Scan | Bearings) -> None:
        """Queue one validated message for the next :meth:`step`."""
        if isinstance(message, Odom):
            self._pending["odometry"].append(message)
        elif isinstance(message, Scan):
            self._pending["lidar"].append(message)
        elif isinstance(message, Bearings):
            self._pending["camera"].append(message)
        else:
            raise TypeError(
                f"message must be an Odom, Scan or Bearings, got {type(message).__name__}"
            )

    def step(self, now_ns: int) -> dict[str, Any]:
        """Advance the filter over the queued messages (stamps up to ``now_ns``) and return
        the estimate as an ``EstimateStamped`` JSON object stamped ``now_ns``."""
        pending, self._pending = self._pending, {"odometry": [], "lidar": [], "camera": []}
        records = self.assembler.measurements({self.robot: pending})[self.robot]
        return self.step_records(records, now_ns)

    def step_records(self, records: RobotMeasurements, now_ns: int) -> dict[str, Any]:
        """Advance the filter over ``records`` (already assembled) and return the estimate."""
        if type(now_ns) is not int or now_ns < 0:
            raise ValueError(f"now_ns must be an int >= 0 (ns), got {now_ns!r}")
        feed = SwarmFeed(time_s=ns_to_s(now_ns), measurements=[records], stale=[()])
        self.localizer.step(feed)
        self.last_stamp_ns = now_ns
        return self.estimate_msg()

    def estimate_msg(self) -> dict[str, Any]:
        """The current mixture as an ``EstimateStamped`` JSON object, stamped at the last step
        (1 ns for a clock that starts at 0, as the simulator's: a ROS stamp is never 0)."""
        mixture = self.localizer.mixture(0)
        return estimate_stamped_msg(
            max(self.last_stamp_ns, 1),
            mixture.weights,
            mixture.means,
            mixture.covs,
            localizer=self.localizer_name,
            weight_kind=self.weight_kind,
            frame_id=f"{self.robot}/base_link",
        )


def mixture_arrays(msg: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``weights (N,)``, ``means (N, 2)``, ``covariances (N, 2, 2)`` of an estimate message."""
    w = np.asarray(msg["weights"], dtype=np.float64)
    return (
        w,
        np.asarray(msg["means"], dtype=np.float64).reshape(w.size, 2),
        np.asarray(msg["covariances"], dtype=np.float64).reshape(w.size, 2, 2),
    )
