"""A recurrent residual student: a GRU over the robot's own estimate, distilled by DAgger.

    from agents.sb3.recurrent_student import DistillConfig, distill

    config = DistillConfig(env_kwargs, base="scripted:formation-known-n-fast",
                           teacher="privileged:formation-known-n-fast@truth",
                           round_seeds=(range(0, 200), range(1000, 1100)),
                           val_seeds=range(200, 210))
    distill(config, "runs/recurrent")

(``python -m experiments.recurrent_student`` reads the same settings from flags.) A causal GRU
over the episode's estimates predicts a larger share of the correction that the controller on
the truth makes beyond the base's command than one frame does
(``experiments/history_fit.py``). :func:`distill` trains that regressor as a policy:

- the model is :mod:`agents.sb3.sequences`' ``history`` regressor (the students' Deep Sets
  encoder of the observation and the base's command, a GRU, a 64-64 tanh head) and its output
  is the residual's correction, unit scale: the command is ``base + correction * high``,
  clipped (:func:`agents.sb3.residual.compose`); each agent keeps its own GRU state, reset
  with the episode;
- round 1 records ``--round-seeds``' first block of episodes with the base driving, round
  ``r > 1`` the next block with round ``r - 1``'s student driving (DAgger: the states the
  student reaches); the labels are the teacher's corrections against the base's command at
  every state (:func:`agents.sb3.warm_start.correction_labels`); every round fits on all the
  rounds' sequences so far, starting from the last round's weights (``--epochs`` for round 1,
  ``--dagger-epochs`` after);
- each round's student is saved (``student_round<r>.pt``, the last also as ``student.pt``)
  with its env, base and teacher, and is scored in closed loop on ``--val-seeds`` per phase
  of the episode, with the base beside it (``train_log.json``, drawn in ``train_log.png``;
  several runs in one figure: :func:`plot_train_logs`). ``student_best.pt`` is a copy of the
  completed round's student with the lowest formation error there (``"best_round"`` in the
  log); the final test belongs on seeds used nowhere here.
- Each round's sequences are kept (``round<r>.npz``, with the key they were collected with)
  and reused when the command is rerun with the same env, base, teacher and seeds, and, from
  round 2, the same driving student (its weights' hash): round 1's always, a later round's
  when the refit reproduces the student bit for bit (the same machine and ``--torch-threads``;
  torch's sums are not bit-identical across thread counts). Every round is refitted, and a
  rerun first removes the earlier run's students.
- Ctrl-C or SIGTERM stops the run where it is, and ``--max-wall-minutes`` after the round in
  which the budget passes: ``student.pt`` becomes the last completed round's student (a copy
  of its ``student_round<r>.pt``; not written if no round completed), ``train_log.json``
  says why (``"stopped"``: the signal, ``"max-wall-minutes"``; null after a full run) and
  the command exits 130 (SIGINT), 143 (SIGTERM) or 0 (the budget). The students, the
  rounds' data and ``train_log.json`` are written to a temporary name, then renamed: a stop
  never leaves one half-written.

Score a student like any policy: ``swarm-phd evaluate --policy runs/recurrent/student.pt``.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation import DEFAULT_PHASES
from swarm_core.atomic_files import atomic_write, write_json_atomically
from swarm_core.inputs import format_seeds

__all__ = [
    "DistillConfig",
    "RecurrentStudentPolicy",
    "distill",
    "student_space",
    "check_student_env",
    "load_student",
    "plot_train_logs",
    "read_student_metadata",
    "save_student",
]

#: The saved file's ``format`` field; a file without it is refused.
FORMAT = "swarm-phd recurrent residual student v1"


def save_student(
    path: str | Path, model: Any, env_kwargs: dict[str, Any], base: str, **extra: Any
) -> None:
    """Write ``model`` (a ``history`` regressor) with what it needs to run: its env's kwargs,
    its base's spec, its hidden width and the observation's length. Atomically: a trainer
    stopped while saving leaves the previous file, never half of one."""
    import torch

    data = {
        "format": FORMAT,
        "state_dict": model.state_dict(),
        "hidden": int(model.gru.hidden_size),
        "obs_dim": int(model.encoder_obs_dim),
        "env_kwargs": env_kwargs,
        "base": base,
        **extra,
    }
    atomic_write(path, lambda tmp: torch.save(data, tmp))


def _read(path: str | Path) -> dict[str, Any]:
    import torch

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"recurrent student {str(path)!r} does not exist")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # a truncated file, a zip model renamed, ...
        raise ValueError(f"{str(path)!r} is not a recurrent student file: {err}") from err
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{str(path)!r} is not a recurrent student file (format {FORMAT!r})")
    return data


def read_student_metadata(path: str | Path) -> dict[str, Any]:
    """Everything a student file holds but its weights: ``env_kwargs``, ``base``, ``hidden``,
    ``obs_dim`` and what its training added (``teacher``, ``round``, ...)."""
    return {k: v for k, v in _read(path).items() if k != "state_dict"}


#: The observations a student's encoder reads: the neighbour table's layout (``top_k`` rows).
STUDENT_OBSERVATIONS = ("phd", "truth")


def check_student_env(env_kwargs: dict[str, Any], field: str) -> None:
    """ValueError naming ``field`` unless a student's encoder can read the env's observation:
    the ``"phd"`` or ``"truth"`` table (not raw measurements) with the default 16 rows."""
    observation = env_kwargs.get("observation", "phd")
    if observation not in STUDENT_OBSERVATIONS:
        raise ValueError(
            f"{field}: a recurrent student reads observation one of {STUDENT_OBSERVATIONS}, "
            f"this env has observation={observation!r}"
        )
    top_k = env_kwargs.get("top_k", 16)
    if top_k != 16:
        raise ValueError(
            f"{field}: a recurrent student reads 16 table rows, this env has top_k={top_k}"
        )


def new_student(observation_space: Any, hidden: int = 64) -> Any:
    """An untrained student: :func:`agents.sb3.sequences.regressor`'s ``history`` kind."""
    from agents.sb3.sequences import regressor

    model = regressor(observation_space, "history", hidden=hidden)
    model.encoder_obs_dim = int(np.prod(observation_space.shape))
    return model


class RecurrentStudentPolicy:
    """A student as a policy, ``(observations, infos) -> actions``, for one env.

    Its base (a :class:`agents.sb3.residual.ResidualBase`) gives the command; the model, fed
    the observation and that command, gives the correction. Each agent's GRU state is kept by
    name from its first step and cleared by :meth:`reset` (the episode's start)."""

    def __init__(self, model: Any, base: str, env: Any) -> None:
        from agents.sb3.residual import ResidualBase

        self.model = model.eval()
        self.base = ResidualBase(base, env)
        self.high = self.base.high
        self.hidden: dict[str, Any] = {}

    def reset(self, seed: int | None = None) -> None:
        self.base.reset(seed)
        self.hidden = {}

    def correct(
        self, observations: dict[str, np.ndarray], commands: dict[str, np.ndarray]
    ) -> dict[str, np.ndarray]:
        """The residual commands for the base's ``commands`` (env units, per agent), one GRU
        step for every agent at once; float32 ``[v_mps, omega_radps]``."""
        import torch

        from agents.sb3.residual import base_in_unit_scale, compose

        agents = list(observations)
        if not agents:
            return {}
        obs = torch.as_tensor(np.stack([observations[a] for a in agents]), dtype=torch.float32)
        base = np.stack([commands[a] for a in agents])
        unit = torch.as_tensor(base_in_unit_scale(base, self.high))
        zeros = torch.zeros(self.model.gru.hidden_size)
        h = torch.stack([self.hidden.get(a, zeros) for a in agents]).unsqueeze(0)
        with torch.no_grad():
            correction, h = self.model.step(obs, unit, h)
        for i, a in enumerate(agents):
            self.hidden[a] = h[0, i]
        actions = compose(base, correction.numpy(), self.high)
        return {a: actions[i] for i, a in enumerate(agents)}

    def __call__(
        self, observations: dict[str, np.ndarray], infos: dict[str, dict[str, Any]] | None
    ) -> dict[str, np.ndarray]:
        return self.correct(observations, self.base(observations, infos))


def load_student(path: str | Path, env: Any) -> RecurrentStudentPolicy:
    """The student saved at ``path`` as a policy for ``env``; ValueError if ``env``'s
    observation is not the length it was trained on."""
    import torch

    torch.set_num_threads(1)  # one agent-step at a time: a thread pool would only spin
    data = _read(path)
    space = env.observation_space(env.possible_agents[0])
    dim = int(np.prod(space.shape))
    if dim != data["obs_dim"]:
        raise ValueError(
            f"recurrent student {str(path)!r} reads observations of length {data['obs_dim']}, "
            f"this env gives {dim} (its env: {data['env_kwargs']})"
        )
    model = new_student(space, hidden=data["hidden"])
    model.load_state_dict(data["state_dict"])
    return RecurrentStudentPolicy(model, data["base"], env)


def _round_data(
    path: Path, key: dict[str, Any], collect: Any
) -> tuple[dict[str, np.ndarray], bool]:
    """A round's sequences: read from ``path`` if it was written with the same ``key`` (env,
    base, teacher, seeds, driver), else collected and written. Returns them and whether they
    were reused. The key is written last, after the data is complete: a run killed while
    writing leaves no key, and its data is collected again."""
    meta = path.with_suffix(".json")
    if path.is_file() and meta.is_file() and json.loads(meta.read_text()) == key:
        with np.load(path) as f:
            return {k: f[k] for k in f.files}, True
    meta.unlink(missing_ok=True)
    data = collect()
    atomic_write(path, lambda tmp: np.savez(tmp, **data))
    write_json_atomically(meta, key)
    return data, False


def _digest(path: Path) -> str:
    """A hash of a saved student's weights (names, shapes and values, in name order): the same
    for the same student whatever ``torch.save``'s container bytes."""
    import hashlib

    state = _read(path)["state_dict"]
    h = hashlib.sha256()
    for name in sorted(state):
        t = state[name].contiguous()
        h.update(f"{name}{tuple(t.shape)}{t.dtype}".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def _concat(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Rounds' sequences as one set, padded to the longest."""
    t_max = max(p["obs"].shape[1] for p in parts)
    out: dict[str, list[np.ndarray]] = {}
    for p in parts:
        pad = t_max - p["obs"].shape[1]
        for k, v in p.items():
            if v.ndim >= 2 and pad:
                width = [(0, 0), (0, pad)] + [(0, 0)] * (v.ndim - 2)
                v = np.pad(v, width)
                if k == "step":
                    v[:, -pad:] = np.arange(p["obs"].shape[1], t_max)
            out.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in out.items()}


def plot_train_logs(logs: list[str | Path], figure: str | Path) -> None:
    """Draw each run's validation score per DAgger round (``train_log.json`` files), over the
    episode and once settled (the last phase), with its base's as a dashed line, to
    ``figure`` (PNG): how DAgger rounds move a student."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), squeeze=False)
    for path in logs:
        log = json.loads(Path(path).read_text())
        metric = "formation_error_m"
        settled = f"{metric}@{log['phases'][-1]}-"
        label = Path(path).parent.name
        if "fit_seed" in log:
            label += f" (fit seed {log['fit_seed']})"
        rounds = [r["round"] for r in log["rounds"]]
        for ax, key in zip(axes[0], (metric, settled), strict=True):
            line = ax.plot(rounds, [r["val"][key] for r in log["rounds"]], "o-", label=label)[0]
            ax.axhline(log["base_val"][key], ls="--", color=line.get_color(), alpha=0.5)
    for ax, title in zip(axes[0], ("episode", "settled (last phase)"), strict=True):
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        ax.set_xlabel("DAgger round (1: the base's states only)")
        ax.set_ylabel("formation error (m), validation seeds")
        ax.set_title(f"recurrent student, {title}; dashed: the base")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(figure, lambda tmp: fig.savefig(tmp, dpi=110))  # a Ctrl-C mid-write: old file
    plt.close(fig)


@dataclass(frozen=True)
class DistillConfig:
    """A DAgger distillation of a recurrent student (:func:`distill`; module doc).

    ``round_seeds``: one block of episode seeds per round (the first with the base driving,
    the next ones with the previous round's student); ``val_seeds``: the closed-loop score of
    every round (none shared with the rounds); ``phases``: the first steps of the scored
    phases; ``epochs`` / ``dagger_epochs``: round 1's / later rounds' passes over the data;
    ``fit_seed``: torch's and the minibatches' seed; ``max_wall_s``: stop after the round in
    which this much wall time has passed (None: no budget). Checked on construction:
    ``ValueError`` naming the command-line flag and the value.
    """

    env_kwargs: dict[str, Any]
    base: str
    teacher: str
    round_seeds: tuple[tuple[int, ...], ...]
    val_seeds: tuple[int, ...]
    phases: tuple[int, ...] = DEFAULT_PHASES
    epochs: int = 30
    dagger_epochs: int = 10
    fit_seed: int = 0
    torch_threads: int = 1
    max_wall_s: float | None = None

    def __post_init__(self) -> None:
        from agents.evaluation import parse_phases
        from agents.sb3.residual import check_residual
        from swarm_core.validation import check_number

        rounds = tuple(tuple(int(s) for s in r) for r in self.round_seeds)
        object.__setattr__(self, "round_seeds", rounds)
        object.__setattr__(self, "val_seeds", tuple(int(s) for s in self.val_seeds))
        object.__setattr__(self, "phases", tuple(parse_phases(self.phases)))
        if not rounds or not all(rounds):
            raise ValueError(f"--round-seeds must name seeds for every round, got {rounds!r}")
        used = [s for r in rounds for s in r]
        if len(set(used)) != len(used):
            shown = " ".join(format_seeds(r) for r in rounds)
            raise ValueError(f"--round-seeds repeat seeds: {shown}")
        shared = sorted(set(used) & set(self.val_seeds))
        if shared:
            raise ValueError(f"--val-seeds share seeds with --round-seeds: {shared}")
        for flag, value in (
            ("--epochs", self.epochs),
            ("--dagger-epochs", self.dagger_epochs),
            ("--torch-threads", self.torch_threads),
        ):
            check_number(flag, value, integer=True, low=1)
        check_number("--fit-seed", self.fit_seed, integer=True, low=0)
        check_number("--max-wall-minutes", self.max_wall_s, low=0, above=True, optional=True)
        check_residual(self.base, "--base")
        check_student_env(self.env_kwargs, "--observation/--env-overrides")


def student_space(config: DistillConfig) -> Any:
    """The observation space the student reads, from a probe env of ``config.env_kwargs``; the
    teacher is loaded on it first (``ValueError`` naming ``--teacher`` for a bad spec), so a
    caller can check a configuration before any rollout."""
    from agents.sb3.privileged import load_teacher
    from swarm_env import parallel_env

    probe = parallel_env(**config.env_kwargs)
    try:
        load_teacher(config.teacher, probe)
        return probe.observation_space(probe.possible_agents[0])
    except ValueError as err:
        raise ValueError(f"--teacher {config.teacher!r}: {err}") from err
    finally:
        probe.close()


def distill(config: DistillConfig, out: str | Path) -> int:
    """Distil a recurrent student by DAgger into ``out`` (module doc): ``student.pt`` (the last
    completed round's), ``student_best.pt`` (the round best on ``config.val_seeds``), each
    round's ``student_round<r>.pt`` and ``round<r>.npz``, ``train_log.json`` and its figure.

    :func:`student_space` checks the teacher before ``out`` is made. Returns the exit code: 0,
    or 130 / 143 after SIGINT / SIGTERM (the last completed round's student kept)."""
    import torch

    torch.set_num_threads(config.torch_threads)
    space = student_space(config)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config.fit_seed)
    return _dagger(config, new_student(space), out)


def _finite_or_inf(val: dict[str, float]) -> float:
    """A round's validation formation error for choosing the best (a NaN is never best)."""
    error = val["formation_error_m"]
    return error if np.isfinite(error) else np.inf


def _dagger(config: DistillConfig, model: Any, out: Path) -> int:
    """The DAgger rounds of :func:`distill`, stopped by a signal or the wall-time budget
    (module doc); returns the exit code."""
    import torch

    from agents.evaluation import score
    from agents.interrupts import EXIT_CODES, Interrupts, WallBudget, stop_reason
    from agents.sb3.sequences import collect_sequences, sequence_tensors, train_sequences
    from swarm_env import parallel_env

    env_kwargs, phases = config.env_kwargs, list(config.phases)
    val_seeds, val_text = list(config.val_seeds), format_seeds(config.val_seeds)
    rounds = [list(r) for r in config.round_seeds]
    log: dict[str, Any] = {
        "env_kwargs": env_kwargs,
        "base": config.base,
        "teacher": config.teacher,
        "round_seeds": [format_seeds(r) for r in rounds],
        "val_seeds": val_seeds,
        "fit_seed": config.fit_seed,
        "epochs": config.epochs,
        "dagger_epochs": config.dagger_epochs,
        "torch_threads": config.torch_threads,
        "phases": phases,
        "rounds": [],
    }
    # A rerun into the same --out keeps the rounds' data for reuse, but not an earlier run's
    # students: after a stop, the students left must be this run's.
    for old in [out / "student.pt", out / "student_best.pt", *out.glob("student_round*.pt")]:
        old.unlink(missing_ok=True)
    r = 1
    budget = WallBudget(config.max_wall_s)
    with Interrupts() as interrupts:
        with interrupts.caught():
            t_base = time.perf_counter()
            log["base_val"] = score(config.base, env_kwargs, val_seeds, phases=phases)["mean"]
            print(f"base on {val_text}: {log['base_val']} ({time.perf_counter() - t_base:.0f} s)")
            parts: list[dict[str, np.ndarray]] = []
            for r, seeds in enumerate(rounds, start=1):
                if interrupts.received:  # a signal that landed in a C callback was dropped
                    raise KeyboardInterrupt
                t0 = time.perf_counter()
                driver = None
                if r > 1:
                    env = parallel_env(**env_kwargs)
                    driver = load_student(out / f"student_round{r - 1}.pt", env)
                    env.close()
                key = {
                    "env_kwargs": env_kwargs,
                    "base": config.base,
                    "teacher": config.teacher,
                    "seeds": seeds,
                    # the driving student by content: a refit one makes the round's data stale
                    "driver": "base" if r == 1 else _digest(out / f"student_round{r - 1}.pt"),
                }
                data, reused = _round_data(
                    out / f"round{r}.npz",
                    key,
                    lambda seeds=seeds, driver=driver: collect_sequences(
                        env_kwargs, config.base, config.teacher, seeds, student=driver
                    ),
                )
                parts.append(data)
                t1 = time.perf_counter()
                epochs = config.epochs if r == 1 else config.dagger_epochs
                torch.set_num_threads(config.torch_threads)  # loading a student set it to 1
                losses = train_sequences(
                    model, sequence_tensors(_concat(parts)), epochs, seed=config.fit_seed + r
                )
                t2 = time.perf_counter()
                path = out / f"student_round{r}.pt"
                save_student(path, model, env_kwargs, config.base, teacher=config.teacher, round=r)
                val = score(str(path), env_kwargs, val_seeds, phases=phases)["mean"]
                t3 = time.perf_counter()
                log["rounds"].append(
                    {
                        "round": r,
                        "seeds": seeds,
                        "data_reused": reused,
                        "sequences": int(sum(p["obs"].shape[0] for p in parts)),
                        "losses": losses,
                        "collect_s": t1 - t0,
                        "fit_s": t2 - t1,
                        "val_s": t3 - t2,
                        "val": val,
                    }
                )
                write_json_atomically(out / "train_log.json", log, indent=1)
                plot_train_logs([out / "train_log.json"], out / "train_log.png")
                print(
                    f"round {r}: {len(seeds)} episodes ({'reused' if reused else 'collected'}, "
                    f"{t1 - t0:.0f} s), fit {t2 - t1:.0f} s, loss {losses[-1]:.4f}; on "
                    f"{val_text}: {val['formation_error_m']:.4f} m "
                    f"(base {log['base_val']['formation_error_m']:.4f} m)"
                )
                if r < len(rounds) and budget.passed():
                    break
        interrupted = interrupts.received
        # log["rounds"] holds exactly the completed rounds (saved, scored, logged).
        completed = log["rounds"][-1]["round"] if log["rounds"] else 0
        with Interrupts(ignore=True):  # a second signal must not leave a half-written file
            # The model may hold part of an interrupted round's fit: the usable student is
            # the last completed round's file, copied whole.
            usable = out / f"student_round{completed}.pt" if completed else None
            if usable is not None:
                atomic_write(out / "student.pt", lambda tmp: shutil.copyfile(usable, tmp))
                # The round best on the validation seeds.
                best = min(log["rounds"], key=lambda d: _finite_or_inf(d["val"]))
                log["best_round"] = best["round"]
                selected = out / f"student_round{best['round']}.pt"
                atomic_write(out / "student_best.pt", lambda tmp: shutil.copyfile(selected, tmp))
            log["interrupted"] = interrupted
            log["stopped"] = stop_reason(interrupted, budget)
            write_json_atomically(out / "train_log.json", log, indent=1)
    if usable is not None:
        print(
            f"student_best.pt is round {best['round']}'s, the best on {val_text} "
            f"({_finite_or_inf(best['val']):.4f} m)"
        )
    if not log["stopped"]:
        return 0
    saved = (
        f"student.pt is round {completed}'s ({usable.name})"
        if usable is not None
        else "no round completed, no student saved"
    )
    if interrupted:
        print(
            f"recurrent_student: {interrupted} in round {r} ({completed} completed): {saved}",
            file=sys.stderr,
        )
        return EXIT_CODES[interrupted]
    print(f"recurrent_student: wall-time budget, stopped after round {completed}: {saved}")
    return 0
