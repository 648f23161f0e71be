"""One sweep trial, as it runs in a Ray worker: one configuration, one seed, one run folder."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any

import yaml

from minitaur_env.training.config import ExperimentConfig
from minitaur_env.training.experiment import Experiment
from minitaur_env.training.hyperparams import RUN_KEYS
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.search_space import decode, group_name

METRIC = "eval_return"
RUNS = "runs"  # <sweep>/runs/<trial id>/ holds each trial's trial.yml and run folder
TRIAL_FILE = "trial.yml"


def _tune_reporter() -> Any:
    """An SB3 callback, run after each evaluation, that reports to Ray Tune."""
    from ray import tune
    from stable_baselines3.common.callbacks import BaseCallback

    class ReportToTune(BaseCallback):
        def _on_step(self) -> bool:
            tune.report(
                {METRIC: float(self.parent.last_mean_reward), "timesteps": self.num_timesteps}
            )
            return True

    return ReportToTune()


TRIAL_SETTINGS = (
    "base",
    "seed",
    "runs",
    "num_threads",
    "command",
    "resume_command",
    "__trial_index__",
)


def set_aside_unresumable(folder: Path, algo: str, env_id: str) -> list[Path]:
    """Move a trial's runs that have no checkpoint (a start cut off before its first one)
    to ``abandoned/<n>/``, deeper than any run glob of the sweep looks, so that the
    trial's fresh start is its only run. Returns where they went."""
    moved = []
    for unfinished in RunFolder.all(folder, algo, env_id):
        tries = itertools.count(1)
        while (aside := folder / "abandoned" / str(next(tries)) / unfinished.name).exists():
            pass
        aside.parent.mkdir(parents=True)
        unfinished.path.rename(aside)
        moved.append(aside)
    return moved


def sampled_values(trial: dict[str, Any]) -> dict[str, Any]:
    """What the search (or a grid) chose for this trial, not the sweep's own settings."""
    return {key: decode(value) for key, value in trial.items() if key not in TRIAL_SETTINGS}


def trial_config(trial: dict[str, Any]) -> ExperimentConfig:
    """The run a trial makes: the sweep's configuration with the trial's seed and sampled
    values. A trial that reserved one CPU steps its envs in its own process: ``auto``
    would spread them over every core of the machine, the other trials' included."""
    base = ExperimentConfig.from_dict(trial["base"])
    sampled = sampled_values(trial)
    seed = trial["seed"] if "seed" in trial else base.seed + int(trial.get("__trial_index__", 0))
    config = dataclasses.replace(
        base,
        seed=int(seed),
        hyperparams={**base.hyperparams, **{k: v for k, v in sampled.items() if k not in RUN_KEYS}},
        **{key: value for key, value in sampled.items() if key in RUN_KEYS},
    )
    if config.vec_env == "auto" and int(trial.get("num_threads", 1)) == 1:
        config = dataclasses.replace(config, vec_env="dummy")
    return config


def run_trial(trial: dict[str, Any], trust_pickle: bool = False) -> None:
    """Ray Tune's function trainable: one configuration, one seed, one run folder;
    ``trust_pickle``: a resumed run may unpickle its files (the sweep's --trust-pickle)."""
    from ray import tune

    import minitaur_env  # noqa: F401  (registers the ids in this worker)

    config = trial_config(trial)
    sampled = sampled_values(trial)
    folder = Path(trial["runs"]) / tune.get_context().get_trial_id()
    folder.mkdir(parents=True, exist_ok=True)
    import ray

    node = ray.get_runtime_context().get_node_id()
    record = {"group": group_name(sampled), "seed": config.seed, "sampled": sampled, "node": node}

    def write(status: str, error: str = "") -> None:
        (folder / TRIAL_FILE).write_text(
            yaml.safe_dump({**record, "status": status, "error": error}, sort_keys=False)
        )

    write("running")
    options = dict(
        verbose=0,
        progress="lines",
        num_threads=int(trial.get("num_threads", 1)),
        after_eval=[_tune_reporter()],
    )
    try:
        earlier = [
            run for run in RunFolder.all(folder, config.algo, config.env) if run.checkpoints()
        ]
        # command.txt says what made the run, as train.py's runs do: the sweep's command
        # line, and its --resume for each resumed session.
        which = f"  # trial {folder.name}, seed {config.seed}"
        if earlier:
            command = trial.get("resume_command")
            options["command"] = command + which if command else None
            experiment = Experiment.resume(earlier[-1].path, trust_pickle=trust_pickle, **options)
        else:
            set_aside_unresumable(folder, config.algo, config.env)
            options["command"] = trial["command"] + which if trial.get("command") else None
            config.validate()
            experiment = Experiment.create(config, folder, **options)
        result = experiment.run()
    except Exception as error:
        write("failed", f"{type(error).__name__}: {' '.join(str(error).split())}")
        raise
    if result.status != "completed":
        write("failed", result.message)
        raise RuntimeError(result.message)
    write("completed")
