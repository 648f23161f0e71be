"""Vectorized env factories for training and evaluation, from a gymnasium id."""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import (
    DummyVecEnv,
    VecCheckNan,
    VecEnv,
    VecNormalize,
)

from minitaur_env.training import VEC_ENVS, TrainingDiverged, UsageError
from minitaur_env.training.single_env import make_env, qualified_env_id
from minitaur_env.training.vec_env import GroupedSubprocVecEnv, available_cores

__all__ = [
    "NanGuard",
    "RewardPerTime",
    "make_env",
    "make_eval_env",
    "make_training_env",
    "qualified_env_id",
]

VEC_ENV_CLASSES = {"dummy": DummyVecEnv, "grouped": GroupedSubprocVecEnv}


class NanGuard(VecCheckNan):
    """SB3's VecCheckNan, raising TrainingDiverged so that callers can tell it by type."""

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv, raise_exception=True)

    def _check_val(self, event: str, **kwargs: Any) -> None:
        try:
            super()._check_val(event, **kwargs)
        except ValueError as error:
            raise TrainingDiverged(" ".join(str(error).split())) from None


class RewardPerTime(gym.Wrapper):
    """Scales each step's reward by ``time_step`` over the episode's control step (the
    env's ``dt``, drawn at reset under a randomized step); outside the Monitor, which
    keeps the env's own returns."""

    def __init__(self, env: gym.Env, time_step: float) -> None:
        super().__init__(env)
        self.time_step = time_step

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        scale = self.time_step / float(self.env.unwrapped.dt)
        return obs, float(reward) * scale, terminated, truncated, info


def resolve_vec_env(vec_env: str, n_envs: int) -> str:
    """``auto``: grouped over the cores for several envs, else one env in this process."""
    if vec_env == "auto":
        return "grouped" if n_envs > 1 and available_cores() > 1 else "dummy"
    return vec_env


def make_training_env(
    env_id: str,
    n_envs: int = 1,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    vec_env: str = "auto",
    monitor_dir: str | None = None,
    append_monitor: bool = False,
    reward_time_step: float | None = None,
) -> VecEnv:
    """Monitored, vectorized env that raises TrainingDiverged as soon as a NaN reaches it
    or leaves it; with ``reward_time_step`` the learner's rewards are scaled to that
    control step (:class:`RewardPerTime`), after the monitor.

    ``vec_env="auto"`` runs several envs grouped over the CPU cores (the same
    transitions as a DummyVecEnv, faster) and a single env in this process.
    """
    if vec_env not in VEC_ENVS:
        raise UsageError(f"--vec-env must be one of {', '.join(VEC_ENVS)}, got {vec_env!r}")
    vec_env = resolve_vec_env(vec_env, n_envs)
    if n_envs < 1:
        raise UsageError(f"--n-envs must be >= 1, got {n_envs}")
    make_env(env_id, env_kwargs).close()  # bad kwargs fail here, not inside a worker
    env = make_vec_env(
        qualified_env_id(env_id),
        n_envs=n_envs,
        seed=seed,
        env_kwargs=env_kwargs or {},
        monitor_dir=monitor_dir,
        monitor_kwargs={"override_existing": not append_monitor},
        vec_env_cls=VEC_ENV_CLASSES[vec_env],
        wrapper_class=RewardPerTime if reward_time_step else None,
        wrapper_kwargs={"time_step": reward_time_step} if reward_time_step else None,
    )
    return NanGuard(env)


def make_eval_env(
    env_id: str,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    normalize: bool | dict[str, Any] = False,
    render_mode: str | None = None,
) -> VecEnv:
    """One monitored env; with ``normalize`` a frozen VecNormalize that reports raw rewards.

    ``normalize`` may be the training VecNormalize's options (``norm_obs`` ...), so that
    observations are treated exactly as in training.
    """
    kwargs = dict(env_kwargs or {})
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    make_env(env_id, kwargs).close()
    env = make_vec_env(qualified_env_id(env_id), n_envs=1, seed=seed, env_kwargs=kwargs)
    # The same wrapper stack as training, which SB3's normalization sync walks in step.
    env = NanGuard(env)
    if normalize:
        options = dict(normalize) if isinstance(normalize, dict) else {}
        options.update(training=False, norm_reward=False)
        env = VecNormalize(env, **options)
    return env
