"""Trained SB3 models load weights only: nothing in a model zip is unpickled unless the user
passes ``--trust-policy`` for a zip from outside a training run."""

from __future__ import annotations

import argparse
import base64
import json
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.policies import TRUST_POLICY_ENV, load_policy  # noqa: E402
from agents.sb3.policy import env_kwargs_for_model, load_sb3_policy  # noqa: E402
from agents.sb3.safe_load import WeightsOnlyModel, run_directory  # noqa: E402
from swarm_env import parallel_env  # noqa: E402
from swarm_phd.cli import main  # noqa: E402

TINY = ["--preset", "lab-3m-4", "--task", "formation", "--max-steps", "20"]


@pytest.fixture(scope="module", params=["sets", "mlp"])
def run_dir(request, tmp_path_factory):
    """One PPO iteration of 16 env steps, with the set extractor and with the MLP (whose
    observation normalisation rides in the zip's JSON)."""
    out = tmp_path_factory.mktemp("runs") / request.param
    argv = ["train", *TINY, "--timesteps", "64", "--n-steps", "16", "--n-copies", "1"]
    argv += ["--n-epochs", "1", "--extractor", request.param, "--eval-seeds", "0"]
    assert main([*argv, "--no-progress-bar", "--out", str(out)]) == 0
    return out


@pytest.fixture(autouse=True)
def untrusted(monkeypatch):
    """No --trust-policy from an earlier command in this process (restored afterwards)."""
    monkeypatch.setenv(TRUST_POLICY_ENV, "0")


def _env(model: Path):
    kwargs = env_kwargs_for_model(model)
    return parallel_env("lab-3m-4", **kwargs)


def _foreign_copy(run_dir: Path, where: Path) -> Path:
    """The run's model.zip alone, as a file downloaded from elsewhere."""
    where.mkdir()
    return Path(shutil.copy(run_dir / "model.zip", where / "model.zip"))


class _Payload:
    """Unpickling this touches a file: what a hostile model zip would do with a shell."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_a_run_loads_weights_only_and_acts_as_sb3s_loader(run_dir, tmp_path):
    from stable_baselines3 import PPO

    model = run_dir / "model.zip"
    assert run_directory(model) == run_dir
    env = _env(model)
    mine = load_policy(str(model), env)
    assert isinstance(mine.model, WeightsOnlyModel)
    reference = load_sb3_policy(_foreign_copy(run_dir, tmp_path / "copy"), env, trust=True)
    assert isinstance(reference.model, PPO)  # SB3's own (unpickling) loader
    # The same tensors, name by name.
    theirs = reference.model.policy.state_dict()
    ours = mine.model.policy.state_dict()
    assert list(ours) == list(theirs)
    for name, tensor in theirs.items():
        assert ours[name].dtype == tensor.dtype and bool((ours[name] == tensor).all()), name
    # Bit-identical actions on an episode's observations, through the swarm policy ...
    obs, infos = env.reset(seed=3)
    mine.reset(3)
    reference.reset(3)
    for _ in range(10):
        a, b = mine(obs, infos), reference(obs, infos)
        assert list(a) == list(b)
        for agent in a:
            np.testing.assert_array_equal(a[agent], b[agent])
        obs, _, _, _, infos = env.step(a)
    # ... and on raw observations, deterministic and sampled (same seed, same draws).
    rng = np.random.default_rng(0)
    batch = rng.normal(size=(32, *reference.model.observation_space.shape)).astype(np.float32)
    for deterministic in (True, False):
        mine.model.set_random_seed(5)
        ours_a, _ = mine.model.predict(batch, deterministic=deterministic)
        reference.model.set_random_seed(5)
        theirs_a, _ = reference.model.predict(batch, deterministic=deterministic)
        np.testing.assert_array_equal(ours_a, theirs_a)
    assert np.abs(ours_a).max() > 0
    env.close()


def test_a_payload_in_the_zips_data_is_never_unpickled(run_dir, tmp_path):
    marker = tmp_path / "pwned"
    blob = base64.b64encode(pickle.dumps(_Payload(marker))).decode()
    # The payload is real: unpickling it touches the marker.
    pickle.loads(base64.b64decode(blob))
    assert marker.exists()
    marker.unlink()
    # A run directory whose model.zip carries it in the member SB3's loader unpickles.
    run = tmp_path / "run"
    run.mkdir()
    for name in ("train_config.json", "env_kwargs.json"):
        shutil.copy(run_dir / name, run / name)
    model = run / "model.zip"
    with zipfile.ZipFile(run_dir / "model.zip") as src, zipfile.ZipFile(model, "w") as dst:
        for name in src.namelist():
            data = src.read(name)
            if name == "data":
                fields = json.loads(data)
                fields["policy_class"][":serialized:"] = blob
                data = json.dumps(fields).encode()
            dst.writestr(name, data)
    env = _env(model)
    policy = load_policy(str(model), env)
    obs, infos = env.reset(seed=0)
    actions = policy(obs, infos)
    assert set(actions) == set(obs)
    assert not marker.exists()
    env.close()


def test_a_zip_from_outside_a_run_needs_trust_policy(run_dir, tmp_path):
    foreign = _foreign_copy(run_dir, tmp_path / "downloads")
    assert run_directory(foreign) is None
    env = _env(run_dir / "model.zip")
    with pytest.raises(ValueError, match="--trust-policy") as refused:
        load_policy(str(foreign), env)
    assert str(foreign) in str(refused.value) and "unpickles" in str(refused.value)
    trusted = load_policy(str(foreign), env, trust=True)
    assert not isinstance(trusted.model, WeightsOnlyModel)
    env.close()


def test_a_checkpoint_loads_weights_only_from_its_run(run_dir, tmp_path):
    checkpoint = tmp_path / "run" / "checkpoints" / "model_64_steps.zip"
    checkpoint.parent.mkdir(parents=True)
    shutil.copy(run_dir / "model.zip", checkpoint)
    assert run_directory(checkpoint) is None
    for name in ("train_config.json", "env_kwargs.json"):
        shutil.copy(run_dir / name, tmp_path / "run" / name)
    assert run_directory(checkpoint) == tmp_path / "run"
    env = _env(checkpoint)
    assert isinstance(load_policy(str(checkpoint), env).model, WeightsOnlyModel)
    env.close()


def test_evaluate_record_and_bridge_take_trust_policy(run_dir, tmp_path, capsys):
    from swarm_phd import bridge, evaluate, record

    for module, base in ((evaluate, []), (record, []), (bridge, ["--loopback"])):
        parser = argparse.ArgumentParser()
        module.add_arguments(parser)
        assert parser.parse_args([*base, "--trust-policy"]).trust_policy is True
        assert parser.parse_args(base).trust_policy is False
    foreign = _foreign_copy(run_dir, tmp_path / "downloads")
    argv = ["evaluate", "--policy", str(foreign), "--seeds", "0", "--localizer", "phd-lo"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(foreign) in err and "--trust-policy" in err
    assert main([*argv, "--duration", "0.5", "--trust-policy"]) == 0
    assert "task formation" in capsys.readouterr().out
    # The bridge: a run's own zip needs no flag; the same file from elsewhere does.
    parser = argparse.ArgumentParser()
    bridge.add_arguments(parser)
    kwargs, _ = bridge.bridge_env_kwargs(
        parser.parse_args(["--loopback", "--policy", str(run_dir / "model.zip")]), None
    )
    assert kwargs["task"] == "formation"
    with pytest.raises(ValueError, match="--trust-policy"):
        bridge.bridge_env_kwargs(parser.parse_args(["--loopback", "--policy", str(foreign)]), None)
    kwargs, _ = bridge.bridge_env_kwargs(
        parser.parse_args(["--loopback", "--trust-policy", "--policy", str(foreign)]), None
    )
    assert kwargs["task"] == "formation"


@pytest.mark.parametrize(
    "variant",
    [
        {"lstm_hidden": 8},
        {"critic_state": True, "residual": "scripted:formation", "residual_observes_base": True},
        {"sde": True},
    ],
    ids=["recurrent", "central-critic-residual", "gsde"],
)
def test_every_policy_kind_loads_weights_only_as_sb3_does(variant, tmp_path):
    """Recurrent PPO, the centralised critic (whose actor reads the scripted command) and
    gSDE: rebuilt from the run's JSON, the same tensors and actions as SB3's loader."""
    pytest.importorskip("sb3_contrib")
    from tests.agents.test_residual import KWARGS, train_tiny

    model = train_tiny(tmp_path / "run", **variant)
    env = parallel_env(**KWARGS)
    mine = load_policy(str(model), env)
    assert isinstance(mine.model, WeightsOnlyModel)
    reference = load_sb3_policy(_foreign_copy(model.parent, tmp_path / "copy"), env, trust=True)
    assert type(mine.model.policy) is type(reference.model.policy)
    theirs = reference.model.policy.state_dict()
    ours = mine.model.policy.state_dict()
    assert list(ours) == list(theirs)
    for name, tensor in theirs.items():
        assert bool((ours[name] == tensor).all()), name
    obs, infos = env.reset(seed=4)
    mine.reset(4)
    reference.reset(4)
    for _ in range(6):
        a, b = mine(obs, infos), reference(obs, infos)
        for agent in a:
            np.testing.assert_array_equal(a[agent], b[agent])
        obs, _, _, _, infos = env.step(a)
    env.close()
