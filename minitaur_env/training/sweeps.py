"""Many runs on Ray Tune: one configuration over seeds, or a hyperparameter search.

Every trial calls the same :class:`~minitaur_env.training.experiment.Experiment` as
train.py and writes a normal run folder, so evaluate.py and the summary read trials as
they read any run. The layout under ``<storage>/<name>/``::

    runs/<trial id>/trial.yml                what the trial trains, its status, its error
    runs/<trial id>/<algo>/<env>_1/          the run folder
    summary.csv, curves.png                  one row and one IQM curve per configuration
    (the rest)                               Ray Tune's own experiment state

A trial that is restarted (``--resume`` after Ctrl-C, or a node lost) continues its run
folder from its newest checkpoint. Ray Tune is installed with ``pip install
'minitaur-env[ray]'``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from minitaur_env.training import UsageError
from minitaur_env.training.experiment import Experiment, ExperimentConfig
from minitaur_env.training.hyperparams import RUN_KEYS
from minitaur_env.training.run_folder import RunFolder

METRIC = "eval_return"
SEARCH_KINDS = ("uniform", "loguniform", "choice", "int")
RUNS = "runs"
TRIAL_FILE = "trial.yml"


# -- the search space -----------------------------------------------------------------
def load_search_space(path: str | Path) -> dict[str, Any]:
    """A YAML search space as Ray Tune domains.

    ::

        learning_rate: {loguniform: [1.0e-4, 1.0e-3]}
        gamma: {uniform: [0.98, 0.999]}
        batch_size: {choice: [128, 256, 512]}
        gradient_steps: {int: [1, 8]}             # both ends included
        policy_kwargs: {choice: ["{net_arch: [256, 256]}", "{net_arch: [400, 300]}"]}

    Choices must be numbers, booleans or strings (Optuna's rule); a string that holds a
    YAML mapping or list is read as one when the trial starts.
    """
    from ray import tune

    try:
        table = yaml.safe_load(Path(path).read_text())
    except OSError as error:
        raise UsageError(f"cannot read search space {path}: {error.strerror}") from error
    except yaml.YAMLError as error:
        raise UsageError(f"search space {path} is not valid YAML: {error}") from error
    if not isinstance(table, dict) or not table:
        raise UsageError(f"search space {path} must map hyperparameter names to ranges")
    space = {}
    for name, spec in table.items():
        if not (isinstance(spec, dict) and len(spec) == 1 and next(iter(spec)) in SEARCH_KINDS):
            raise UsageError(
                f"search space {path}: {name} must be one of "
                + ", ".join(f"{{{kind}: ...}}" for kind in SEARCH_KINDS)
                + f", got {spec!r}"
            )
        kind, values = next(iter(spec.items()))
        if kind == "choice":
            if not isinstance(values, list) or not values:
                raise UsageError(f"search space {path}: {name} choice needs a non-empty list")
            bad = [v for v in values if not isinstance(v, (bool, int, float, str))]
            if bad:
                raise UsageError(
                    f"search space {path}: {name} choices must be numbers, booleans or "
                    f"strings (write {bad[0]!r} as a YAML string)"
                )
            space[name] = tune.choice(values)
            continue
        if not (isinstance(values, list) and len(values) == 2 and values[0] < values[1]):
            raise UsageError(f"search space {path}: {name} {kind} needs [low, high], low < high")
        low, high = values
        if kind == "uniform":
            space[name] = tune.uniform(float(low), float(high))
        elif kind == "loguniform":
            if low <= 0:
                raise UsageError(f"search space {path}: {name} loguniform needs low > 0")
            space[name] = tune.loguniform(float(low), float(high))
        else:
            space[name] = tune.randint(int(low), int(high) + 1)
    return space


def _decode(value: Any) -> Any:
    if isinstance(value, str) and value.strip()[:1] in ("{", "["):
        return yaml.safe_load(value)
    return value


def group_name(sampled: dict[str, Any]) -> str:
    """A readable name for a configuration: its sampled values, or ``default``."""
    if not sampled:
        return "default"

    def text(value: Any) -> str:
        return f"{value:.3g}" if isinstance(value, float) else str(value).replace(" ", "")

    return ",".join(f"{key}={text(value)}" for key, value in sorted(sampled.items()))


# -- one trial (runs in a Ray worker) ---------------------------------------------------
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


def _evaluation_lines(total_steps: int) -> Any:
    """A Tune callback printing one line per trial evaluation, as train.py does off a tty."""
    from ray import tune

    from minitaur_env.training.progress import format_duration

    class EvaluationLines(tune.Callback):
        def on_trial_result(self, iteration, trials, trial, result, **info) -> None:
            seed = trial.config.get("seed")
            print(
                f"trial {trial.trial_id}{'' if seed is None else f' (seed {seed})'}  "
                f"step {result['timesteps']:,}/{total_steps:,}  eval {result[METRIC]:.2f}  "
                f"elapsed {format_duration(result.get('time_total_s', 0.0))}",
                flush=True,
            )

    return EvaluationLines()


TRIAL_SETTINGS = ("base", "seed", "runs", "num_threads", "command", "resume_command",
                  "__trial_index__")  # fmt: skip


def run_trial(trial: dict[str, Any]) -> None:
    """Ray Tune's function trainable: one configuration, one seed, one run folder."""
    from ray import tune

    import minitaur_env  # noqa: F401  (registers the ids in this worker)

    base = ExperimentConfig.from_dict(trial["base"])
    sampled = {key: _decode(value) for key, value in trial.items() if key not in TRIAL_SETTINGS}
    seed = trial["seed"] if "seed" in trial else base.seed + int(trial.get("__trial_index__", 0))
    config = dataclasses.replace(
        base,
        seed=int(seed),
        hyperparams={**base.hyperparams, **{k: v for k, v in sampled.items() if k not in RUN_KEYS}},
        **{key: value for key, value in sampled.items() if key in RUN_KEYS},
    )
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
            experiment = Experiment.resume(earlier[-1].path, **options)
        else:
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


# -- the sweep -------------------------------------------------------------------------
@dataclasses.dataclass
class Sweep:
    """A sweep's settings; ``run()`` launches or resumes it and writes its summary."""

    base: ExperimentConfig
    storage: str = "sweeps"
    name: str = "sweep"
    seeds: list[int] = dataclasses.field(default_factory=lambda: [0])
    search: dict[str, Any] | None = None
    trials: int = 8
    scheduler: str = "none"
    cpus_per_trial: float = 1.0
    gpus_per_trial: float = 0.0
    max_concurrent: int = 0
    address: str | None = None
    command: str = ""  # how the sweep was launched: each trial's command.txt records it

    @property
    def folder(self) -> Path:
        return Path(self.storage) / self.name

    def validate(self) -> None:
        if self.scheduler not in ("none", "asha"):
            raise UsageError(f"--scheduler must be asha or none, got {self.scheduler!r}")
        if self.scheduler == "asha" and not self.base.eval_freq:
            raise UsageError("--scheduler asha stops trials on their evaluations: set --eval-freq")
        if self.search is not None and len(self.seeds) > 1 and self.scheduler == "asha":
            raise UsageError(
                "--scheduler asha with --seeds > 1 in a --search would stop some seeds of a "
                "configuration early and bias its average; use one or the other"
            )
        if self.cpus_per_trial <= 0 or self.gpus_per_trial < 0 or self.trials < 1:
            raise UsageError("--cpus-per-trial must be > 0, --gpus-per-trial >= 0, --trials >= 1")

    def _tuner(self, resume: bool) -> Any:
        from ray import tune
        from ray.tune.schedulers import ASHAScheduler
        from ray.tune.search import Repeater
        from ray.tune.search.optuna import OptunaSearch

        trainable = tune.with_resources(
            run_trial, {"cpu": self.cpus_per_trial, "gpu": self.gpus_per_trial}
        )
        path = str(self.folder.resolve())
        if resume:
            if not tune.Tuner.can_restore(path):
                raise UsageError(f"--resume: no Ray Tune sweep to resume in {self.folder}")
            return tune.Tuner.restore(path, trainable, resume_unfinished=True)
        space: dict[str, Any] = {
            "base": self.base.to_dict(),
            "runs": str((self.folder / RUNS).resolve()),
            "num_threads": max(1, math.floor(self.cpus_per_trial)),
            "command": self.command,
            "resume_command": f"python -m minitaur_env.sweep -f {self.storage} "
            f"--name {self.name} --resume",
        }
        search_alg, samples = None, 1
        if self.search is None:
            space["seed"] = tune.grid_search(self.seeds)
        else:
            space.update(self.search)
            search_alg = OptunaSearch(seed=self.base.seed)
            if len(self.seeds) > 1:  # each sampled configuration over the seeds, averaged
                search_alg = Repeater(search_alg, repeat=len(self.seeds))
            samples = self.trials * len(self.seeds)
        scheduler = None
        if self.scheduler == "asha":
            scheduler = ASHAScheduler(
                time_attr="timesteps",
                max_t=self.base.n_timesteps,
                grace_period=max(self.base.eval_freq, self.base.n_timesteps // 9),
                reduction_factor=3,
            )
        return tune.Tuner(
            trainable,
            param_space=space,
            tune_config=tune.TuneConfig(
                metric=METRIC,
                mode="max",
                search_alg=search_alg,
                scheduler=scheduler,
                num_samples=samples,
                max_concurrent_trials=self.max_concurrent or None,
            ),
            run_config=tune.RunConfig(
                name=self.name,
                storage_path=str(Path(self.storage).resolve()),
                failure_config=tune.FailureConfig(max_failures=0),
                verbose=0,
                callbacks=[_evaluation_lines(self.base.n_timesteps)],
            ),
        )

    def unfinished(self) -> list[Path]:
        """The trial folders whose run was cut short (Ctrl-C, a lost node)."""
        return [
            path.parent
            for path in sorted((self.folder / RUNS).glob(f"*/{TRIAL_FILE}"))
            if yaml.safe_load(path.read_text())["status"] == "running"
        ]

    def run(self, resume: bool = False) -> list[str]:
        """Launch (or resume) the trials; return one line per failed trial."""
        import ray

        self.validate()
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # the reporter that verbose=0 silences
        # Ray starts its workers at nice 15: beside any other busy process (a second
        # sweep, a train.py) the trials then got ~2 % of a core, 600 Pendulum steps took
        # 2.5 min instead of 5 s. Trials are the work; run them at normal priority.
        os.environ.setdefault("RAY_worker_niceness", "0")
        quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
        if self.address:
            ray.init(address=self.address, **quiet)
        else:
            ray.init(include_dashboard=False, **quiet)
        logging.getLogger("ray.tune").setLevel(logging.WARNING)
        try:
            results = self._tuner(resume).fit()
        finally:
            ray.shutdown()
        failures = []
        for result in results:
            if result.error is not None:
                lines = [line for line in str(result.error).splitlines() if line.strip()]
                trial_id = Path(result.path).name if result.path else "?"
                failures.append(f"trial {trial_id} failed: {lines[-1] if lines else result.error}")
        return failures


# -- the outcome ------------------------------------------------------------------------
def summarize(folder: str | Path, milestones: Sequence[float] | None = None) -> list[dict]:
    """One row per configuration of a sweep folder; writes summary.csv and curves.png.

    ``milestones``: the returns whose first crossing the rows report (steps, minutes);
    by default those of :func:`default_milestones` for the sweep's env.
    """
    import gymnasium as gym

    from minitaur_env.training.aggregate import (
        GroupSummary,
        RunCurve,
        default_milestones,
        plot_iqm_curves,
        write_csv,
    )

    folder = Path(folder)
    trials = sorted((folder / RUNS).glob(f"*/{TRIAL_FILE}"))
    if not trials:
        raise UsageError(f"{folder} holds no sweep trials ({RUNS}/*/{TRIAL_FILE})")
    runs_of = {path: [p.parent for p in path.parent.glob("*/*/config.yml")] for path in trials}
    env_id = next(
        (yaml.safe_load((runs[0] / "config.yml").read_text())["env"] for runs in runs_of.values()
         if runs),
        None,
    )  # fmt: skip
    if env_id is not None:
        import minitaur_env  # noqa: F401  (the Minitaur ids' specs)
    if milestones is None:
        milestones = default_milestones(env_id) if env_id is not None else ()
    groups: dict[str, GroupSummary] = {}
    for trial_file, runs in runs_of.items():
        trial = yaml.safe_load(trial_file.read_text())
        group = groups.setdefault(
            trial["group"], GroupSummary(trial["group"], [], [], tuple(milestones))
        )
        if trial["status"] == "completed" and runs:
            group.curves.append(RunCurve.read(runs[0]))
        elif trial["status"] == "failed":
            group.failed.append(trial.get("error", ""))
        else:  # interrupted: --resume finishes it
            group.unfinished += 1
    rows = [group.row() for group in groups.values()]
    write_csv(rows, folder / "summary.csv")
    threshold = gym.spec(env_id).reward_threshold if env_id is not None else None
    plot_iqm_curves(list(groups.values()), folder / "curves.png", threshold)
    return rows


def seed_list(values: list[int], first_seed: int = 0) -> list[int]:
    """``--seeds N`` (with ``--first-seed K``: K..K+N-1) or ``--seeds 0 4 7``."""
    if len(values) == 1:
        seeds = list(range(first_seed, first_seed + values[0]))
    elif first_seed:
        raise UsageError("--first-seed goes with a count (--seeds N), not a list of seeds")
    else:
        seeds = list(values)
    if not seeds or len(set(seeds)) != len(seeds):
        raise UsageError("--seeds takes a count N >= 1, or a list of distinct seeds")
    return seeds


def run_sweep_from_args(args: Any) -> int:
    """What ``python -m minitaur_env.sweep`` does with its flags; returns the exit code."""
    from minitaur_env.training.aggregate import format_rows
    from minitaur_env.training.cli import config_from_args

    if args.summarize:
        rows = summarize(args.summarize, args.milestones)
        print(format_rows(rows))
        print(f"summary: {Path(args.summarize) / 'summary.csv'}")
        return 0
    seeds = seed_list(args.seeds, args.first_seed)
    base = config_from_args(args, save_freq=args.save_freq, vec_env="dummy", device="cpu")
    sweep = Sweep(
        base=base,
        storage=args.storage,
        name=args.name or f"{args.algo}-{args.env.split(':')[-1]}",
        seeds=seeds,
        search=load_search_space(args.search) if args.search else None,
        trials=args.trials,
        scheduler=args.scheduler,
        cpus_per_trial=args.cpus_per_trial,
        gpus_per_trial=args.gpus_per_trial,
        max_concurrent=args.max_concurrent,
        address=args.address,
        command=shlex.join(["python", "-m", "minitaur_env.sweep", *sys.argv[1:]]),
    )
    failures = sweep.run(resume=args.resume)
    for line in failures:
        print(line, file=sys.stderr)
    if sweep.unfinished():  # Tune returns normally after Ctrl-C, with the trials cut short
        print(
            f"sweep interrupted; continue it with: python -m minitaur_env.sweep "
            f"-f {sweep.storage} --name {sweep.name} --resume",
            file=sys.stderr,
        )
        return 130
    rows = summarize(sweep.folder, args.milestones)
    print(format_rows(rows))
    print(f"summary: {sweep.folder / 'summary.csv'}; curves: {sweep.folder / 'curves.png'}")
    return 1 if failures else 0
