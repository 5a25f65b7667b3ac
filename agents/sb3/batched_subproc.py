"""The batched VecEnv's copies split across worker processes, stepped at the same time.

:class:`~agents.sb3.batched.BatchedSwarmVecEnv` steps its ``K`` copies in the calling process,
so on a 2-core machine one core idles while the env steps (PPO's update, the other phase, runs
on one torch thread: a second one is slower when another process shares the cores,
``benchmarks/RESULTS.md``). Here each of ``n_workers`` spawned processes holds a
``BatchedSwarmVecEnv`` of a contiguous block of the copies (one localizer call per worker per
step); this process sends each its block of the actions, and gathers the rows in copy order.

Copy ``k`` takes the seeds it takes in one process (``copy_offset``) and the filter math is per
robot, so the rollout is bit-identical to ``BatchedSwarmVecEnv(env_kwargs, K, seed)``
(``tests/agents/test_batched_subproc.py``).

Workers are spawned, not forked (numba kills a forked child of a process that has run the
OpenMP kernels), and run their kernels on one thread. They ignore SIGINT and SIGTERM: a Ctrl-C
or a job scheduler's SIGTERM reaches the whole process group, and only the trainer acts on it
(it saves, then closes the workers). Both signals are blocked in this process while the
workers start, so a worker cannot be hit before it ignores them, and a signal that arrives
meanwhile is delivered to this process afterwards. A worker ends on ``close`` or when this
process's end of its pipe closes; :meth:`SubprocBatchedVecEnv.close` (also run at interpreter
exit for a VecEnv never closed) kills the ones that do not answer within its timeout.

Actions are checked here before any worker moves. A worker that raises sends its exception
back, re-raised here over the worker's traceback; a failed step or reset closes the VecEnv
(its copies are no longer in step), a failed call such as ``env_method`` does not. A worker
that dies is reported with its exit code, and the VecEnv closed.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.util
import pickle
import signal
import time
import traceback
from collections.abc import Sequence
from multiprocessing.reduction import ForkingPickler
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from agents.sb3.batched import check_unit_actions, copy_seeds_for_reset
from swarm_core.validation import check_number

__all__ = ["SubprocBatchedVecEnv", "split_copies"]

#: The signals a worker ignores (module doc).
WORKER_IGNORES = {signal.SIGINT, signal.SIGTERM}


class RemoteTraceback(Exception):
    """The traceback of an exception raised in an env worker (the ``__cause__`` of the
    exception re-raised in the trainer's process)."""


def split_copies(n_copies: int, n_workers: int) -> list[range]:
    """Contiguous blocks of the ``n_copies`` copies, one per worker, sizes differing by <= 1."""
    check_number("n_copies", n_copies, integer=True, low=1)
    check_number("n_workers", n_workers, integer=True, low=1)
    if n_workers > n_copies:
        raise ValueError(
            f"n_workers ({n_workers}) must not exceed n_copies ({n_copies}): a worker "
            "steps at least one copy"
        )
    blocks = np.array_split(np.arange(n_copies), n_workers)
    return [range(int(b[0]), int(b[-1]) + 1) for b in blocks]


class SubprocBatchedVecEnv(VecEnv):
    """``n_copies`` env copies in ``n_workers`` processes as one SB3 VecEnv (module doc).

    Parameters
    ----------
    env_kwargs, n_copies, seed
        As :class:`~agents.sb3.batched.BatchedSwarmVecEnv`; entry ``k R + i`` is agent ``i``
        of copy ``k`` (``R`` robots per copy), whatever worker steps it.
    n_workers : int
        Worker processes, in ``[1, n_copies]``; each steps a contiguous block of copies (one
        worker steps them all in another process: no stepping in parallel).
    **batched_kwargs
        The other keyword arguments of ``BatchedSwarmVecEnv`` (``residual``,
        ``critic_state``, ``residual_observes_base``, ``residual_mode``).

    Every command is one message to each worker concerned and one answer from each. If that
    exchange is cut short (a Ctrl-C or any exception in this process between the sends and the
    last answer), the pipes no longer pair commands with answers: the VecEnv then refuses every
    command but :meth:`close`.
    """

    def __init__(
        self,
        env_kwargs: dict[str, Any],
        n_copies: int,
        n_workers: int,
        seed: int | None = 0,
        **batched_kwargs: Any,
    ) -> None:
        self.blocks = split_copies(n_copies, n_workers)
        self._closed = False
        self._broken: str | None = None
        self._stepping = False
        self._connections: list[Any] = []
        self._processes: list[Any] = []
        context = multiprocessing.get_context("spawn")
        # Run at interpreter exit if close() never is (before multiprocessing's own exit
        # handler, whose SIGTERM the workers ignore).
        self._finalizer = multiprocessing.util.Finalize(
            self, _shutdown, args=(self._connections, self._processes), exitpriority=10
        )
        try:
            # Blocked, not ignored (CPython's resource tracker does the same): the blocked set
            # passes through the spawn, so a worker cannot die of a Ctrl-C before it ignores
            # it, and one that comes meanwhile reaches this process when the mask is restored.
            mask = signal.pthread_sigmask(signal.SIG_BLOCK, WORKER_IGNORES)
            try:
                for block in self.blocks:
                    parent, child = context.Pipe()
                    process = context.Process(
                        target=_worker,
                        args=(child, env_kwargs, len(block), block.start, seed, batched_kwargs),
                        daemon=True,
                        name=f"swarm-env-copies-{block.start}-{block.stop - 1}",
                    )
                    process.start()
                    child.close()
                    self._connections.append(parent)
                    self._processes.append(process)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            first = self._exchange({w: ("describe", None) for w in self._workers}, moves=True)[0]
            self.agents_per_copy: int = first["agents_per_copy"]
            #: As ``BatchedSwarmVecEnv``'s: entries of the scripted command and of the critic
            #: block at the end of each observation row.
            self.base_dims: int = first["base_dims"]
            self.critic_dims: int = first["critic_dims"]
            self._high = first["action_high"]
            self._next_seed = seed
            super().__init__(
                self.agents_per_copy * n_copies, first["observation_space"], first["action_space"]
            )
        except BaseException:
            self.close()
            raise

    @property
    def n_copies(self) -> int:
        return self.blocks[-1].stop

    @property
    def action_high(self) -> np.ndarray:
        """``[v_max, omega_max]``: a unit action times this is the env command, shape (2,)."""
        return self._high.copy()

    def copy_infos(self, copy: int) -> dict[str, dict[str, Any]]:
        """Copy ``copy``'s env ``infos`` for its current observation (as
        :meth:`~agents.sb3.batched.BatchedSwarmVecEnv.copy_infos`; pickled across)."""
        w, local = self._locate(copy)
        return self._exchange({w: ("call", ("copy_infos", (local,), {}))})[0]

    def scripted_commands(self, copy: int) -> dict[str, np.ndarray]:
        """The residual base's commands for copy ``copy`` (residual mode only)."""
        w, local = self._locate(copy)
        return self._exchange({w: ("call", ("scripted_commands", (local,), {}))})[0]

    # ------------------------------------------------------------------ VecEnv API
    def reset(self, copy_seeds: Sequence[int] | None = None) -> np.ndarray:
        """Reset every copy, seeded as :meth:`BatchedSwarmVecEnv.reset
        <agents.sb3.batched.BatchedSwarmVecEnv.reset>` seeds the same copies."""
        self._check_ready()
        seeds = copy_seeds_for_reset(
            self.n_copies, self.agents_per_copy, self._next_seed, self._seeds, copy_seeds
        )
        self._next_seed = None
        self._reset_seeds()
        messages = {
            w: ("call", ("reset_with_seeds", ([seeds[k] for k in block],), {}))
            for w, block in enumerate(self.blocks)
        }
        return np.concatenate(self._exchange(messages, moves=True))

    def step_async(self, actions: np.ndarray) -> None:
        self._check_ready()
        actions = check_unit_actions(actions, self.num_envs, self.agents_per_copy)
        n = self.agents_per_copy
        self._stepping = True
        self._send_all(
            {
                w: ("step", actions[block.start * n : block.stop * n])
                for w, block in enumerate(self.blocks)
            }
        )

    def step_wait(self):
        if self._closed or self._broken:
            self._check_ready()
        if not self._stepping:
            raise RuntimeError("step_wait() without step_async()")
        self._stepping = False
        results = self._gather(self._workers, moves=True)
        obs, rewards, dones, infos = zip(*results, strict=True)
        return (
            np.concatenate(obs),
            np.concatenate(rewards),
            np.concatenate(dones),
            [info for block in infos for info in block],
        )

    def close(self, timeout: float = 10.0) -> None:
        """Close the workers' envs and end the processes (idempotent). Workers that have not
        answered within ``timeout`` seconds in all are killed."""
        if self._closed:
            return
        self._closed = True
        self._finalizer.cancel()
        _shutdown(self._connections, self._processes, timeout)

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return self._per_entry("get_attr", indices, attr_name)

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        self._per_entry("set_attr", indices, attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        return self._per_entry("env_method", indices, method_name, *args, **kwargs)

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        answers = self._exchange({w: ("call", ("get_images", (), {})) for w in self._workers})
        return [image for block in answers for image in block]

    # ------------------------------------------------------------------ internals
    @property
    def _workers(self) -> range:
        return range(len(self.blocks))

    def _indices(self, indices) -> list[int]:
        return list(self._get_indices(indices))  # SB3's reading of None / int / iterable

    def _locate(self, copy: int) -> tuple[int, int]:
        """(worker, the copy's index in that worker) of global copy ``copy``."""
        for w, block in enumerate(self.blocks):
            if copy in block:
                return w, copy - block.start
        raise ValueError(f"copy must be an int in [0, {self.n_copies}), got {copy!r}")

    def _per_entry(self, method: str, indices, *args: Any, **kwargs: Any) -> list[Any]:
        """Call a per-entry VecEnv method in the workers holding ``indices``; the results in
        the order of ``indices``."""
        entries = self._indices(indices)
        n = self.agents_per_copy
        owner: list[tuple[int, int]] = []  # (worker, position in that worker's answer)
        asked: dict[int, list[int]] = {}
        for j in entries:
            if isinstance(j, bool) or not isinstance(j, (int, np.integer)):
                raise ValueError(f"indices must be ints in [0, {self.num_envs}), got {j!r}")
            if not 0 <= j < self.num_envs:
                raise ValueError(f"index {j} is outside [0, {self.num_envs})")
            w, _ = self._locate(int(j) // n)
            local = asked.setdefault(w, [])
            owner.append((w, len(local)))
            local.append(int(j) - self.blocks[w].start * n)
        messages = {
            w: ("call", (method, args, {**kwargs, "indices": local})) for w, local in asked.items()
        }
        answers = dict(zip(asked, self._exchange(messages), strict=True))
        return [None if answers[w] is None else answers[w][i] for w, i in owner]

    def _exchange(self, messages: dict[int, tuple], moves: bool = False) -> list[Any]:
        """Send each worker in ``messages`` its command; their answers, in that order."""
        self._check_ready()
        self._send_all(messages)
        return self._gather(list(messages), moves)

    def _send_all(self, messages: dict[int, tuple]) -> None:
        # Pickled first: an argument that cannot be pickled fails here, before anything is sent.
        payloads = {w: ForkingPickler.dumps(message) for w, message in messages.items()}
        try:
            for w, payload in payloads.items():
                try:
                    self._connections[w].send_bytes(payload)
                except OSError:  # BrokenPipeError: the worker has exited
                    failure = self._died(w)
                    self._broken = str(failure)
                    self.close()  # the workers already sent this command may have moved
                    raise failure from None
        except BaseException as exc:
            self._broken = self._broken or f"interrupted while sending ({type(exc).__name__})"
            raise

    def _gather(self, workers: Sequence[int], moves: bool = False) -> list[Any]:
        """Each worker's answer, in order. A worker's exception is re-raised here after every
        answer is read; when the command ``moves`` the copies (a step, a reset), the VecEnv is
        closed first, as the copies are no longer in step. A dead worker is reported with its
        exit code, and the VecEnv closed."""
        answers, failure = [], None
        try:
            for w in workers:
                try:
                    status, value = self._connections[w].recv()
                except (EOFError, OSError):
                    failure = failure or self._died(w)
                    moves = True
                    continue
                if status == "error" and failure is None:
                    exc, text = value
                    exc.__cause__ = RemoteTraceback(text)
                    failure = exc
                answers.append(value)
        except BaseException as exc:  # a Ctrl-C between answers: the pipes are out of step
            self._broken = f"interrupted while reading the workers' answers ({type(exc).__name__})"
            raise
        if failure is not None:
            if moves:
                self._broken = f"{type(failure).__name__}: {failure}"
                self.close()
            raise failure
        return answers

    def _died(self, w: int) -> RuntimeError:
        process = self._processes[w]
        process.join(timeout=5)
        block = self.blocks[w]
        status = (
            "still running but not answering"
            if process.exitcode is None
            else f"exit code {process.exitcode}"
        )
        return RuntimeError(
            f"env worker {w} (copies {block.start}-{block.stop - 1}, pid {process.pid}) "
            f"died: {status}"
        )

    def _check_ready(self) -> None:
        if self._broken:
            then = "it was closed" if self._closed else "close() it"
            raise RuntimeError(
                f"this SubprocBatchedVecEnv is unusable ({self._broken}): {then}, and make a "
                "new one"
            )
        if self._closed:
            raise RuntimeError("this SubprocBatchedVecEnv is closed")
        if self._stepping:
            raise RuntimeError("step_async() was called: step_wait() must come first")


def _shutdown(connections: list, processes: list, timeout: float = 10.0) -> None:
    """Ask each worker to close, wait for its ``"closed"`` (after any answer still owed) within
    ``timeout`` seconds in all, close the pipes (a worker still waiting reads end-of-file), and
    kill any worker left (it ignores SIGTERM)."""
    for conn in connections:
        try:
            conn.send(("close", None))
        except Exception:  # a dead worker, a broken pipe
            pass
    deadline = time.monotonic() + timeout
    for conn in connections:
        try:
            while conn.poll(max(0.0, deadline - time.monotonic())):
                if conn.recv()[0] == "closed":
                    break
        except Exception:  # end-of-file, a cut message: the worker is going anyway
            pass
    for conn in connections:
        conn.close()
    for process in processes:
        process.join(timeout=max(0.1, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join(timeout=5)


def _worker(conn, env_kwargs, n_copies, copy_offset, seed, batched_kwargs) -> None:
    """A worker's loop: build its copies, then answer ``describe``, ``step``, ``call`` and
    ``close``."""
    # The trainer handles Ctrl-C and SIGTERM sent to the whole group (module doc); they were
    # blocked when this process started, so ignore them first, then unblock (pending: dropped).
    for signum in WORKER_IGNORES:
        signal.signal(signum, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, WORKER_IGNORES)
    try:
        from swarm_core.threads import set_kernel_threads

        set_kernel_threads(1)
        from agents.sb3.batched import BatchedSwarmVecEnv

        venv = BatchedSwarmVecEnv(
            env_kwargs, n_copies, seed, copy_offset=copy_offset, **batched_kwargs
        )
    except Exception as exc:
        venv, failure = None, exc
    while True:
        try:
            command, payload = conn.recv()
        except (EOFError, OSError):  # the trainer is gone
            break
        try:
            if venv is None and command != "close":
                raise failure
            if command == "describe":
                result = {
                    "agents_per_copy": venv.agents_per_copy,
                    "base_dims": venv.base_dims,
                    "critic_dims": venv.critic_dims,
                    "action_high": venv.action_high,
                    "observation_space": venv.observation_space,
                    "action_space": venv.action_space,
                }
            elif command == "step":
                venv.step_async(payload)
                result = venv.step_wait()
            elif command == "call":
                name, args, kwargs = payload
                result = getattr(venv, name)(*args, **kwargs)
            elif command == "close":
                try:
                    if venv is not None:
                        venv.close()
                finally:
                    _answer(conn, ("closed", None))
                break
            else:
                raise ValueError(f"unknown env worker command {command!r}")
            answer = ("ok", result)
        except Exception as exc:
            answer = ("error", _portable(exc))
        if not _answer(conn, answer):
            break
    conn.close()


def _answer(conn, message: tuple) -> bool:
    """Send ``message``; False if the trainer is gone (the worker then ends quietly)."""
    try:
        conn.send(message)
    except OSError:
        return False
    return True


def _portable(exc: Exception) -> tuple[Exception, str]:
    """``exc`` (or a RuntimeError with its text, if it cannot be pickled) and its traceback."""
    text = traceback.format_exc()
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        exc = RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc, text
