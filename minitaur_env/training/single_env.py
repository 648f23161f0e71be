"""One gymnasium env from an id, for evaluation and video; needs neither torch nor SB3."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

import minitaur_env  # noqa: F401  (registers the Minitaur ids)
from minitaur_env.sim import GuiUnavailable
from minitaur_env.training import UsageError


def qualified_env_id(env_id: str) -> str:
    """The id, checked, with a ``module:`` prefix where a fresh process needs the import.

    SubprocVecEnv workers start from a clean interpreter, where only a prefixed id
    such as ``minitaur_env:MinitaurBulletEnv-v0`` is known to gymnasium.
    """
    try:
        spec = gym.spec(env_id)
    except gym.error.Error as error:
        raise UsageError(f"unknown env id {env_id!r}: {error}") from error
    entry_point = spec.entry_point
    if ":" not in env_id and isinstance(entry_point, str):
        module = entry_point.split(":")[0].split(".")[0]
        if module == "minitaur_env":
            return f"{module}:{env_id}"
    return env_id


def make_env(env_id: str, env_kwargs: dict[str, Any] | None = None, **extra: Any) -> gym.Env:
    """A single gymnasium env (with its registered time limit)."""
    qualified = qualified_env_id(env_id)
    try:
        return gym.make(qualified, **{**(env_kwargs or {}), **extra})
    except (TypeError, ValueError, GuiUnavailable) as error:
        raise UsageError(f"cannot make {env_id} with {env_kwargs or {}}: {error}") from error
