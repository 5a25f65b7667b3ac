"""The env's wiring: World contract members, halt on any exception, state(), phases, encoders."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env import parallel_env
from swarm_env.world.sim import SimWorld


class _CountingWorld(SimWorld):
    """The simulator, counting halt() calls and able to fail on demand."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.halts = 0
        self.fail_step = False

    def halt(self) -> None:
        self.halts += 1

    def step(self, commands, extra_commands=None):
        if self.fail_step:
            raise RuntimeError("transport lost")
        return super().step(commands, extra_commands)


def _env_with(world_cls=_CountingWorld, **kw):
    from swarm_env.config import make_config

    config = make_config("lab-3m-4", max_steps=50, **kw)
    return parallel_env(config=config, world=world_cls(config))


def test_any_exception_in_step_halts_the_robots_first():
    env = _env_with()
    env.reset(seed=0)
    env.world.fail_step = True
    with pytest.raises(RuntimeError, match="transport lost"):
        env.step({a: np.zeros(2) for a in env.agents})
    assert env.world.halts == 1
    env.world.fail_step = False

    def broken_rewards(truth, actions):
        raise ZeroDivisionError("task bug")

    env.task.rewards = broken_rewards
    with pytest.raises(ZeroDivisionError):
        env.step({a: np.zeros(2) for a in env.agents})
    assert env.world.halts == 2


def test_a_signal_wrapped_by_a_kernel_callback_leaves_the_env_as_the_signal():
    """SIGTERM's exception raised while numba loads a cached kernel arrives as a SystemError
    caused by it; step() and reset() halt the robots and raise the signal's own exception,
    so a library caller's ``except SystemExit`` / ``KeyboardInterrupt`` sees it, with a note
    naming the wrapper and no cycle through it (a traceback would print the chain backwards).
    A SystemError that no signal caused stays a SystemError."""
    from hardware_bridge.signals import Terminated

    env = _env_with()
    env.reset(seed=0)
    actions = {a: np.zeros(2) for a in env.agents}

    def wrapped(inner):
        def localizer_step(feed):
            try:
                raise inner
            except BaseException as err:
                raise SystemError("returned a result with an exception set") from err

        return localizer_step

    calls = [
        (lambda: env.step(actions), Terminated(15)),
        (lambda: env.step(actions), KeyboardInterrupt()),
        (lambda: env.reset(seed=1), Terminated(15)),
    ]
    for n, (call, signal_exc) in enumerate(calls, start=1):
        env.localizer.step = wrapped(signal_exc)
        with pytest.raises(type(signal_exc)) as caught:
            call()
        assert caught.value is signal_exc
        assert caught.value.__cause__ is None and caught.value.__suppress_context__
        chain, node = [], caught.value.__context__  # the wrapper, no longer linking back
        while node is not None and len(chain) < 5:
            chain.append(node)
            node = node.__cause__ or node.__context__
        assert signal_exc not in chain and len(chain) == 1
        assert any("SystemError" in note for note in caught.value.__notes__)
        assert env.world.halts == n

    env.localizer.step = wrapped(ZeroDivisionError("a kernel bug"))
    with pytest.raises(SystemError) as caught:
        env.step(actions)
    assert isinstance(caught.value.__cause__, ZeroDivisionError)
    assert env.world.halts == 4


def test_bad_actions_raise_before_the_world_moves_and_halt_the_robots():
    env = _env_with()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step({a: np.array([np.nan, 0.0]) for a in env.agents})
    assert env.world.halts == 1 and env.time_s == 0.0


def test_calls_after_close_raise():
    env = parallel_env("lab-3m-4", max_steps=5)
    env.reset(seed=0)
    env.close()
    with pytest.raises(RuntimeError, match="after close"):
        env.step({a: np.zeros(2) for a in env.possible_agents})
    with pytest.raises(RuntimeError, match="after close"):
        env.reset(seed=0)


def test_state_is_the_true_global_state():
    env = parallel_env("lab-3m-4", max_steps=5)
    with pytest.raises(RuntimeError):
        env.state()
    env.reset(seed=1)
    env.step({a: np.array([0.2, 0.5]) for a in env.agents})
    state = env.state()
    assert env.state_space.contains(state)
    rows = state.reshape(4, 6)
    poses = env.last_world_step.truth.poses
    np.testing.assert_allclose(rows[:, :2], poses[:, :2], atol=1e-6)
    np.testing.assert_allclose(rows[:, 2], np.cos(poses[:, 2]), atol=1e-6)
    np.testing.assert_allclose(rows[:, 3], np.sin(poses[:, 2]), atol=1e-6)
    assert np.all(rows[:, 4] > 0)  # odometry speed of the commanded forward motion


def test_render_without_a_mode_warns():
    env = parallel_env("lab-3m-4", max_steps=5)
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_phased_step_equals_step():
    """step() is step_world + localizer.step + finish_step (what the batched VecEnv uses)."""
    a, b = parallel_env("lab-3m-4", max_steps=20), parallel_env("lab-3m-4", max_steps=20)
    oa, _ = a.reset(seed=5)
    b.localizer.step(b.reset_world(seed=5))
    ob, _ = b.finish_reset()
    for x in oa:
        np.testing.assert_array_equal(oa[x], ob[x])
    rng = np.random.default_rng(5)
    for _ in range(10):
        act = {x: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for x in a.agents}
        oa, ra, *_ = a.step(act)
        b.localizer.step(b.step_world(act))
        ob, rb, *_ = b.finish_step()
        for x in oa:
            np.testing.assert_array_equal(oa[x], ob[x])
            assert ra[x] == rb[x]


@pytest.mark.parametrize("observation", ["phd", "truth", "measurements"])
def test_layout_names_every_column(observation):
    env = parallel_env("lab-3m-4", max_steps=5, observation=observation)
    obs, _ = env.reset(seed=0)
    layout = env.encoder.layout
    assert layout.size == env.observation_space("ugv_0").shape[0]
    for name, rows, cols in layout.tables:
        table = layout.table(obs["ugv_0"], name)
        assert table.shape == (rows, len(cols))
        assert layout.column("valid", name) == len(cols) - 1
    with pytest.raises(ValueError, match="column"):
        layout.column("nope")
