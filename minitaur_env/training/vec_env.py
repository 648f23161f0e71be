"""A VecEnv that runs groups of envs, one group per process, the first in the caller.

SB3's ``SubprocVecEnv`` gives every env its own process, and the calling process only
waits. On a machine with few cores that costs twice: the caller still needs a core to
wake up for every step, and each env step pays a pipe round trip. Here the envs are
split into as many contiguous groups as there are processes; the first group steps in
the calling process while the others step in their workers, so two processes keep two
cores busy and each worker pays one round trip per group step, not per env.

Each group is an SB3 ``DummyVecEnv``, so auto-reset, ``terminal_observation`` and
``TimeLimit.truncated`` behave exactly as in SB3's own VecEnvs, and the same seeds give
the same transitions as a ``DummyVecEnv`` of all the envs.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import itertools
import multiprocessing as mp
import os
import signal
import time
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv
from stable_baselines3.common.vec_env.base_vec_env import (
    CloudpickleWrapper,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)


class EnvWorkerError(RuntimeError):
    """An env of a GroupedSubprocVecEnv raised, or a worker process died."""


def _leave_signals_to_the_caller() -> None:
    # A terminal's Ctrl-C, or a SIGTERM sent to the whole process group (Slurm, a
    # container stop), reaches every process. A worker that died of it would break
    # the caller's pipe while the caller saves a checkpoint; the caller ends the
    # workers itself when it closes.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


class _TagsErrorsWithIndex(gym.Wrapper):
    """Marks any exception of the wrapped env with the env's index in the VecEnv."""

    def __init__(self, env: gym.Env, index: int) -> None:
        super().__init__(env)
        self.vec_env_index = index

    def step(self, action: Any) -> Any:
        try:
            return self.env.step(action)
        except Exception as error:
            error.env_index = getattr(error, "env_index", self.vec_env_index)  # type: ignore[attr-defined]
            raise

    def reset(self, **kwargs: Any) -> Any:
        try:
            return self.env.reset(**kwargs)
        except Exception as error:
            error.env_index = getattr(error, "env_index", self.vec_env_index)  # type: ignore[attr-defined]
            raise


class _Indexed:
    """An env function whose env reports its index with any exception it raises."""

    def __init__(self, env_fn: Callable[[], gym.Env], index: int) -> None:
        self.env_fn = env_fn
        self.index = index

    def __call__(self) -> gym.Env:
        try:
            env = self.env_fn()
        except Exception as error:
            error.env_index = self.index  # type: ignore[attr-defined]
            raise
        return _TagsErrorsWithIndex(env, self.index)


def _describe(error: BaseException) -> str:
    index = getattr(error, "env_index", None)
    where = f"env {index}" if index is not None else "an env"
    return f"{where} raised {type(error).__name__}: {error}"


def _group_worker(
    remote: Connection, parent_remote: Connection, env_fns: CloudpickleWrapper
) -> None:
    _leave_signals_to_the_caller()
    parent_remote.close()
    group = None
    try:
        group = DummyVecEnv(env_fns.var)
        remote.send(("ready", None))
        while True:
            command, data = remote.recv()
            if command == "step":
                remote.send(("ok", (*group.step(data), group.reset_infos)))
            elif command == "reset":
                _prepare_reset(group, *data)
                remote.send(("ok", (group.reset(), group.reset_infos)))
            elif command == "call":
                name, args, kwargs = data
                remote.send(("ok", getattr(group, name)(*args, **kwargs)))
            elif command == "close":
                return
    except (EOFError, BrokenPipeError, KeyboardInterrupt):  # the caller went away
        return
    except Exception as error:
        # The caller gets one line naming the env; the worker then exits.
        with contextlib.suppress(BrokenPipeError, OSError):
            remote.send(("error", _describe(error)))
    finally:
        if group is not None:
            group.close()


def _kill_workers(processes: list[Any]) -> None:
    for process in processes:
        if process.is_alive():
            process.kill()
            process.join(timeout=5.0)


def _prepare_reset(group: DummyVecEnv, seeds: list[int | None], options: list[dict]) -> None:
    """Hand a group its slice of the seeds and options of the next reset."""
    # VecEnv.seed() gives consecutive seeds (or none), so a slice is its first + index.
    if seeds[0] is not None:
        group.seed(seeds[0])
    group.set_options(options)


def available_cores() -> int:
    """CPU cores this process may run on (its affinity, where the OS reports one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _split(n_envs: int, n_groups: int) -> list[range]:
    bounds = np.linspace(0, n_envs, n_groups + 1).round().astype(int)
    return [range(start, stop) for start, stop in itertools.pairwise(bounds)]


def _concatenate(parts: Sequence[VecEnvObs]) -> VecEnvObs:
    if isinstance(parts[0], dict):
        return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}  # type: ignore[index]
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate(items) for items in zip(*parts, strict=True))
    return np.concatenate(parts)  # type: ignore[arg-type]


class GroupedSubprocVecEnv(VecEnv):
    """``n_envs`` envs in ``n_processes`` processes; the first group runs in this one.

    ``n_processes`` defaults to the CPU cores available, capped at the number of envs.
    ``n_processes=1`` is a ``DummyVecEnv`` in all but name.

    An exception in any env reaches the caller as one :class:`EnvWorkerError` naming the
    env's index and the original exception, as does a worker that dies. Workers ignore
    Ctrl-C and SIGTERM, which are the caller's to handle; ``close()`` asks them to stop
    and ends any that has not within ``close_timeout`` seconds, so it never blocks.

    As with ``SubprocVecEnv``, the env functions must be picklable and the calling script
    needs an ``if __name__ == "__main__":`` guard (workers start with forkserver or spawn).
    """

    def __init__(
        self,
        env_fns: list[Callable[[], gym.Env]],
        n_processes: int | None = None,
        start_method: str | None = None,
        close_timeout: float = 10.0,
    ) -> None:
        if not env_fns:
            raise ValueError("GroupedSubprocVecEnv needs at least one env")
        if n_processes is None:
            n_processes = available_cores()
        if n_processes < 1:
            raise ValueError(f"n_processes must be at least 1, got {n_processes}")
        self.groups = _split(len(env_fns), min(n_processes, len(env_fns)))
        if start_method is None:
            methods = mp.get_all_start_methods()
            start_method = "forkserver" if "forkserver" in methods else "spawn"
        context = mp.get_context(start_method)

        env_fns = [_Indexed(fn, index) for index, fn in enumerate(env_fns)]
        self.close_timeout = close_timeout
        self.remotes: list[Connection] = []
        self.processes: list[Any] = []
        self.closed = False
        # The workers ignore SIGTERM, so multiprocessing's own exit handler, which
        # terminates daemonic children and then joins them, would wait forever for a
        # worker of an env never closed (a script ending in an exception). Handlers run
        # last-registered first, so this one kills them before that join.
        self._kill_at_exit = functools.partial(_kill_workers, self.processes)
        atexit.register(self._kill_at_exit)
        for group in self.groups[1:]:
            remote, work_remote = context.Pipe()
            fns = CloudpickleWrapper([env_fns[i] for i in group])
            process = context.Process(
                target=_group_worker, args=(work_remote, remote, fns), daemon=True
            )
            process.start()
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(process)
        self._unread = [1] * len(self.remotes)  # each worker's "ready"
        self.local: DummyVecEnv | None = None
        try:
            self.local = self._local(DummyVecEnv, [env_fns[i] for i in self.groups[0]])
            for number in range(len(self.remotes)):
                self._receive(number)  # "ready", or the error that stopped the worker
        except BaseException:
            self.close()
            raise
        super().__init__(len(env_fns), self.local.observation_space, self.local.action_space)

    # -- talking to the workers --------------------------------------------------
    def _send(self, number: int, message: tuple[str, Any]) -> None:
        while self._unread[number]:  # an answer left unread when an error cut a step short
            self._receive(number)
        try:
            self.remotes[number].send(message)
        except (BrokenPipeError, OSError) as error:
            raise self._worker_died(number) from error
        self._unread[number] += 1

    def _receive(self, number: int) -> Any:
        try:
            status, payload = self.remotes[number].recv()
        except (EOFError, OSError) as error:
            self._unread[number] = 0
            raise self._worker_died(number) from error
        self._unread[number] -= 1
        if status == "error":
            raise EnvWorkerError(payload)
        return payload

    def _worker_died(self, number: int) -> EnvWorkerError:
        process = self.processes[number]
        process.join(timeout=1.0)
        group = self.groups[number + 1]
        return EnvWorkerError(
            f"the worker process of envs {group.start}..{group.stop - 1} exited "
            f"(exit code {process.exitcode})"
        )

    def _local(self, method: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        try:
            return method(*args, **kwargs)
        except Exception as error:
            raise EnvWorkerError(_describe(error)) from error

    # -- stepping --------------------------------------------------------------
    def step_async(self, actions: np.ndarray) -> None:
        for number, group in enumerate(self.groups[1:]):
            self._send(number, ("step", actions[group.start : group.stop]))
        self._local_actions = actions[self.groups[0].start : self.groups[0].stop]

    def step_wait(self) -> VecEnvStepReturn:
        # The local group steps while the workers step theirs.
        local = self._local(self.local.step, self._local_actions)
        results = [(*local, self.local.reset_infos)]
        results += [self._receive(number) for number in range(len(self.remotes))]
        obs, rewards, dones, infos, reset_infos = zip(*results, strict=True)
        self.reset_infos = [info for part in reset_infos for info in part]
        return (
            _concatenate(obs),
            np.concatenate(rewards),
            np.concatenate(dones),
            [info for part in infos for info in part],
        )

    def reset(self) -> VecEnvObs:
        seeds, options = self._seeds, self._options
        for number, group in enumerate(self.groups[1:]):
            self._send(
                number,
                ("reset", (seeds[group.start : group.stop], options[group.start : group.stop])),
            )
        first = self.groups[0]
        self.local._seeds = seeds[first.start : first.stop]
        self.local._options = options[first.start : first.stop]
        results = [(self._local(self.local.reset), self.local.reset_infos)]
        results += [self._receive(number) for number in range(len(self.remotes))]
        obs, reset_infos = zip(*results, strict=True)
        self.reset_infos = [info for part in reset_infos for info in part]
        self._reset_seeds()
        self._reset_options()
        return _concatenate(obs)

    def close(self) -> None:
        """Stop every worker within ``close_timeout`` seconds, whatever it was doing."""
        if self.closed:
            return
        self.closed = True
        atexit.unregister(self._kill_at_exit)
        for remote in self.remotes:
            with contextlib.suppress(BrokenPipeError, OSError):  # unless already gone
                remote.send(("close", None))
        deadline = time.monotonic() + self.close_timeout
        for process in self.processes:
            process.join(timeout=max(0.0, deadline - time.monotonic()))
            if process.is_alive():  # stuck in its env: it ignores SIGTERM, so kill it
                process.kill()
                process.join(timeout=5.0)
        for remote in self.remotes:
            remote.close()
        if self.local is not None:
            self.local.close()

    # -- per-env access ---------------------------------------------------------
    def _call(
        self,
        name: str,
        indices: VecEnvIndices,
        args: tuple[Any, ...],
        kwargs: dict[str, Any] | None = None,
    ) -> list[Any]:
        """``group.name(*args, **kwargs, indices=...)`` on each group holding ``indices``."""
        wanted = list(self._get_indices(indices))
        pending = []
        for number, group in enumerate(self.groups):
            local_indices = [i - group.start for i in wanted if i in group]
            if not local_indices:
                continue
            group_kwargs = {**(kwargs or {}), "indices": local_indices}
            if number == 0:
                result = self._local(getattr(self.local, name), *args, **group_kwargs)
            else:
                self._send(number - 1, ("call", (name, args, group_kwargs)))
                result = _FromWorker(number - 1)
            pending.append((group.start, local_indices, result))
        by_index: dict[int, Any] = {}
        for start, local_indices, result in pending:
            values = self._receive(result.number) if isinstance(result, _FromWorker) else result
            # set_attr answers None for the whole group.
            values = [None] * len(local_indices) if values is None else values
            for local, value in zip(local_indices, values, strict=True):
                by_index[start + local] = value
        return [by_index[i] for i in wanted]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._call("get_attr", indices, (attr_name,))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._call("set_attr", indices, (attr_name, value))

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        return self._call("env_method", indices, (method_name, *method_args), method_kwargs)

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        return self._call("env_is_wrapped", indices, (wrapper_class,))

    def get_images(self) -> Sequence[np.ndarray | None]:
        images = list(self._local(self.local.get_images))
        for number in range(len(self.remotes)):
            self._send(number, ("call", ("get_images", (), {})))
        for number in range(len(self.remotes)):
            images += self._receive(number)
        return images


class _FromWorker:
    """An answer still to be read from worker ``number``."""

    def __init__(self, number: int) -> None:
        self.number = number
