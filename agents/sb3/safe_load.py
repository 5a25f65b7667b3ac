"""Weights-only loading of the project's own SB3 runs: no pickled object of the zip is read.

SB3's loader (``PPO.load``) unpickles the zip's ``data`` member (the policy class, the spaces,
the learning-rate schedule), and unpickling can run any code a file's author put there. A run
written by ``swarm-phd train`` does not need it: its policy is rebuilt here from the run's JSON
files (``train_config.json``: the policy's class and keywords; ``env_kwargs.json``: the env,
built once for its observation and action spaces), and only the network's tensors are read
from the zip's ``policy.pth``, by ``torch.load(..., weights_only=True)``, which refuses any
object but tensors and plain containers. The zip's ``data`` and ``pytorch_variables.pth`` are
never opened; its ``swarm_phd.json`` is read as JSON.

A zip found without those JSON files (a file from elsewhere) cannot be rebuilt this way; the
commands refuse it unless ``--trust-policy`` is given (:func:`agents.policies.load_policy`).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

#: The run files a weights-only load needs, beside the zip or one directory up (checkpoints/).
RUN_FILES = ("train_config.json", "env_kwargs.json")


def run_directory(model_path: str | Path) -> Path | None:
    """The ``swarm-phd train --out`` directory ``model_path`` belongs to (``model.zip`` and
    ``warm_start.zip`` sit in it, checkpoints one level down), or ``None`` if neither its
    directory nor the one above holds :data:`RUN_FILES`."""
    path = Path(model_path)
    for run in (path.parent, path.parent.parent):
        if all((run / name).is_file() for name in RUN_FILES):
            return run
    return None


class WeightsOnlyModel:
    """The part of an SB3 algorithm :class:`agents.sb3.policy.SB3Policy` uses (``policy``,
    ``observation_space``, ``predict``, ``set_random_seed``), around a policy rebuilt from the
    run's JSON files with the zip's weights."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy
        self.observation_space = policy.observation_space
        self.action_space = policy.action_space

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        return self.policy.predict(observation, state, episode_start, deterministic)

    def set_random_seed(self, seed: int | None = None) -> None:
        """As SB3's ``BaseAlgorithm.set_random_seed`` on the CPU: the global generators and
        the action space."""
        if seed is None:
            return
        from stable_baselines3.common.utils import set_random_seed

        set_random_seed(seed, using_cuda=False)
        self.action_space.seed(seed)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"run file {str(path)!r} is not readable JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"run file {str(path)!r} must hold a JSON object, got {data!r}")
    return data


def _spaces(env_kwargs: dict[str, Any], added: int) -> tuple[Any, Any, int]:
    """The observation space the run's policy read (the env's, plus ``added`` entries the
    policy appends: the scripted command, the critic's block), its unit action space and the
    env's ``top_k``, from the env built with ``env_kwargs``."""
    from gymnasium import spaces

    from agents.sb3.adapter import UNIT_ACTION_SPACE
    from swarm_env import parallel_env

    env = parallel_env(**env_kwargs)
    try:
        box = env.observation_space(env.possible_agents[0])
        top_k = int(env.config.top_k)
    finally:
        env.close()
    low = np.concatenate([box.low.astype(np.float32), np.full(added, -np.inf, np.float32)])
    high = np.concatenate([box.high.astype(np.float32), np.full(added, np.inf, np.float32)])
    return spaces.Box(low, high, dtype=np.float32), UNIT_ACTION_SPACE, top_k


def build_policy(run: Path, meta: dict[str, Any]) -> Any:
    """The untrained policy of the run in ``run`` (its class and keywords as
    :func:`agents.sb3.train._build_model` made them), on the spaces it was trained with."""
    config = _read_json(run / "train_config.json")
    env_kwargs = _read_json(run / "env_kwargs.json")
    kwargs = dict(config.get("policy_kwargs") or {})
    critic_dims = int(config.get("critic_dims") or 0)
    added = 2 * bool(config.get("residual_observes_base")) + critic_dims
    observation_space, action_space, top_k = _spaces(env_kwargs, added)
    if config.get("extractor", meta.get("extractor", "mlp")) == "sets":
        from agents.sb3.features import NeighbourSetExtractor

        kwargs["features_extractor_class"] = NeighbourSetExtractor
    if "net_arch" in kwargs and isinstance(kwargs["net_arch"], dict):
        kwargs["net_arch"] = {k: list(v) for k, v in kwargs["net_arch"].items()}
    policy_class: Any
    if critic_dims:
        from agents.sb3.central_critic import CentralCriticPolicy

        policy_class = CentralCriticPolicy
        kwargs = {k: v for k, v in kwargs.items() if not k.startswith(("features_", "share_"))}
        kwargs.update(critic_dims=critic_dims, top_k=top_k)
    else:
        from stable_baselines3.common.policies import ActorCriticPolicy

        policy_class = ActorCriticPolicy
    if config.get("recurrent"):
        from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy

        policy_class = RecurrentActorCriticPolicy
        kwargs.update(lstm_hidden_size=int(config["lstm_hidden"]), shared_lstm=False)
    use_sde = bool((config.get("ppo") or {}).get("use_sde", False))
    return policy_class(observation_space, action_space, lambda _: 0.0, use_sde=use_sde, **kwargs)


def read_weights(model_path: str | Path) -> dict[str, Any]:
    """The policy's tensors in the zip's ``policy.pth``, loaded weights-only (no object but
    tensors and plain containers is accepted)."""
    import torch

    path = Path(model_path)
    try:
        with zipfile.ZipFile(path) as z:
            if "policy.pth" not in z.namelist():
                raise ValueError(f"model zip {str(path)!r} has no policy.pth member")
            raw = z.read("policy.pth")
    except zipfile.BadZipFile as exc:
        raise ValueError(f"{str(path)!r} is not a model zip: {exc}") from exc
    try:
        state = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises UnpicklingError / RuntimeError on a bad member
        raise ValueError(
            f"model zip {str(path)!r}: its policy.pth is not a plain tensor state: {exc}"
        ) from exc
    if not isinstance(state, dict):
        raise ValueError(f"model zip {str(path)!r}: policy.pth holds {type(state).__name__}")
    return state


def load_weights_only(model_path: str | Path, meta: dict[str, Any]) -> WeightsOnlyModel:
    """The model of ``model_path`` (a zip written by ``swarm-phd train``; ``meta``: its
    ``swarm_phd.json``) rebuilt from its run's JSON files and loaded weights-only; ValueError
    naming the file if it belongs to no run or its weights do not fit the rebuilt policy."""
    import torch

    torch.set_num_threads(1)
    path = Path(model_path)
    run = run_directory(path)
    if run is None:
        raise ValueError(
            f"model zip {str(path)!r} has no {' and '.join(RUN_FILES)} beside it (nor one "
            "directory up): it is not part of a swarm-phd train run"
        )
    policy = build_policy(run, meta)
    try:
        policy.load_state_dict(read_weights(path))
    except RuntimeError as exc:  # missing / unexpected keys, shape mismatch
        raise ValueError(
            f"model zip {str(path)!r}: its weights do not fit the policy described by "
            f"{str(run / 'train_config.json')!r}: {exc}"
        ) from exc
    policy.set_training_mode(False)
    return WeightsOnlyModel(policy)
