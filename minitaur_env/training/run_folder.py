"""A run folder (``logs/<algo>/<env>_<N>/``): the one place that knows its file names."""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from minitaur_env.training import UsageError, env_name
from minitaur_env.training.files import (
    atomic_path,
    ensure_writable,
    read_lines,
    read_yaml,
    write_text,
    write_yaml,
)

CONFIG_FILE = "config.yml"
PROVENANCE_FILE = "provenance.yml"
ONNX_POLICY = "policy.onnx"  # the deterministic actor, in shipped and Hub folders
# A member of our model zips: the VecNormalize statistics the model was saved with (JSON).
EMBEDDED_STATISTICS = "minitaur_env_vecnormalize.json"
# A member of best_model.zip: the evaluation that made it the best (steps, mean return).
# It travels in the zip so that the model and its score are replaced as one file.
EMBEDDED_EVALUATION = "minitaur_env_evaluation.json"
# A member of SBX model zips: the flax train states and PRNG keys as msgpack (plain
# arrays), which SBX itself only pickles; the safe loader restores them from here.
EMBEDDED_JAX_STATE = "minitaur_env_jax_state.msgpack"
HUB_VECNORMALIZE = "vec_normalize.pkl"  # a Hub model folder's name (the zoo's push_to_hub)
CHECKPOINT_PREFIX = "rl_model"  # SB3 CheckpointCallback's names: rl_model_<N>_steps.zip
_CHECKPOINT = re.compile(rf"^{CHECKPOINT_PREFIX}_(\d+)_steps\.zip$")
# .npz: plain arrays (replay_buffer.py); .pkl: SB3's pickle, written before 0.3.
_REPLAY_BUFFER = re.compile(rf"^{CHECKPOINT_PREFIX}_replay_buffer_(\d+)_steps\.(npz|pkl)$")


@dataclasses.dataclass
class MonitorEpisode:
    monitor: Path
    line: int  # index in the file
    session: int  # 0, then one more after each resume
    time: float  # the Monitor's clock, restarted by each session
    training_time: float  # seconds of training, across sessions
    length: int


class RunFolder:
    """Every path of one training run, computed here and nowhere else.

    ::

        config.yml, command.txt        resolved configuration, command line(s)
        evaluations.npz                EvalCallback: timesteps, results, ep_lengths
        best_model.zip                 (+ best_model_vecnormalize.pkl)
        <env>.zip                      the final model (rl-baselines3-zoo's name)
        <env>/                         the zoo's files: config.yml, args.yml, env_kwargs.yml,
                                       vecnormalize.pkl (the final model's, or the best's
                                       until the run ends)
        checkpoints/                   rl_model_<N>_steps.zip, replay buffers, VecNormalize
        monitor/<i>.monitor.csv        per-episode return/length of each training env
        progress.csv                   SB3 logger (progress-resumed-at-<N>.csv after a resume)
        learning_curve.png, videos/
        provenance.yml                 shipped agents only (pretrained/<algo>/<env>_1/)
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    def __str__(self) -> str:
        return str(self.path)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, RunFolder) and other.path == self.path

    def __hash__(self) -> int:
        return hash(self.path)

    # -- creating and finding runs ---------------------------------------------
    @classmethod
    def create(cls, log_folder: str | Path, algo: str, env_id: str) -> RunFolder:
        """The next free ``<log_folder>/<algo>/<env>_<N>`` (N from 1), created now."""
        parent = Path(log_folder) / algo
        ensure_writable(parent)
        existing = cls.all(log_folder, algo, env_id)
        number = existing[-1].number + 1 if existing else 1
        while True:
            path = parent / f"{env_name(env_id)}_{number}"
            try:
                path.mkdir()
                return cls(path)
            except FileExistsError:  # another run took this number meanwhile
                number += 1

    @classmethod
    def existing(cls, path: str | Path) -> RunFolder:
        """A run folder that holds a config.yml, or a UsageError saying what is wrong."""
        run = cls(path)
        if not run.config.is_file():
            raise UsageError(f"{run.path}: no config.yml there; is it a run folder?")
        return run

    @classmethod
    def all(cls, log_folder: str | Path, algo: str, env_id: str) -> list[RunFolder]:
        """Existing runs of ``algo`` on ``env_id``, lowest N first."""
        parent = Path(log_folder) / algo
        pattern = re.compile(rf"^{re.escape(env_name(env_id))}_(\d+)$")
        runs = []
        if parent.is_dir():
            for child in parent.iterdir():
                match = pattern.match(child.name)
                if match and child.is_dir():
                    runs.append((int(match.group(1)), cls(child)))
        return [run for _, run in sorted(runs, key=lambda item: item[0])]

    @classmethod
    def of_model(cls, model: Path) -> RunFolder:
        """The run folder a model zip belongs to: its own, or its checkpoint's run."""
        model = Path(model)
        return cls(model.parents[1] if model.parent.name == "checkpoints" else model.parent)

    @staticmethod
    def is_run(path: str | Path) -> bool:
        return (Path(path) / CONFIG_FILE).is_file()

    @classmethod
    def found_under(cls, folder: str | Path, pattern: str = "*/*") -> list[RunFolder]:
        """The run folders at ``folder/<pattern>``, in name order."""
        return [
            cls(config.parent) for config in sorted(Path(folder).glob(f"{pattern}/{CONFIG_FILE}"))
        ]

    @property
    def number(self) -> int:
        return int(self.path.name.rsplit("_", 1)[1])

    @property
    def name(self) -> str:
        """``<algo>-<env>_<N>``: a name for files that leave the folder (videos, TensorBoard)."""
        return f"{self.path.parent.name}-{self.path.name}"

    # -- files ----------------------------------------------------------------
    @property
    def config(self) -> Path:
        return self.path / CONFIG_FILE

    @property
    def command(self) -> Path:
        return self.path / "command.txt"

    @property
    def evaluations(self) -> Path:
        return self.path / "evaluations.npz"

    @property
    def best_model(self) -> Path:
        return self.path / "best_model.zip"

    @property
    def env_name(self) -> str:
        """The env id's name, read from config.yml so that a renamed copy (``seed0/``) still
        finds its files; from the folder's name before the config is written."""
        if self.config.is_file():
            env = self.read_config().get("env")
            if isinstance(env, str):
                return env_name(env)
        return self.path.name.rsplit("_", 1)[0]

    @property
    def zoo_model(self) -> Path:
        """``<env>.zip``: where the final model is saved, under the zoo's name for it."""
        return self.path / f"{self.env_name}.zip"

    @classmethod
    def model_of(cls, run_or_model: str | Path) -> Path:
        """What a command given a run folder or a model zip plays: the zip as given, or the
        run folder's final model. One meaning everywhere (package, onnx): a run folder
        stands for the model it ended with; its best model is ``best_model.zip``."""
        path = Path(run_or_model)
        if not path.is_dir():
            return path
        run = cls.existing(path)
        if not run.final_model.is_file():
            raise UsageError(
                f"{path} has no final model ({run.final_model.name}) yet: pass its "
                f"{run.best_model.name} or a checkpoint instead"
            )
        return run.final_model

    @property
    def final_model(self) -> Path:
        """``<env>.zip``, the model the run ended with (the zoo's name for it)."""
        return self.zoo_model

    @property
    def zoo_dir(self) -> Path:
        """``<env>/``: where rl-baselines3-zoo's enjoy and record_video look for settings."""
        return self.path / self.env_name

    @property
    def zoo_vecnormalize(self) -> Path:
        return self.zoo_dir / "vecnormalize.pkl"

    @property
    def monitor_dir(self) -> Path:
        return self.path / "monitor"

    @property
    def provenance(self) -> Path:
        """How a shipped agent was trained and judged (only in ``pretrained/`` folders)."""
        return self.path / PROVENANCE_FILE

    @property
    def onnx_policy(self) -> Path:
        """The deterministic actor as ONNX (python -m minitaur_env.onnx), where shipped."""
        return self.path / ONNX_POLICY

    def final_model_report(self, live_actor: bool = False) -> Path:
        """benchmarks/minitaur_table.py's judgement of the final model (or its live actor)."""
        suffix = "_live_actor" if live_actor else ""
        return self.path / f"final_model_report{suffix}.json"

    @property
    def learning_curve(self) -> Path:
        return self.path / "learning_curve.png"

    @property
    def videos_dir(self) -> Path:
        return self.path / "videos"

    @property
    def lock_file(self) -> Path:
        """Held by the process that trains the run (``files.exclusive``)."""
        return self.path / ".lock"

    @property
    def failure_log(self) -> Path:
        """The traceback of the exception that stopped the run last (its one line is printed)."""
        return self.path / "failure.txt"

    @property
    def staging_dir(self) -> Path:
        """Where files SB3 writes in place are written before they replace the run's."""
        return self.path / ".staging"

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / "checkpoints"

    def progress(self, resumed_at: int | None = None) -> Path:
        """SB3's CSV log; each resumed session writes its own."""
        if resumed_at is None:
            return self.path / "progress.csv"
        return self.path / f"progress-resumed-at-{resumed_at}.csv"

    def checkpoint(self, steps: int) -> Path:
        return self.checkpoint_dir / f"{CHECKPOINT_PREFIX}_{steps}_steps.zip"

    def replay_buffer(self, steps: int) -> Path:
        return self.checkpoint_dir / f"{CHECKPOINT_PREFIX}_replay_buffer_{steps}_steps.npz"

    def pickled_replay_buffer(self, steps: int) -> Path:
        """Where versions before 0.3 saved the buffer, as SB3's pickle."""
        return self.replay_buffer(steps).with_suffix(".pkl")

    def vecnormalize(self, steps: int) -> Path:
        return self.checkpoint_dir / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl"

    @staticmethod
    def replay_buffer_beside(model: Path) -> Path:
        """The replay buffer the zoo saves beside a model (``train.py -i`` starts from it):
        SB3's pickle; ``.with_suffix(".npz")``, the same as plain arrays."""
        return model.with_name("replay_buffer.pkl")

    @staticmethod
    def vecnormalize_beside(model: Path) -> Path:
        """Where the VecNormalize statistics of a best model zip are kept."""
        return model.with_name(f"{model.stem}_vecnormalize.pkl")

    def vecnormalize_for(self, model: Path) -> Path | None:
        """The VecNormalize statistics saved with ``model`` (a zip of this run), if any: the
        pickle's path, whether the pickle or only its JSON sibling is there."""
        candidates = [self.vecnormalize_beside(model), model.parent / HUB_VECNORMALIZE]
        if model == self.zoo_model:
            candidates.insert(0, self.zoo_vecnormalize)
        match = _CHECKPOINT.match(model.name)
        if match and model.parent == self.checkpoint_dir:
            candidates.append(self.vecnormalize(int(match.group(1))))
        return next(
            (path for path in candidates if path.is_file() or normalizer_json(path).is_file()),
            None,
        )

    def checkpoints(self) -> list[tuple[int, Path]]:
        """(steps, model zip) of every checkpoint, newest first."""
        return self._numbered(_CHECKPOINT)

    def replay_buffers(self) -> list[tuple[int, Path]]:
        """(steps, replay buffer) of every saved buffer, newest first."""
        return self._numbered(_REPLAY_BUFFER)

    def _numbered(self, pattern: re.Pattern[str]) -> list[tuple[int, Path]]:
        found = []
        if self.checkpoint_dir.is_dir():
            for path in self.checkpoint_dir.iterdir():
                match = pattern.match(path.name)
                if match:
                    found.append((int(match.group(1)), path))
        return sorted(found, reverse=True)

    def prune_replay_buffers(self, keep: int = 2) -> None:
        """Delete all but the ``keep`` newest replay buffers (each can be hundreds of MB).

        Two are kept so that a resume still finds the buffer matching the previous
        checkpoint when a kill tore the newest one.
        """
        for _, path in self.replay_buffers()[keep:]:
            path.unlink(missing_ok=True)

    # -- contents ---------------------------------------------------------------
    def read_config(self) -> dict[str, Any]:
        config = read_yaml(self.config, "run configuration")
        if not isinstance(config, dict):
            raise UsageError(f"{self.config} does not hold a run configuration")
        return config

    def settings(self) -> dict[str, Any]:
        """The run's configuration, or ``{}`` where the folder has none (a bare model)."""
        return self.read_config() if self.config.is_file() else {}

    def write_config(self, config: dict[str, Any]) -> None:
        """config.yml, and the same settings in the zoo's files under ``<env>/``."""
        write_yaml(self.config, config, sort_keys=False)
        self.zoo_dir.mkdir(exist_ok=True)
        write_yaml(self.zoo_dir / "config.yml", zoo_hyperparams(config))
        zoo_args = (
            "algo",
            "env",
            "seed",
            "n_timesteps",
            "eval_freq",
            "eval_episodes",
            "save_freq",
            "env_kwargs",
            "device",
        )
        write_yaml(self.zoo_dir / "args.yml", {key: config[key] for key in zoo_args})
        write_yaml(self.zoo_dir / "env_kwargs.yml", config["env_kwargs"] or {})

    def rewind_logs(self, steps: int, log: Any = print) -> None:
        """Forget evaluations and training episodes logged after env step ``steps``.

        A resume restarts from a checkpoint, so what the killed session logged after it
        belongs to a branch that no longer exists; kept, it would repeat steps, evaluations
        and progress rows. An episode still running at the checkpoint is dropped too, and so is
        what a kill tore: an unreadable evaluations.npz, a monitor's partial last line
        (each with a line saying so). Every rewrite replaces its file atomically.
        """
        if self.evaluations.exists():
            try:
                with np.load(self.evaluations) as data:
                    logged = dict(data)
            except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
                torn = self.evaluations.with_suffix(".npz.unreadable")
                os.replace(self.evaluations, torn)
                log(
                    f"{self.evaluations.name} was unreadable ({error}); moved to {torn.name}, "
                    "the evaluations start again from this session"
                )
            else:
                kept = logged["timesteps"] <= steps
                if not kept.all():
                    with atomic_path(self.evaluations) as temp:
                        np.savez(temp, **{key: value[kept] for key, value in logged.items()})
        for progress in sorted(self.path.glob("progress*.csv")):
            self._rewind_progress(progress, steps)
        for monitor in sorted(self.monitor_dir.glob("*.monitor.csv")):
            lines = read_lines(monitor)
            if lines and not lines[-1].endswith("\n"):
                write_text(monitor, "".join(lines[:-1]))
                log(f"{monitor.name}: dropped a partial last line ({lines[-1]!r})")
                lines = lines[:-1]
            malformed = [i for i, line in enumerate(lines[2:], start=2) if _episode(line) is None]
            if malformed:
                write_text(monitor, "".join(t for i, t in enumerate(lines) if i not in malformed))
                log(
                    f"{monitor.name}: dropped {len(malformed)} malformed line(s), the first "
                    f"at line {malformed[0] + 1} ({lines[malformed[0]].strip()!r})"
                )
        episodes = self.monitor_episodes()
        episodes.sort(key=lambda episode: (episode.session, episode.time))
        done, dropped = 0, {}
        for episode in episodes:
            done += episode.length
            if done > steps:
                dropped.setdefault(episode.monitor, set()).add(episode.line)
        for monitor, lines in dropped.items():
            kept = [text for i, text in enumerate(read_lines(monitor)) if i not in lines]
            write_text(monitor, "".join(kept))

    @staticmethod
    def _rewind_progress(progress: Path, steps: int) -> None:
        """Drop SB3's CSV rows logged after ``steps`` (and a row a kill tore)."""
        lines = read_lines(progress)
        if not lines:
            return
        header = next(csv.reader(lines[:1]))
        if "time/total_timesteps" not in header:
            return
        column = header.index("time/total_timesteps")
        kept = [lines[0]]
        for line in lines[1:]:
            row = next(csv.reader([line]), [])
            if line.endswith("\n") and len(row) == len(header):
                try:
                    logged_at = float(row[column] or 0)
                except ValueError:
                    continue
                if logged_at <= steps:
                    kept.append(line)
        if len(kept) < len(lines):
            write_text(progress, "".join(kept))

    def monitor_episodes(self) -> list[MonitorEpisode]:
        """Every finished training episode of the monitor files, with its session.

        SB3's Monitor restarts its clock at 0 in each resumed session: a clock that goes
        back starts a new session, and ``training_time`` continues from where the previous
        session's last episode ended, so time spent stopped is not counted.
        """
        episodes = []
        for monitor in sorted(self.monitor_dir.glob("*.monitor.csv")):
            session, offset, previous = 0, 0.0, 0.0
            lines = read_lines(monitor)
            for index, line in enumerate(lines[2:], start=2):  # a JSON header, then r,l,t
                parsed = _episode(line)
                if parsed is None:  # torn; a resume drops it and says so
                    continue
                length, time = parsed
                if time < previous:
                    session, offset = session + 1, offset + previous
                previous = time
                episodes.append(
                    MonitorEpisode(monitor, index, session, time, offset + time, length)
                )
        return episodes

    def append_command(self, command: str) -> None:
        with self.command.open("a") as handle:
            handle.write(command + "\n")


def _episode(line: str) -> tuple[int, float] | None:
    """(length, time) of a monitor line ``r,l,t[,...]``, or None where it is not one."""
    fields = line.strip().split(",")
    try:
        float(fields[0])
        length, time = int(fields[1]), float(fields[2])
    except (IndexError, ValueError):
        return None
    return (length, time) if length > 0 and math.isfinite(time) and time >= 0 else None


def zoo_hyperparams(config: dict[str, Any]) -> dict[str, Any]:
    """A run's config.yml as the zoo's ``<env>/config.yml`` holds it: one flat entry."""
    return {
        **config.get("hyperparams", {}),
        **{
            key: config[key]
            for key in ("policy", "n_timesteps", "n_envs", "normalize")
            if key in config
        },
    }


def normalizer_json(pickle_path: Path) -> Path:
    """The pickle-free sibling of VecNormalize statistics: ``vecnormalize.pkl`` ->
    ``vecnormalize.json``, read by default (``safe_load``); the pickle is for the zoo and
    ``--resume``."""
    return pickle_path.with_suffix(".json")
