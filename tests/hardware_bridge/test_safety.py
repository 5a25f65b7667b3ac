"""Safety: the watchdog (stall, exception, close, SIGINT), pickling/vectorisation refusal, one
controller per robot, remote hosts only with the flag."""

from __future__ import annotations

import copy
import os
import pickle
import signal
import threading
import time

import pytest

from hardware_bridge import real_env
from tests.hardware_bridge.conftest import crash_in_step, drive, wait_until, zero_times


@pytest.mark.timeout(30)
def test_watchdog_sends_zero_twist_within_0_6_s_of_the_client_stalling(lab):
    server, env = lab()
    t_first = time.monotonic()
    drive(env, 5)
    t_stall = time.monotonic()  # the controller stops calling step() here
    robots = set(env.possible_agents)
    assert wait_until(lambda: set(zero_times(server, t_stall)) == robots, 1.5)
    zeros = zero_times(server, t_stall)
    # No stop while the controller was stepping: every command in between was motion.
    during = [(t, r, v) for t, r, v, _ in server.twists() if t_first < t <= t_stall]
    assert len(during) >= 4 * 4 and all(v > 0 for _, _, v in during)
    latency = {r: t - t_stall for r, t in zeros.items()}
    assert all(dt <= 0.6 for dt in latency.values()), latency
    timeout = env.world.bridge.watchdog_timeout_s
    assert all(dt >= timeout - 0.05 for dt in latency.values()), f"fired early {latency}"
    # It keeps the robots stopped (repeats) until the next step.
    assert wait_until(
        lambda: len([1 for t, *_ in server.twists() if t > max(zeros.values()) + 0.1]) >= 4,
        1.0,
    )
    # Stepping again resumes motion.
    drive(env, 2)


@pytest.mark.timeout(30)
def test_exception_in_step_and_close_stop_the_robots_at_once(lab, monkeypatch):
    server, env = lab()
    drive(env, 3)
    t0 = crash_in_step(env, monkeypatch, env.world.limiter, "limit")  # the planner crashes
    assert wait_until(lambda: len(zero_times(server, t0)) == 4, 0.3)
    assert max(zero_times(server, t0).values()) - t0 < 0.2
    monkeypatch.undo()
    drive(env, 2)
    t1 = time.monotonic()
    env.close()
    assert wait_until(lambda: len(zero_times(server, t1)) == 4, 0.3)
    assert max(zero_times(server, t1).values()) - t1 < 0.2


@pytest.mark.timeout(30)
@pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(),
    reason="signals are delivered to the main thread",
)
def test_sigint_stops_the_robots_before_keyboard_interrupt(lab):
    # Python's own handler, or SIG_IGN when the tests run as a background job: close restores it.
    before = signal.getsignal(signal.SIGINT)
    server, env = lab()
    drive(env, 3)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(2.0)  # interrupted by the signal
    # Well before the 0.5 s step timeout could have fired.
    assert wait_until(lambda: len(zero_times(server, t0)) == 4, 0.3)
    assert max(zero_times(server, t0).values()) - t0 < 0.25
    env.close()
    assert signal.getsignal(signal.SIGINT) is before


@pytest.mark.timeout(30)
def test_bridge_env_refuses_pickling_copying_vectorising_and_a_second_controller(loopback):
    server = loopback()
    env = real_env(port=server.port, preset="seed-lab")
    try:
        assert env.metadata["is_parallelizable"] is False
        with pytest.raises(TypeError, match="real robots"):
            pickle.dumps(env)
        with pytest.raises(TypeError, match="real robots"):
            copy.deepcopy(env)
        with pytest.raises(TypeError, match="real robots"):
            copy.copy(env.world)
        ss = pytest.importorskip("supersuit")
        vec = ss.pettingzoo_env_to_vec_env_v1(env)
        with pytest.raises(TypeError, match="real robots"):
            ss.concat_vec_envs_v1(vec, 2, num_cpus=0, base_class="gymnasium")
        with pytest.raises(RuntimeError, match="already driven"):
            real_env(robots=["ugv_1"], port=server.port, preset="seed-lab")
    finally:
        env.close()
    # Released on close: another controller may take the robots now.
    env2 = real_env(robots=["ugv_1"], port=server.port, preset="seed-lab")
    env2.close()


def test_remote_host_refused_without_the_flag():
    with pytest.raises(ValueError, match="allow_remote"):
        real_env(robots=["ugv_0"], host="192.0.2.10")
    with pytest.raises(ValueError, match="robot id"):
        real_env(robots=["ugv 0"])
    with pytest.raises(ValueError, match="unique"):
        real_env(robots=["ugv_0", "ugv_0"])
