"""Trained SB3 models as swarm policies, and the metadata that rebuilds their env.

Every model zip written by ``swarm-phd train`` (the final ``model.zip`` and each checkpoint)
carries one extra member, ``swarm_phd.json`` (SB3's loader ignores it)::

    {"env_kwargs": {...},            # preset, task, task_params, observation, n_robots, ...
     "obs_norm": {"mean": [...], "var": [...], "clip": 10.0, "epsilon": 1e-8} | null,
     "action_scale": "unit",         # the policy acts in [-1, 1]; scaled by [v_max, omega_max]
     "residual": "scripted:NAME",    # optional, a residual policy (agents.sb3.residual):
                                     # command = clip(scripted + c x high, -high, high)
     "residual_mode": "gain",        # optional ("add" if absent): the correction scales the
                                     # scripted command by 4**correction (agents.sb3.residual)
     "residual_observes_base": true, # optional: the scripted command / high is appended to
                                     # the observation (agents.sb3.residual)
     "critic_dims": P,               # optional, a centralised critic's block
                                     # (agents.sb3.central_critic): P zeros are appended to
                                     # the observation, which the actor does not read
     "recurrent": true}              # optional: an sb3-contrib RecurrentPPO model (LSTM
                                     # memory per agent, cleared by reset())

``env_kwargs.json`` next to ``model.zip`` holds the same ``env_kwargs`` for humans and scripts.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from agents.sb3.adapter import scale_actions
from swarm_core.atomic_files import atomic_write

META_NAME = "swarm_phd.json"


def write_metadata(model_path: str | Path, meta: dict[str, Any]) -> None:
    """Add (or replace) ``swarm_phd.json`` inside the model zip."""
    path = Path(model_path)
    with zipfile.ZipFile(path, "r") as src:
        members = {n: src.read(n) for n in src.namelist() if n != META_NAME}
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as dst:
        for name, data in members.items():
            dst.writestr(name, data)
        dst.writestr(META_NAME, json.dumps(meta, indent=2))


def save_model(model: Any, path: str | Path, meta: dict[str, Any]) -> Path:
    """``model.save`` plus its metadata, atomically: a crash or a signal while saving leaves
    the previous model file whole (:func:`swarm_core.atomic_files.atomic_write`)."""

    def write(tmp: Path) -> None:
        model.save(tmp)
        write_metadata(tmp, meta)

    return atomic_write(path, write)


def read_metadata(model_path: str | Path) -> dict[str, Any]:
    """The ``swarm_phd.json`` of a model zip; ``ValueError`` if it is not a swarm-phd model."""
    path = Path(model_path)
    if not path.is_file():
        raise ValueError(f"model file {str(path)!r} does not exist")
    try:
        with zipfile.ZipFile(path) as z:
            if META_NAME in z.namelist():
                return json.loads(z.read(META_NAME))
    except zipfile.BadZipFile as exc:
        raise ValueError(f"{str(path)!r} is not a model zip: {exc}") from exc
    side = path.parent / "env_kwargs.json"
    if side.is_file():
        return {
            "env_kwargs": json.loads(side.read_text()),
            "obs_norm": None,
            "action_scale": "unit",
        }
    raise ValueError(
        f"{str(path)!r} has no {META_NAME} and no env_kwargs.json beside it: "
        "train it with `swarm-phd train`"
    )


def env_kwargs_for_model(model_path: str | Path) -> dict[str, Any]:
    """Env overrides the model was trained with (observation mode, task, task params, ...),
    without ``preset`` (the caller chooses; pass ``preset=kw.pop('preset')`` to reuse it)."""
    kwargs = dict(read_metadata(model_path)["env_kwargs"])
    kwargs.pop("preset", None)
    return kwargs


class SB3Policy:
    """A trained PPO model driving every agent with the same network (``(obs, infos) ->
    actions``). Deterministic (the Gaussian's mean) unless ``deterministic=False``.

    A recurrent model keeps each agent's LSTM state between calls (by agent name, so agents
    that leave the episode do not shift the others'); :meth:`reset` clears it, and must be
    called at every episode start, as for the scripted policies."""

    def __init__(
        self,
        model: Any,
        meta: dict[str, Any],
        action_high: np.ndarray,
        deterministic: bool = True,
        base: Any = None,
    ) -> None:
        self.model = model
        #: A residual model's scripted base (:class:`agents.sb3.residual.ResidualBase`) or None.
        self.base = base
        self.meta = meta
        self.action_high = np.asarray(action_high, dtype=np.float64)
        self.deterministic = deterministic
        norm = meta.get("obs_norm")
        if norm:
            self._mean = np.asarray(norm["mean"], dtype=np.float64)
            self._std = np.sqrt(np.asarray(norm["var"], dtype=np.float64) + norm["epsilon"])
            self._clip = float(norm["clip"])
        else:
            self._mean = None
        #: Entries of a centralised critic's block, padded with zeros (the actor ignores them).
        self.critic_dims = int(meta.get("critic_dims", 0))
        self.recurrent = bool(meta.get("recurrent", False))
        #: A residual's correction per agent at the last call, unit scale, clipped to
        #: [-1, 1] as ``compose`` clips it (read by ``experiments/residual_gains.py``).
        self.last_correction: dict[str, np.ndarray] = {}
        from agents.sb3.residual import check_residual_mode

        #: How the correction acts on the base's command (``agents.sb3.residual.compose``).
        self.residual_mode = check_residual_mode(meta.get("residual_mode", "add"))
        #: Recurrent models: each agent's LSTM state ``(h, c)``, each (layers, hidden); an
        #: agent without one starts its episode at the next call.
        self._memory: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            self.model.set_random_seed(seed)
        if self.base is not None:
            self.base.reset(seed)
        self._memory.clear()

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self._mean is None:
            return obs.astype(np.float32)
        return np.clip((obs - self._mean) / self._std, -self._clip, self._clip).astype(np.float32)

    def __call__(
        self, observations: dict[str, np.ndarray], infos: dict[str, dict[str, Any]] | None = None
    ) -> dict[str, np.ndarray]:
        if not observations:
            return {}
        agents = list(observations)
        batch = np.stack([observations[a] for a in agents])
        base = None
        if self.base is not None:
            from agents.sb3.residual import base_in_unit_scale, compose

            base = self.base(observations, infos)
            if self.meta.get("residual_observes_base"):
                unit = base_in_unit_scale([base[a] for a in agents], self.action_high)
                batch = np.concatenate([batch, unit], axis=1)
        batch = self.normalize(batch)
        if self.critic_dims:
            batch = np.pad(batch, ((0, 0), (0, self.critic_dims)))
        if self.recurrent:
            actions = self._predict_recurrent(agents, batch)
        else:
            actions, _ = self.model.predict(batch, deterministic=self.deterministic)
        if base is not None:
            self.last_correction = {
                a: np.clip(np.asarray(actions[k], np.float64), -1.0, 1.0)
                for k, a in enumerate(agents)
            }
            return {
                a: compose(base[a], actions[k], self.action_high, self.residual_mode)
                for k, a in enumerate(agents)
            }
        return {a: scale_actions(actions[k], self.action_high) for k, a in enumerate(agents)}

    def _predict_recurrent(self, agents: list[str], batch: np.ndarray) -> np.ndarray:
        """One step of the LSTM for ``agents`` (their rows of ``batch``), each from its own
        state; an agent seen for the first time since :meth:`reset` starts an episode."""
        starts = np.array([a not in self._memory for a in agents])
        state = None
        if not starts.all():
            shape = self.model.policy.lstm_hidden_state_shape  # (layers, 1, hidden)
            zeros = np.zeros((shape[0], shape[2]), np.float32)
            pairs = [self._memory.get(a, (zeros, zeros)) for a in agents]
            state = tuple(np.stack([p[i] for p in pairs], axis=1) for i in (0, 1))
        actions, (h, c) = self.model.predict(
            batch, state=state, episode_start=starts, deterministic=self.deterministic
        )
        for k, a in enumerate(agents):
            self._memory[a] = (h[:, k].copy(), c[:, k].copy())
        return actions


#: Why a zip from elsewhere is refused, and the flag that loads it anyway.
UNTRUSTED_ZIP = (
    "loading it with SB3's loader unpickles Python objects stored in it (its policy class, "
    "spaces, schedules), which can run any code. Pass --trust-policy if you trained this file "
    "yourself or trust its source (a zip inside its swarm-phd train --out directory, next to "
    "train_config.json and env_kwargs.json, loads weights only and needs no flag)"
)


def load_sb3_policy(
    path: str | Path, env: Any, deterministic: bool = True, trust: bool = False
) -> SB3Policy:
    """Load ``path`` for ``env``; the env's observation space must match the model's.

    A zip of a ``swarm-phd train`` run (its ``train_config.json`` and ``env_kwargs.json``
    beside it, or one directory up for a checkpoint) loads weights only
    (:mod:`agents.sb3.safe_load`): nothing in it is unpickled. Any other zip needs ``trust``
    (``--trust-policy``): SB3's own loader unpickles its ``data``, which can run code."""
    import torch

    from agents.sb3.safe_load import load_weights_only, run_directory

    torch.set_num_threads(1)
    own_run = run_directory(path) is not None
    if not own_run and not trust:
        raise ValueError(
            f"policy {str(path)!r} is an SB3 model zip from outside a swarm-phd train run: "
            + UNTRUSTED_ZIP
        )
    meta = read_metadata(path)
    if own_run:
        model: Any = load_weights_only(path, meta)
    elif meta.get("recurrent"):
        from sb3_contrib import RecurrentPPO

        model = RecurrentPPO.load(str(path), device="cpu")
    else:
        from stable_baselines3 import PPO

        model = PPO.load(str(path), device="cpu")
    agent = env.possible_agents[0]
    want = model.observation_space.shape
    have = env.observation_space(agent).shape
    # Entries the policy adds to the env's observation: the scripted command, the critic block.
    added = 2 * bool(meta.get("residual_observes_base")) + int(meta.get("critic_dims", 0))
    want = (want[0] - added,)
    if want != have:
        raise ValueError(
            f"model {str(path)!r} expects observations of shape {want}, the env gives {have}: "
            f"build the env with the model's kwargs {meta['env_kwargs']}"
        )
    base = None
    if meta.get("residual"):
        from agents.sb3.residual import ResidualBase

        base = ResidualBase(meta["residual"], env)
    return SB3Policy(
        model, meta, env.action_space(agent).high, deterministic=deterministic, base=base
    )
