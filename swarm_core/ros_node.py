"""Running one of the project's ROS 2 nodes as a process: the ``main()`` the packages under
``ros/`` (``swarm_phd_camera``, ``swarm_phd_onboard``) share.

``rclpy`` is imported when a node runs, not with this module, so the library imports on a
machine without ROS.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any


def run_node(
    make_node: Callable[[], Any],
    program: str,
    refused: type[BaseException] | tuple[type[BaseException], ...],
    argv: list[str] | None = None,
) -> int:
    """Initialise ``rclpy`` with ``argv`` (default ``sys.argv``), build the node with
    ``make_node()`` and spin it until Ctrl-C or a ROS shutdown; returns the exit status.

    An exception of a ``refused`` type raised while building (a bad parameter or calibration:
    the node names it) is printed as ``"{program}: {message}"`` on stderr and gives status 2,
    after shutting ``rclpy`` down; any other exception propagates. Once built, the node is
    destroyed and ``rclpy`` shut down (if still up) however spinning ends; status 0."""
    import rclpy

    rclpy.init(args=argv if argv is not None else sys.argv)
    try:
        node = make_node()
    except refused as exc:
        print(f"{program}: {exc}", file=sys.stderr)
        rclpy.shutdown()
        return 2
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
