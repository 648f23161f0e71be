"""Run folders (``logs/<algo>/<env>_<N>/``) and their checkpoints."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import unwrap_vec_normalize

from minitaur_env.training import UsageError

CHECKPOINT_DIR = "checkpoints"
CHECKPOINT_PREFIX = "rl_model"  # CheckpointCallback's file names: rl_model_<N>_steps.zip
_CHECKPOINT = re.compile(rf"^{CHECKPOINT_PREFIX}_(\d+)_steps\.zip$")


def env_folder_name(env_id: str) -> str:
    return env_id.split(":")[-1]


def run_dirs(log_folder: str | Path, algo: str, env_id: str) -> list[Path]:
    """Existing runs of ``algo`` on ``env_id``, oldest (lowest N) first."""
    parent = Path(log_folder) / algo
    pattern = re.compile(rf"^{re.escape(env_folder_name(env_id))}_(\d+)$")
    runs = []
    if parent.is_dir():
        for child in parent.iterdir():
            match = pattern.match(child.name)
            if match and child.is_dir():
                runs.append((int(match.group(1)), child))
    return [path for _, path in sorted(runs)]


def ensure_writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        # A uniquely named probe: runs started together must not delete each other's.
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as error:
        raise UsageError(f"cannot write to {folder}: {error.strerror or error}") from error


def new_run_dir(log_folder: str | Path, algo: str, env_id: str) -> Path:
    """Create the next ``<log_folder>/<algo>/<env>_<N>`` folder (N starts at 1)."""
    parent = Path(log_folder) / algo
    ensure_writable(parent)
    existing = run_dirs(log_folder, algo, env_id)
    number = int(existing[-1].name.rsplit("_", 1)[1]) + 1 if existing else 1
    while True:
        run_dir = parent / f"{env_folder_name(env_id)}_{number}"
        try:
            run_dir.mkdir()
            return run_dir
        except FileExistsError:  # another run took this number meanwhile
            number += 1


def checkpoints(run_dir: str | Path) -> list[tuple[int, Path]]:
    """(steps, model zip) of every checkpoint of a run, newest first."""
    folder = Path(run_dir) / CHECKPOINT_DIR
    found = []
    if folder.is_dir():
        for path in folder.iterdir():
            match = _CHECKPOINT.match(path.name)
            if match:
                found.append((int(match.group(1)), path))
    return sorted(found, reverse=True)


def replay_buffer_path(run_dir: str | Path, steps: int) -> Path:
    return Path(run_dir) / CHECKPOINT_DIR / f"{CHECKPOINT_PREFIX}_replay_buffer_{steps}_steps.pkl"


def vecnormalize_path(run_dir: str | Path, steps: int) -> Path:
    return Path(run_dir) / CHECKPOINT_DIR / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl"


def save_checkpoint(model: BaseAlgorithm, run_dir: str | Path, steps: int) -> Path:
    """Save model, replay buffer and normalization under CheckpointCallback's names."""
    folder = Path(run_dir) / CHECKPOINT_DIR
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{CHECKPOINT_PREFIX}_{steps}_steps.zip"
    model.save(path)
    if isinstance(model, OffPolicyAlgorithm) and model.replay_buffer is not None:
        model.save_replay_buffer(replay_buffer_path(run_dir, steps))
    normalizer = unwrap_vec_normalize(model.get_env())
    if normalizer is not None:
        normalizer.save(str(vecnormalize_path(run_dir, steps)))
    return path
