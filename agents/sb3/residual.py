"""Residual policies: a scripted controller plus a learned correction.

Residual reinforcement learning (Johannink et al. 2019, "Residual Reinforcement Learning for
Robot Control"; Silver et al. 2018, "Residual Policy Learning"): the action sent to the robot is

    a = clip(b(o) + c_theta(o) * high, -high, high)      high = [v_max, omega_max]

where ``b`` is a hand-written controller (here ``scripted:NAME`` from
:data:`agents.policies.SCRIPTED`, which reads the robot's own PHD table and lidar scan) and
``c_theta`` is the PPO policy (unit scale, clipped to [-1, 1]). The correction's mean starts
at exactly zero (:func:`zero_correction`), so before any update the deterministic residual
policy *is* the scripted controller, and PPO only has to learn where the controller is wrong.
The policy network sees the env's observation, not ``b``'s internal state (the scripted
controller's random-walk generator, its full lidar scan); ``SwarmConfig.lidar_sectors`` gives
it the scan summarised in sectors, and ``--residual-observes-base`` gives it ``b``'s command
itself (:func:`base_in_unit_scale`, appended to the observation).

That is ``--residual-mode add``, the default. With ``--residual-mode gain`` the correction
scales the command instead:

    a = clip(b(o) * GAIN_RANGE ** c_theta(o), -high, high)      (per axis, GAIN_RANGE = 4)

a state-dependent gain on each of the controller's two commands, from 1/4 to 4 times: a
correction of 0.5 on ``v`` doubles the controller's pull. An additive correction that would do
the same must grow with the command itself, which PPO's exploration at a fixed std does not
find (``python -m experiments.residual_gains``); the gain mode makes "pull harder" one constant
direction
of the action (PPO did not find that either). A base command of zero stays zero
(the gain cannot start a stopped robot).

Training: ``swarm-phd train --residual scripted:formation`` (batched VecEnv only: the base
needs each copy's ``infos``). Evaluation: the model zip's ``swarm_phd.json`` says
``"residual": "scripted:formation"`` (and ``"residual_mode"`` if not ``add``), and
:class:`agents.sb3.policy.SB3Policy` composes the base and the correction the same way.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def check_residual(spec: Any, field: str = "--residual") -> str:
    """``spec`` if it names a scripted controller (``"scripted:NAME"``), else ``ValueError``
    naming ``field``."""
    from agents.policies import SCRIPTED

    if not isinstance(spec, str) or not spec.startswith("scripted:"):
        raise ValueError(f"{field} must be 'scripted:NAME', got {spec!r}")
    name = spec.split(":", 1)[1]
    if name not in SCRIPTED:
        raise ValueError(
            f"{field}: unknown scripted policy {name!r}; choose from {sorted(SCRIPTED)}"
        )
    return spec


#: How the correction acts on the scripted command (``--residual-mode``; module doc).
RESIDUAL_MODES = ("add", "gain")
#: ``--residual-mode gain``: a correction of +-1 multiplies a command by this or divides it.
GAIN_RANGE = 4.0


def check_residual_mode(mode: Any) -> str:
    """``mode`` if it is one of :data:`RESIDUAL_MODES`, else ``ValueError``."""
    if mode not in RESIDUAL_MODES:
        raise ValueError(f"--residual-mode must be one of {RESIDUAL_MODES}, got {mode!r}")
    return mode


def compose(
    base: np.ndarray, correction: np.ndarray, high: np.ndarray, mode: str = "add"
) -> np.ndarray:
    """The residual command: ``clip(base + clip(correction, -1, 1) * high, -high, high)``
    (``mode="add"``) or ``clip(base * GAIN_RANGE ** clip(correction, -1, 1), -high, high)``
    (``mode="gain"``).

    ``base``: the scripted controller's command in env units ``[v_mps, omega_radps]``;
    ``correction``: the policy's output in unit scale; ``high``: ``[v_max, omega_max]``; all
    broadcast, (..., 2); float32 out. Both are formed in env units so that a zero correction
    returns the scripted command bit for bit (a unit-scale round trip would not; ``4 ** 0`` is
    exactly 1)."""
    high = np.asarray(high, dtype=np.float64)
    c = np.clip(np.asarray(correction, dtype=np.float64), -1.0, 1.0)
    base = np.asarray(base, dtype=np.float64)
    if check_residual_mode(mode) == "gain":
        command = base * np.power(GAIN_RANGE, c)
    else:
        command = base + c * high
    return np.clip(command, -high, high).astype(np.float32)


def base_in_unit_scale(base: Any, high: np.ndarray) -> np.ndarray:
    """Scripted commands ``[v_mps, omega_radps]`` (..., 2) as the policy's input: ``base /
    high`` clipped to [-1, 1], float32 (``--residual-observes-base``)."""
    unit = np.asarray(base, dtype=np.float64) / np.asarray(high, dtype=np.float64)
    return np.clip(unit, -1.0, 1.0).astype(np.float32)


class ResidualBase:
    """The base controller of a residual policy, for one env (its agents' names).

    Calls the scripted controller on the env's ``(observations, infos)`` and returns its
    commands (env units, float64). Scripted controllers keep per-agent state by agent name:
    build one ``ResidualBase`` per env copy.
    """

    def __init__(self, spec: str, env: Any) -> None:
        from agents.policies import load_policy

        self.spec = check_residual(spec)
        self.policy = load_policy(spec, env)
        self.high = np.asarray(env.action_space(env.possible_agents[0]).high, dtype=np.float64)

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset(seed)

    def __call__(
        self, observations: dict[str, np.ndarray], infos: dict[str, dict[str, Any]] | None
    ) -> dict[str, np.ndarray]:
        actions = self.policy(observations, infos or {})
        return {a: np.asarray(actions[a], dtype=np.float64) for a in observations}


def zero_correction(policy: Any, log_std: float) -> None:
    """Start the correction at mean zero: the SB3 ``ActorCriticPolicy``'s ``action_net``
    weights and bias are set to 0 (its input features still train it: the gradient of the
    output w.r.t. the weights is the features), and its log-std to ``log_std``."""
    import torch

    with torch.no_grad():
        policy.action_net.weight.zero_()
        policy.action_net.bias.zero_()
        policy.log_std.fill_(float(log_std))
