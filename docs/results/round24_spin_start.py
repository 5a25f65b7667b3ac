"""Round 24's diagnostic (docs/results.md): does turning in place at the start cut the early
steps' large localization errors?

``spin<K>-<r>``: every robot turns in place at ``r`` x its maximum turn rate for the first
``K`` control steps, then drives as ``formation-known-n`` (which runs, and keeps its own
state, from the first step). Registered beside the scripted controllers for this process
only, then scored by ``localization_table`` with ``--phases``:

    python docs/results/round24_spin_start.py --policies runs/r21/Z_f0/student.pt \
        scripted:formation-known-n scripted:spin10-1.0 scripted:spin20-1.0 \
        scripted:spin20-0.5 scripted:spin40-0.5 --seeds 200-219 --localizers phd-lc \
        --phases 0,2,5,10,20,50,100 --out docs/results --name formation_round24_spin_start200

(The student is listed first for its env: lab-3m-4, PHD observation, 300 steps.)

``known-n-truth``, ``spin10-1.0-truth`` and ``spin20-1.0-truth`` are the same controllers on
the true neighbours, so that the formation does not depend on the estimate; the robots'
filters run on their sensors all the same, and are what is scored:

    python docs/results/round24_spin_start.py --policies runs/r21/Z_f0/student.pt \
        scripted:known-n-truth scripted:spin10-1.0-truth scripted:spin20-1.0-truth \
        --seeds 200-219 --localizers phd-lc --phases 0,2,5,10,20,50,100 --out docs/results \
        --name formation_round24_spin_start_truth200
"""

from __future__ import annotations

import functools
import sys

import numpy as np

from agents import policies
from agents.sb3 import localization_table


class SpinFirst:
    """Turn in place for the first ``steps`` calls, then act as ``inner``."""

    observation_modes = ("phd", "truth")  # the inner controller's

    @classmethod
    def for_env(cls, env, steps: int, rate: float) -> SpinFirst:
        return cls(policies.SCRIPTED["formation-known-n"](env), steps, rate)

    def __init__(self, inner, steps: int, rate: float) -> None:
        self.inner, self.steps, self.rate, self.t = inner, steps, rate, 0
        self.wandering = frozenset()

    def reset(self, seed: int | None = None) -> None:
        self.inner.reset(seed)
        self.t = 0

    def __call__(self, observations, infos):
        actions = self.inner(observations, infos)  # its state follows the episode
        self.wandering = self.inner.wandering
        if self.t < self.steps:
            omega = self.rate * self.inner.max_turn_rate_radps
            actions = {a: np.array([0.0, omega], dtype=np.float32) for a in actions}
        self.t += 1
        return actions


class SpinFirstOnTruth(SpinFirst):
    observation_modes = ("truth",)  # the env gives the controller the true table


class KnownNOnTruth:
    observation_modes = ("truth",)

    @classmethod
    def for_env(cls, env):
        return policies.SCRIPTED["formation-known-n"](env)


policies.SCRIPTED["known-n-truth"] = KnownNOnTruth.for_env
for steps in (10, 20):
    policies.SCRIPTED[f"spin{steps}-1.0-truth"] = functools.partial(
        SpinFirstOnTruth.for_env, steps=steps, rate=1.0
    )
for steps in (10, 20, 40):
    for rate in (0.5, 1.0):
        policies.SCRIPTED[f"spin{steps}-{rate}"] = functools.partial(
            SpinFirst.for_env, steps=steps, rate=rate
        )

if __name__ == "__main__":
    sys.exit(localization_table.main(sys.argv[1:]))
