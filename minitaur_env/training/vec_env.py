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

import itertools
import multiprocessing as mp
import os
import signal
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv
from stable_baselines3.common.vec_env.base_vec_env import (
    CloudpickleWrapper,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)


def _leave_ctrl_c_to_the_caller() -> None:
    # A terminal's Ctrl-C reaches every process of the group. A worker that died of it
    # would break the caller's pipe while the caller saves a checkpoint and closes.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _IgnoringCtrlC:
    """An env function that first makes its (worker) process ignore Ctrl-C."""

    def __init__(self, env_fn: Callable[[], gym.Env]) -> None:
        self.env_fn = env_fn

    def __call__(self) -> gym.Env:
        _leave_ctrl_c_to_the_caller()
        return self.env_fn()


class SubprocVecEnvIgnoringCtrlC(SubprocVecEnv):
    """SB3's SubprocVecEnv, with workers that leave Ctrl-C to the calling process."""

    def __init__(
        self, env_fns: list[Callable[[], gym.Env]], start_method: str | None = None
    ) -> None:
        super().__init__([_IgnoringCtrlC(fn) for fn in env_fns], start_method)


def _group_worker(
    remote: Connection, parent_remote: Connection, env_fns: CloudpickleWrapper
) -> None:
    _leave_ctrl_c_to_the_caller()
    parent_remote.close()
    group = DummyVecEnv(env_fns.var)
    try:
        while True:
            command, data = remote.recv()
            if command == "step":
                remote.send((*group.step(data), group.reset_infos))
            elif command == "reset":
                _prepare_reset(group, *data)
                remote.send((group.reset(), group.reset_infos))
            elif command == "call":
                name, args, kwargs = data
                remote.send(getattr(group, name)(*args, **kwargs))
            elif command == "close":
                group.close()
                remote.send(None)
                return
    except EOFError:  # the caller went away without closing us
        group.close()


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
    ``n_processes=1`` is a ``DummyVecEnv`` in all but name. As with ``SubprocVecEnv``,
    the env functions must be picklable and the calling script needs an
    ``if __name__ == "__main__":`` guard (workers start with forkserver or spawn).
    """

    def __init__(
        self,
        env_fns: list[Callable[[], gym.Env]],
        n_processes: int | None = None,
        start_method: str | None = None,
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

        self.remotes: list[Connection] = []
        self.processes: list[Any] = []
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
        self.local = DummyVecEnv([env_fns[i] for i in self.groups[0]])
        self.waiting = False
        self.closed = False
        super().__init__(len(env_fns), self.local.observation_space, self.local.action_space)

    # -- stepping --------------------------------------------------------------
    def step_async(self, actions: np.ndarray) -> None:
        for remote, group in zip(self.remotes, self.groups[1:], strict=True):
            remote.send(("step", actions[group.start : group.stop]))
        self._local_actions = actions[self.groups[0].start : self.groups[0].stop]
        self.waiting = True

    def step_wait(self) -> VecEnvStepReturn:
        # The local group steps while the workers step theirs.
        results = [(*self.local.step(self._local_actions), self.local.reset_infos)]
        results += [remote.recv() for remote in self.remotes]
        self.waiting = False
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
        for remote, group in zip(self.remotes, self.groups[1:], strict=True):
            remote.send(
                ("reset", (seeds[group.start : group.stop], options[group.start : group.stop]))
            )
        first = self.groups[0]
        self.local._seeds = seeds[first.start : first.stop]
        self.local._options = options[first.start : first.stop]
        results = [(self.local.reset(), self.local.reset_infos)]
        results += [remote.recv() for remote in self.remotes]
        obs, reset_infos = zip(*results, strict=True)
        self.reset_infos = [info for part in reset_infos for info in part]
        self._reset_seeds()
        self._reset_options()
        return _concatenate(obs)

    def close(self) -> None:
        if self.closed:
            return
        if self.waiting:
            for remote in self.remotes:
                remote.recv()
        for remote in self.remotes:
            remote.send(("close", None))
            remote.recv()
        for process in self.processes:
            process.join()
        for remote in self.remotes:
            remote.close()
        self.local.close()
        self.closed = True

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
                result = getattr(self.local, name)(*args, **group_kwargs)
            else:
                result = self.remotes[number - 1]
                result.send(("call", (name, args, group_kwargs)))
            pending.append((group.start, local_indices, result))
        by_index: dict[int, Any] = {}
        for start, local_indices, result in pending:
            values = result.recv() if isinstance(result, Connection) else result
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
        images = list(self.local.get_images())
        for remote in self.remotes:
            remote.send(("call", ("get_images", (), {})))
        for remote in self.remotes:
            images += remote.recv()
        return images
