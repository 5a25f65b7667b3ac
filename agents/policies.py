"""Policies by name, for the CLI and evaluation: ``random``, ``scripted:NAME`` or a model file.

A policy is any callable ``(observations, infos) -> actions`` over the live agents, with an
optional ``reset(seed)``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agents import scripted
from agents.pretrained import resolve as resolve_pretrained

SCRIPTED: dict[str, Callable[..., scripted.ScriptedPolicy]] = {
    "wander": scripted.WanderPolicy.for_env,
    "formation": scripted.FormationPolicy.for_env,
    # The same, turning its lidar's blind sectors off its teammates once it has arrived.
    "formation-sensing": functools.partial(scripted.FormationPolicy.for_env, sensing_turn=True),
    # ... holding its position once arrived: it moves again only for a pull of 5 cm/s, not
    # for its estimate's noise (docs/results.md round 9: 0.05 chosen on validation seeds
    # 200-209 from {0.05, 0.08}; a 6 cm radial error at k_p = 0.8).
    "formation-sensing-hold": functools.partial(
        scripted.FormationPolicy.for_env, sensing_turn=True, restart_mps=0.05
    ),
    # ... each with its centroid scaled to the known swarm size N (after the spread discount
    # the weights of the teammates in sight average 0.8, which shrank the centroid towards
    # the robot: docs/results.md, round 10).
    "formation-known-n": functools.partial(
        scripted.FormationPolicy.for_env, swarm_size_centroid=True
    ),
    "formation-sensing-known-n": functools.partial(
        scripted.FormationPolicy.for_env, sensing_turn=True, swarm_size_centroid=True
    ),
    # ... with twice the position gain (k_p 1.6 against 0.8): the others settle in
    # 1/k_p = 1.25 s and stop on errors below deadband / k_p = 2.5 cm. Chosen on validation
    # seeds 200-229 from k_p {0.8, 1.2, 1.6, 2.4, 3.2} x heading gain {2, 4} (docs/results.md,
    # round 12): 0.072 -> 0.060 m; the grid is flat from 1.6 to 3.2.
    "formation-known-n-fast": functools.partial(
        scripted.FormationPolicy.for_env, swarm_size_centroid=True, k_p=1.6
    ),
    "formation-sensing-hold-known-n": functools.partial(
        scripted.FormationPolicy.for_env,
        sensing_turn=True,
        restart_mps=0.05,
        swarm_size_centroid=True,
    ),
    "exploration": scripted.DispersionPolicy.for_env,
    "encirclement": scripted.EncirclementPolicy.for_env,
    "anti-symmetry": scripted.AntiSymmetryPolicy.for_env,
}


class RandomPolicy:
    """Uniform random actions within the action bounds, for all live agents in one draw.

    Seeded on its own (``reset(seed)``), so its actions do not depend on the env's generator.
    """

    def __init__(self, env: Any, seed: int | None = 0) -> None:
        self.high = env.action_space(env.possible_agents[0]).high.astype(np.float64)
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(seed)

    def __call__(self, observations, infos):
        agents = list(observations)
        draws = self._rng.uniform(-self.high, self.high, size=(len(agents), 2))
        return dict(zip(agents, draws.astype(np.float32), strict=True))


def random_policy(env: Any, seed: int | None = 0) -> RandomPolicy:
    """A :class:`RandomPolicy` for ``env``."""
    return RandomPolicy(env, seed)


#: Set to ``1`` by ``--trust-policy`` (evaluate, record, bridge), for this process and the
#: workers it starts: :func:`load_policy` then loads SB3 zips from outside a training run
#: with SB3's unpickling loader.
TRUST_POLICY_ENV = "SWARM_PHD_TRUST_POLICY"


def trust_policy_files() -> None:
    """``--trust-policy``: let :func:`load_policy` unpickle SB3 zips that are not part of a
    ``swarm-phd train`` run, in this process and the worker processes it starts."""
    import os

    os.environ[TRUST_POLICY_ENV] = "1"


def add_trust_policy_argument(parser: Any) -> None:
    """``--trust-policy`` of ``evaluate`` and ``record`` (an ``argparse`` parser): the commands
    then call :func:`trust_policy_files`."""
    parser.add_argument(
        "--trust-policy",
        action="store_true",
        help="load an SB3 .zip from outside a swarm-phd train run with SB3's loader, which "
        "unpickles objects stored in the file and so can run code in it: only for a file you "
        "trained or verified yourself (a zip in its run directory loads weights only)",
    )


def trusts_policy_files() -> bool:
    """Whether ``--trust-policy`` was given (:func:`trust_policy_files`)."""
    import os

    return os.environ.get(TRUST_POLICY_ENV) == "1"


def load_policy(spec: str, env: Any, trust: bool | None = None) -> Any:
    """Build the policy named by ``spec`` for ``env``.

    ``"random"``: uniform actions from the agents' seeded action spaces. ``"pretrained:NAME"``:
    a policy shipped with the package (:mod:`agents.pretrained`). ``"scripted:NAME"``: a
    controller from :data:`SCRIPTED`. ``"privileged:NAME"``: a training teacher that also reads
    the simulator's truth (:mod:`agents.sb3.privileged`; a reference, not deployable). Anything
    ending in ``.zip``: a trained SB3 model; in ``.pt``: a recurrent residual student
    (:mod:`agents.sb3.recurrent_student`). A directory: the ``--out`` of ``swarm-phd train
    --engine rllib`` or one of its checkpoints (:func:`rllib_checkpoint`; the mean action of
    its shared module, :mod:`agents.rllib.policy`).

    A ``.zip`` of a ``swarm-phd train`` run loads weights only (:mod:`agents.sb3.safe_load`);
    another ``.zip`` is refused (ValueError naming ``--trust-policy``) unless ``trust`` (None:
    whether ``--trust-policy`` was given, :func:`trusts_policy_files`), since SB3's loader
    unpickles it.
    """
    spec = resolve_pretrained(spec)
    if spec == "random":
        return random_policy(env)
    if spec.startswith("scripted:"):
        name = spec.split(":", 1)[1]
        if name not in SCRIPTED:
            raise ValueError(f"unknown scripted policy {name!r}; choose from {sorted(SCRIPTED)}")
        return SCRIPTED[name](env)
    if spec.startswith("privileged:"):  # a training teacher that reads the simulator's truth
        from agents.sb3.privileged import load_teacher

        return load_teacher(spec, env)
    if spec.endswith(".pt"):  # a recurrent residual student (agents.sb3.recurrent_student)
        from agents.sb3.recurrent_student import load_student

        return load_student(spec, env)
    if spec.endswith(".zip"):
        if not Path(spec).is_file():
            raise ValueError(f"policy file {spec!r} does not exist")
        from agents.sb3.policy import load_sb3_policy

        if trust is None:
            trust = trusts_policy_files()
        return load_sb3_policy(spec, env, trust=trust)
    checkpoint = rllib_checkpoint(spec)
    if checkpoint is not None:  # a run of swarm-phd train --engine rllib
        from agents.rllib.policy import load_policy as load_rllib_policy

        return load_rllib_policy(checkpoint, env)
    raise ValueError(
        "policy must be 'random', 'scripted:NAME', 'pretrained:NAME', 'privileged:NAME', a .zip "
        "model, a .pt recurrent student or an RLlib run directory (or its checkpoint/), "
        f"got {spec!r}"
    )


def rllib_checkpoint(spec: str) -> Path | None:
    """The RLlib checkpoint ``spec`` names, or ``None`` if it names none: the ``--out`` of
    ``swarm-phd train --engine rllib`` (its final ``checkpoint/``), that ``checkpoint/``, or one
    of its ``checkpoints/step_<agent steps>/``. The run's ``env_kwargs.json`` must sit next to
    them (:func:`rllib_env_kwargs`)."""
    spec = resolve_pretrained(spec)
    path = Path(spec)
    if spec.endswith((".zip", ".pt")) or not path.is_dir():
        return None
    from agents.rllib.policy import MODULE_SUBDIR

    for candidate in (path / "checkpoint", path):
        if (candidate / MODULE_SUBDIR).is_dir():
            return candidate
    return None


def rllib_env_kwargs(checkpoint: Path) -> dict[str, Any]:
    """The env kwargs of the RLlib run that wrote ``checkpoint``: its ``env_kwargs.json``, in
    the run directory (``checkpoint/``'s parent, or ``checkpoints/step_N``'s grandparent)."""
    import json

    for run in (checkpoint.parent, checkpoint.parent.parent):
        if (run / "env_kwargs.json").is_file() and (run / "train_config.json").is_file():
            return dict(json.loads((run / "env_kwargs.json").read_text()))
    raise ValueError(
        f"RLlib checkpoint {str(checkpoint)!r} has no env_kwargs.json in its run directory: "
        "pass the --out directory of swarm-phd train --engine rllib"
    )


def is_trained_model(spec: str) -> bool:
    """Whether ``spec`` names a trained policy file or run (SB3 ``.zip``, student ``.pt``, RLlib
    run directory): a policy that carries its own env settings (:func:`model_env_kwargs`)."""
    spec = resolve_pretrained(spec)
    return spec.endswith((".zip", ".pt")) or rllib_checkpoint(spec) is not None


def model_env_kwargs(spec: str) -> dict[str, Any] | None:
    """The env kwargs a trained policy was trained in (an SB3 ``.zip``, a recurrent student
    ``.pt`` or an RLlib run directory), or ``None`` for a policy by name."""
    spec = resolve_pretrained(spec)
    if spec.endswith(".zip"):
        from agents.sb3.policy import read_metadata

        return dict(read_metadata(spec)["env_kwargs"])
    if spec.endswith(".pt"):
        from agents.sb3.recurrent_student import read_student_metadata

        return dict(read_student_metadata(spec)["env_kwargs"])
    checkpoint = rllib_checkpoint(spec)
    if checkpoint is not None:
        return rllib_env_kwargs(checkpoint)
    return None


def trained_policy_env(
    spec: str, preset: str | None = None, task: str | None = None, **overrides: Any
) -> dict[str, Any] | None:
    """The env kwargs a trained policy file (``.zip`` or ``.pt``) runs in: its own preset,
    task, task parameters and observation settings, then ``overrides``. A ``preset`` or
    ``task`` given replaces the model's; another task drops the model's task parameters (they
    belong to its own task), while ``overrides["task_params"]`` on the model's own task are
    merged over its parameters (a changed reward weight keeps the formation it learnt).
    ``None`` for a policy by name."""
    model = model_env_kwargs(spec)
    if model is None:
        return None
    model_preset = model.pop("preset", None)
    return {**model_on_task(model, task, overrides), "preset": preset or model_preset}


def model_on_task(
    model: dict[str, Any], task: str | None, overrides: dict[str, Any]
) -> dict[str, Any]:
    """A trained policy's env kwargs ``model`` (``{}`` for a policy by name) on ``task`` (None:
    the model's own; a model without one was trained on ``"wander"``), then ``overrides``.
    Another task drops the model's task parameters (they belong to its own task, which its
    observation may include); ``overrides["task_params"]`` are merged over those kept.
    ``"task"`` is None only for a policy by name given none."""
    out = dict(model)
    own = out.pop("task", "wander" if model else None)
    params = out.pop("task_params", None) or {}
    if task is not None and task != own:
        params = {}
    overrides = dict(overrides)
    given = overrides.pop("task_params", None) or {}
    return {**out, **overrides, "task": task or own, "task_params": {**params, **given}}


def policy_env(preset: str | None, task: str | None, policy: str, **overrides: Any) -> Any:
    """The env ``policy`` (a ``load_policy`` spec) runs in, as evaluate and record build it:
    a trained policy's own env (:func:`trained_policy_env`, ``preset``, ``task`` and
    ``overrides`` over its settings), else ``preset`` (default ``seed-sim``) and ``task``
    (default ``wander``) with the observation mode the policy reads. Policies that ignore the
    observation get raw measurements and no filters in the env (an evaluation runs its own),
    unless the task's reward scores the estimates. Returns a ``SwarmEnv``."""
    from swarm_env import parallel_env

    model = trained_policy_env(policy, preset, task, **overrides)
    if model is not None:  # a trained model (.zip) or recurrent student (.pt): its own env
        preset, task, overrides = model.pop("preset"), model.pop("task"), model
    else:
        observation = policy_observation(policy)
        if observation is None:
            from swarm_env.tasks import task_needs_estimates

            overrides.setdefault("observation", "measurements")
            overrides.setdefault(
                "localize", task_needs_estimates(task or "wander", overrides.get("task_params"))
            )
        else:  # e.g. scripted:formation acts on the robot's own PHD estimate
            overrides.setdefault("observation", observation)
    return parallel_env(preset or "seed-sim", task=task or "wander", **overrides)


def policy_observation(spec: str) -> str | None:
    """The observation mode a scripted policy reads (``"phd"`` for the controllers acting on
    the robot's PHD estimate), or ``None`` if it ignores the observation (``random``,
    ``scripted:wander``: lidar only). Models carry their own mode (see ``agents.sb3.policy``);
    a recurrent student (``.pt``) and an RLlib run read their env's."""
    spec = resolve_pretrained(spec)
    if spec.endswith(".pt"):
        from agents.sb3.recurrent_student import read_student_metadata

        return read_student_metadata(spec)["env_kwargs"].get("observation", "phd")
    checkpoint = rllib_checkpoint(spec)
    if checkpoint is not None:  # an RLlib run reads its env's observation, as a student
        return rllib_env_kwargs(checkpoint).get("observation", "phd")
    if spec.startswith(("scripted:", "privileged:")):
        from agents.sb3.privileged import TEACHERS

        name = spec.split(":", 1)[1]
        if spec.startswith("privileged:") and name.endswith("@truth"):
            # The controller on the true table, inside an env on the estimate.
            return policy_observation("scripted:" + name[: -len("@truth")])
        registry = SCRIPTED if spec.startswith("scripted:") else TEACHERS
        factory = registry.get(name)
        factory = getattr(factory, "func", factory)  # a functools.partial of a for_env
        modes = getattr(getattr(factory, "__self__", None), "observation_modes", None)
        return modes[0] if modes else None
    return None
