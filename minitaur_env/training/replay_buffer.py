"""A replay buffer saved as plain arrays (``.npz``), so that resuming a run runs no code.

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
