"""``swarm_core.ros_node.run_node``, the ROS packages' shared ``main()``, against a stand-in
``rclpy`` that logs the calls (no ROS on this machine)."""

from __future__ import annotations

import sys
import types

import pytest

from swarm_core.ros_node import run_node


class _Node:
    def __init__(self, log: list[str], spin_raises: type[BaseException] | None = None) -> None:
        self.log = log
        self.spin_raises = spin_raises

    def destroy_node(self) -> None:
        self.log.append("destroy_node")


@pytest.fixture
def rclpy(monkeypatch):
    """A stand-in ``rclpy`` module; ``rclpy.log`` lists the calls in order."""
    fake = types.ModuleType("rclpy")
    fake.log = []
    fake.up = False

    def init(args=None):
        fake.log.append(("init", args))
        fake.up = True

    def spin(node):
        fake.log.append("spin")
        if node.spin_raises is not None:
            raise node.spin_raises("stopped")

    def shutdown():
        fake.log.append("shutdown")
        fake.up = False

    fake.init, fake.spin, fake.shutdown, fake.ok = init, spin, shutdown, lambda: fake.up
    monkeypatch.setitem(sys.modules, "rclpy", fake)
    return fake


@pytest.mark.parametrize("stop", [None, KeyboardInterrupt])
def test_a_node_spins_then_is_destroyed_and_rclpy_shut_down(rclpy, stop):
    status = run_node(lambda: _Node(rclpy.log, stop), "prog", ValueError, ["prog", "--ros-args"])
    assert status == 0
    assert rclpy.log == [("init", ["prog", "--ros-args"]), "spin", "destroy_node", "shutdown"]


def test_argv_defaults_to_the_process_arguments(rclpy, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["camera_node", "--ros-args", "-p", "x:=1"])
    run_node(lambda: _Node(rclpy.log), "prog", ValueError)
    assert rclpy.log[0] == ("init", ["camera_node", "--ros-args", "-p", "x:=1"])


def test_a_refused_node_is_named_on_stderr_with_status_2(rclpy, capsys):
    def bad():
        raise ValueError("robot 'ugv_x' is not a robot id")

    assert run_node(bad, "swarm_phd_onboard", (KeyError, ValueError), ["p"]) == 2
    assert capsys.readouterr().err == "swarm_phd_onboard: robot 'ugv_x' is not a robot id\n"
    assert rclpy.log == [("init", ["p"]), "shutdown"]


def test_other_errors_propagate_and_a_spin_error_still_cleans_up(rclpy):
    def broken():
        raise RuntimeError("not a refusal")

    with pytest.raises(RuntimeError, match="not a refusal"):
        run_node(broken, "prog", ValueError, ["p"])
    rclpy.log.clear()
    with pytest.raises(RuntimeError, match="stopped"):
        run_node(lambda: _Node(rclpy.log, RuntimeError), "prog", ValueError, ["p"])
    assert rclpy.log == [("init", ["p"]), "spin", "destroy_node", "shutdown"]
