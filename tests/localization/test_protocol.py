"""The robot-index check every localizer (and the bridge's received estimates) runs."""

from __future__ import annotations

import numpy as np
import pytest

from hardware_bridge.estimate import ReceivedEstimates
from localization.protocol import robot_index


def test_robot_index_accepts_python_and_numpy_ints_in_range():
    assert robot_index(0, 3) == 0
    assert robot_index(np.int64(2), 3) == 2
    assert type(robot_index(np.int64(2), 3)) is int


@pytest.mark.parametrize(
    ("robot", "message"),
    [
        (True, "robot must be an int index, got True"),
        (1.0, "robot must be an int index, got 1.0"),
        ("0", "robot must be an int index, got '0'"),
        (3, r"robot must be in \[0, 3\), got 3"),
        (-1, r"robot must be in \[0, 3\), got -1"),
    ],
)
def test_robot_index_refuses_non_indices_naming_the_value(robot, message):
    with pytest.raises(ValueError, match=message):
        robot_index(robot, 3)


def test_received_estimates_check_robots_as_the_localizers_do():
    received = ReceivedEstimates(["ugv_0", "ugv_1"], "phd-lc", "phd-weight", dict)
    received.reset([1])
    with pytest.raises(ValueError, match=r"robot must be in \[0, 2\), got 2"):
        received.reset([2])
    with pytest.raises(ValueError, match="robot must be an int index, got False"):
        received.mixture(False)
