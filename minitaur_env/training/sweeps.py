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
import signal
from pathlib import Path
from typing import Any

from minitaur_env.training import UsageError
from minitaur_env.training.config import ExperimentConfig
from minitaur_env.training.experiment import check_buildable
from minitaur_env.training.files import read_yaml
from minitaur_env.training.trial import METRIC, RUNS, TRIAL_FILE, run_trial


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
    # Whether a trial resuming its run may unpickle the run's files (SBX checkpoints,
    # runs from before 0.3): this session's --trust-pickle, never a stored setting.
    trust_pickle: bool = False
    stopped_by: int | None = None  # the signal that cut this session's trials short

    @property
    def folder(self) -> Path:
        return Path(self.storage) / self.name

    def validate(self) -> None:
        if self.scheduler not in ("none", "asha"):
            raise UsageError(f"--scheduler must be asha or none, got {self.scheduler!r}")
        if not self.base.eval_freq:
            raise UsageError("a sweep compares its trials by their evaluations: --eval-freq > 0")
        if self.base.eval_freq > self.base.n_timesteps:
            raise UsageError(
                f"--eval-freq {self.base.eval_freq} is more than -n {self.base.n_timesteps}: "
                "no trial would be evaluated, and a sweep compares its trials by their evaluations"
            )
        if self.search is not None and len(self.seeds) > 1 and self.scheduler == "asha":
            raise UsageError(
                "--scheduler asha with --seeds > 1 in a --search would stop some seeds of a "
                "configuration early and bias its average; use one or the other"
            )
        if self.cpus_per_trial <= 0 or self.gpus_per_trial < 0 or self.trials < 1:
            raise UsageError("--cpus-per-trial must be > 0, --gpus-per-trial >= 0, --trials >= 1")
        if self.gpus_per_trial > 0 and self.address is None:
            import torch  # a local Ray sees the GPUs torch sees

            if torch.cuda.device_count() < self.gpus_per_trial:
                raise UsageError(
                    f"--gpus-per-trial {self.gpus_per_trial:g}: this machine has "
                    f"{torch.cuda.device_count()} GPU(s), so no trial could ever start"
                )
        check_buildable(self.base)

    def _check_cluster(self, resources: dict[str, float]) -> None:
        """Refuse trials the cluster could never place: Tune would wait for them forever."""
        for key, wanted, flag in (
            ("CPU", self.cpus_per_trial, "--cpus-per-trial"),
            ("GPU", self.gpus_per_trial, "--gpus-per-trial"),
        ):
            if wanted > resources.get(key, 0.0):
                raise UsageError(
                    f"{flag} {wanted:g}: the Ray cluster has {resources.get(key, 0.0):g} "
                    f"{key}(s), so no trial could ever start"
                )

    def _tuner(self, resume: bool) -> Any:
        from ray import tune
        from ray.tune.schedulers import ASHAScheduler
        from ray.tune.search import Repeater
        from ray.tune.search.optuna import OptunaSearch

        trainable = tune.with_resources(
            tune.with_parameters(run_trial, trust_pickle=self.trust_pickle),
            {"cpu": self.cpus_per_trial, "gpu": self.gpus_per_trial},
        )
        path = str(self.folder.resolve())
        if resume:
            if not tune.Tuner.can_restore(path):
                raise UsageError(f"--resume: no Ray Tune sweep to resume in {self.folder}")
            # An errored trial (a crash, a killed worker) continues from its run folder's
            # newest checkpoint like a paused one: Tune's default would leave it unfinished.
            return tune.Tuner.restore(path, trainable, resume_unfinished=True, resume_errored=True)
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
                callbacks=[
                    _evaluation_lines(self.base.n_timesteps),
                    tune.logger.CSVLoggerCallback(),
                    tune.logger.JsonLoggerCallback(),
                ],
            ),
        )

    def unfinished(self) -> list[Path]:
        """The trial folders whose run was cut short (Ctrl-C, a lost node)."""
        return [
            path.parent
            for path in sorted((self.folder / RUNS).glob(f"*/{TRIAL_FILE}"))
            if read_yaml(path)["status"] == "running"
        ]

    def run(self, resume: bool = False) -> list[str]:
        """Launch (or resume) the trials; return one line per failed trial."""
        import ray

        self.validate()
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # the reporter that verbose=0 silences
        # Tune adds a TensorBoardX logger by default, whose atexit cleanup starts a thread:
        # on Python 3.12 that prints a RuntimeError traceback after a Ctrl-C'd sweep's last
        # line. Our run folders hold the curves; Tune keeps its CSV and JSON (below).
        os.environ["TUNE_DISABLE_AUTO_CALLBACK_LOGGERS"] = "1"
        # Ray starts its workers at nice 15: beside any other busy process (a second
        # sweep, a train.py) the trials then got ~2 % of a core, 600 Pendulum steps took
        # 2.5 min instead of 5 s. Trials are the work; run them at normal priority.
        os.environ.setdefault("RAY_worker_niceness", "0")
        quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
        # A Ray the caller already started (a notebook's ray.init with its own resources)
        # is used and left running; one started here is shut down here.
        started_here = not ray.is_initialized()
        if not started_here and self.address:
            raise UsageError(
                f"--address {self.address}: this process is already connected to Ray; "
                "leave out the address, or call ray.shutdown() first"
            )
        if started_here and self.address:
            ray.init(address=self.address, **quiet)
        elif started_here:
            ray.init(include_dashboard=False, **quiet)
        logging.getLogger("ray.tune").setLevel(logging.WARNING)

        # SIGTERM (a scheduler's stop, systemd, kill) ends the sweep as Ctrl-C does: Tune
        # stops the trials at their checkpoints and keeps its state for --resume. Ray's
        # own handler printed a C++ stack dump and left no resume hint.
        def interrupt_instead(signum: int, frame: Any) -> None:
            self.stopped_by = signal.SIGTERM
            os.kill(os.getpid(), signal.SIGINT)  # the signal Tune knows how to stop on

        previous = signal.signal(signal.SIGTERM, interrupt_instead)
        try:
            self._check_cluster(ray.cluster_resources())
            results = self._tuner(resume).fit()
        finally:
            signal.signal(signal.SIGTERM, previous)
            if started_here:
                ray.shutdown()
        failures = []
        for result in results:
            if result.error is not None:
                lines = [line for line in str(result.error).splitlines() if line.strip()]
                trial_id = Path(result.path).name if result.path else "?"
                failures.append(f"trial {trial_id} failed: {lines[-1] if lines else result.error}")
        return failures


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
