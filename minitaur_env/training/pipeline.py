"""Overlap an off-policy algorithm's gradient steps with the env's next step.

SB3's off-policy loop alternates: step the env, then run the gradient steps, then step
again, so one of the two always waits. When the env steps in a worker process (a
``SubprocVecEnv``), the gradient steps can run while the worker computes the next
transition. The batch size, networks, gradient steps per env step and replay data are
unchanged; the one difference is that each action comes from the policy one round of
gradient steps earlier, as with any asynchronous actor. Each round of gradient steps
still samples from a buffer holding every transition collected so far.

Use :func:`overlapped` on the algorithm class and :class:`OverlappingVecEnv` in place of
``SubprocVecEnv``; with any other VecEnv the algorithm behaves as the original.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import gymnasium as gym
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from minitaur_env.training.vec_env import SubprocVecEnvIgnoringCtrlC

Algorithm = TypeVar("Algorithm", bound=type[BaseAlgorithm])


class OverlappingVecEnv(SubprocVecEnvIgnoringCtrlC):
    """A SubprocVecEnv that runs queued work after sending the actions.

    Its workers leave Ctrl-C to the caller, which saves a checkpoint and closes them.

    A subclass rather than a wrapper, so that the training env keeps the same wrapper
    chain as the eval env (SB3 syncs VecNormalize statistics layer by layer).
    """

    def __init__(self, env_fns: list[Callable[[], gym.Env]], start_method: str | None = None):
        super().__init__(env_fns, start_method)
        self._queued: Callable[[], None] | None = None

    def run_while_stepping(self, work: Callable[[], None]) -> None:
        self.flush()  # never hold more than one round
        self._queued = work

    def flush(self) -> None:
        work, self._queued = self._queued, None
        if work is not None:
            work()

    def step_wait(self) -> VecEnvStepReturn:
        self.flush()  # the workers are stepping meanwhile
        return super().step_wait()

    def reset(self) -> VecEnvObs:
        self.flush()
        return super().reset()


def _find_overlapping(env: VecEnv | None) -> OverlappingVecEnv | None:
    while env is not None:
        if isinstance(env, OverlappingVecEnv):
            return env
        env = getattr(env, "venv", None)
    return None


class _OverlappedUpdates:
    """Mixin: ``train`` is queued on the env's OverlappingVecEnv when there is one."""

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:  # SB3's default
        overlapping = _find_overlapping(self.env)  # type: ignore[attr-defined]
        train = functools.partial(
            super().train,  # type: ignore[misc]
            gradient_steps=gradient_steps,
            batch_size=batch_size,
        )
        if overlapping is None:
            train()
        else:
            overlapping.run_while_stepping(train)

    def learn(self, *args: Any, **kwargs: Any) -> Any:
        result = super().learn(*args, **kwargs)  # type: ignore[misc]
        overlapping = _find_overlapping(self.env)  # type: ignore[attr-defined]
        if overlapping is not None:
            overlapping.flush()  # the last round, so that no update is lost
        return result


@functools.cache
def overlapped(algorithm: Algorithm) -> Algorithm:
    """A subclass of an off-policy algorithm whose gradient steps overlap env steps.

    Saved models load with the original class: SB3 zips store parameters, not classes.
    """
    name = f"Overlapped{algorithm.__name__}"
    return type(name, (_OverlappedUpdates, algorithm), {"__module__": __name__})  # type: ignore[return-value]
