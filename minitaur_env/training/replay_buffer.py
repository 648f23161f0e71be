"""Replay buffers saved as plain arrays (``.npz``), so that resuming a run runs no code,
and a buffer that also stores each transition's mirror image.

SB3's ``save_replay_buffer`` pickles the buffer object, and unpickling a file can run
code from it. A checkpoint's buffer is instead written as its arrays and its position,
and read back with ``allow_pickle=False`` into the buffer the resumed model built from
its own settings, after every array's shape and dtype have been checked against it.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer

from minitaur_env.robot import NUM_LEGS, mirror_leg_action, mirror_observation
from minitaur_env.sensors import OBSERVATION_BOUND
from minitaur_env.training import UsageError
from minitaur_env.training.files import atomic_path

FORMAT = "minitaur_env replay buffer 1"
# The arrays of SB3's ReplayBuffer (NStepReplayBuffer adds none); next_observations is
# absent with optimize_memory_usage.
ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def save_replay_buffer(buffer: Any, path: Path) -> None:
    """The buffer's arrays, position and fill state as ``path`` (an .npz), atomically."""
    arrays = {name: getattr(buffer, name) for name in ARRAYS if hasattr(buffer, name)}
    with atomic_path(path) as temp, open(temp, "wb") as out:
        np.savez(
            out,
            format=np.array(FORMAT),
            kind=np.array(type(buffer).__name__),
            pos=np.array(int(buffer.pos)),
            full=np.array(bool(buffer.full)),
            **arrays,
        )


def load_replay_buffer(buffer: Any, path: Path) -> None:
    """Fill ``buffer`` (the one the resumed model made) from ``path``; a file that does
    not match it exactly is a UsageError, and leaves the buffer as it was."""
    try:
        with np.load(path, allow_pickle=False) as saved:
            content = {name: saved[name] for name in saved.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise UsageError(f"{path}: not a readable replay buffer ({error})") from error
    if str(content.get("format", "")) != FORMAT:
        raise UsageError(f"{path}: not a replay buffer written by minitaur_env")
    if str(content.get("kind", "")) != type(buffer).__name__:
        raise UsageError(
            f"{path}: holds a {content.get('kind')}, the run uses a {type(buffer).__name__}"
        )
    arrays = {}
    for name in ARRAYS:
        mine = getattr(buffer, name, None)
        if mine is None:
            continue
        stored = content.get(name)
        if stored is None or stored.shape != mine.shape or stored.dtype != mine.dtype:
            found = "missing" if stored is None else f"{stored.dtype}{list(stored.shape)}"
            raise UsageError(
                f"{path}: {name} is {found}, the run's buffer holds {mine.dtype}{list(mine.shape)}"
            )
        arrays[name] = stored
    pos = int(content["pos"])
    if not 0 <= pos < len(buffer.observations):
        raise UsageError(f"{path}: position {pos} outside the buffer")
    for name, stored in arrays.items():
        setattr(buffer, name, stored)
    buffer.pos, buffer.full = pos, bool(content["full"])


def stacked_classic_frames(space: spaces.Space) -> int | None:
    """How many classic observations ``space`` holds side by side (1: the classic one,
    k: the last k of them, as the ``history`` env argument stacks them), or None when it
    is not made of classic observations.

    The declared bounds identify the classic observation: another 28-value observation
    would be mirrored into nonsense without a word.
    """
    size = OBSERVATION_BOUND.size
    if not isinstance(space, spaces.Box) or len(space.shape) != 1 or space.shape[0] % size:
        return None
    frames = space.shape[0] // size
    if frames < 1 or not np.array_equal(space.high, np.tile(OBSERVATION_BOUND, frames)):
        return None
    return frames


class MirroredReplayBuffer(NStepReplayBuffer):
    """Each transition stored twice: as it happened and as its left-right mirror image
    (``robot.mirror_observation`` and ``robot.mirror_leg_action``), so that an update
    learns from twice the experience an env step gives.

    The mirror image keeps the reward, termination and time limit: the classic reward
    (forward progress, energy, drift, shake) and the fall test are the same for it. The
    images are extra env columns of the buffer, so n-step returns run along them as along
    the real transitions, and each column keeps ``buffer_size`` transitions. Only the
    classic observation and the leg-model action have a mirror image here.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: Any = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_steps: int = 1,
        gamma: float = 0.99,
    ) -> None:
        frames = stacked_classic_frames(observation_space)
        if frames is None or getattr(action_space, "shape", None) != (2 * NUM_LEGS,):
            raise UsageError(
                "mirror: needs the classic 28-value observation (or a stack of them) and the "
                f"8 leg-model actions, got observations {observation_space} "
                f"and actions {action_space}"
            )
        self.frames = frames
        low, high = action_space.low, action_space.high
        if not (
            np.array_equal(mirror_leg_action(low), low)
            and np.array_equal(mirror_leg_action(high), high)
        ):
            raise UsageError(
                f"mirror: the action bounds are not left-right symmetric: {action_space}"
            )
        super().__init__(
            2 * buffer_size,
            observation_space,
            action_space,
            device,
            n_envs=2 * n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
            n_steps=n_steps,
            gamma=gamma,
        )

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        real_envs = self.n_envs // 2  # the second half of the columns are the images
        obs = obs.reshape((real_envs, *self.obs_shape))
        next_obs = next_obs.reshape((real_envs, *self.obs_shape))
        action = action.reshape((real_envs, self.action_dim))
        super().add(
            np.concatenate([obs, self._mirror(obs)]),
            np.concatenate([next_obs, self._mirror(next_obs)]),
            np.concatenate([action, mirror_leg_action(action)]),
            np.concatenate([reward, reward]),
            np.concatenate([done, done]),
            [*infos, *infos],
        )

    def _mirror(self, observation: np.ndarray) -> np.ndarray:
        frames = observation.reshape((*observation.shape[:-1], self.frames, -1))
        return mirror_observation(frames).reshape(observation.shape)
