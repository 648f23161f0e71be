"""One training run as an object: build it (fresh or from a checkpoint), run it, stop it.

::

    from minitaur_env.training import Experiment, ExperimentConfig

    config = ExperimentConfig.resolve(algo="sac", env="MinitaurBulletEnv-v0", seed=1)
    result = Experiment.create(config, log_folder="logs").run()
    Experiment.resume("logs/sac/MinitaurBulletEnv-v0_1", n_timesteps=400_000).run()

``train.py``, the sweep's trials and the tests all go through this class. Ctrl-C and
SIGTERM end a run the same way: the weights are checked, a checkpoint (model, replay
buffer, VecNormalize) is written and ``run()`` returns an ``interrupted`` result that
names it.
"""

from __future__ import annotations

import shutil
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from minitaur_env.training import TrainingDiverged, UsageError
from minitaur_env.training.algorithms import algorithm_class, resolve_policy
from minitaur_env.training.checkpoints import (
    load_newest_checkpoint,
    load_trained_agent,
    save_after_failure,
    save_checked_checkpoint,
    save_model,
    trained_agent_normalizer,
    weights_finite,
)
from minitaur_env.training.config import ExperimentConfig
from minitaur_env.training.envs import make_eval_env, make_training_env
from minitaur_env.training.files import ensure_writable, exclusive
from minitaur_env.training.hyperparams import algorithm_kwargs, reward_time_step
from minitaur_env.training.results import RunResult
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.runtime import (
    ignoring_more_signals,
    set_torch_threads,
    signal_of,
    stop_signals_as_exceptions,
)
from minitaur_env.training.safe_load import (
    save_normalizer,
)
from minitaur_env.training.seeds import SeedPlan

# Raised late by SB3 or torch for a setting they reject (the checks before training catch
# most): status 2, as a usage error before training would be.
USAGE_ERRORS = (UsageError, ValueError, TypeError, AssertionError)


class Experiment:
    """Build, train, checkpoint and summarize one run in its run folder
    (:class:`~minitaur_env.training.run_folder.RunFolder`).

    ``callbacks`` are SB3 callbacks added to the run's own; ``after_eval`` callbacks run
    after each evaluation (as ``EvalCallback(callback_after_eval=...)``, so they can read
    ``self.parent.last_mean_reward``).
    """

    def __init__(
        self,
        config: ExperimentConfig,
        run: RunFolder,
        *,
        resume: bool = False,
        trust_pickle: bool = False,
        verbose: int = 0,
        progress: str = "auto",
        num_threads: int = 0,
        callbacks: Sequence[BaseCallback] = (),
        after_eval: Sequence[BaseCallback] = (),
        command: str | None = None,
        log: Any = print,
    ) -> None:
        self.config = config
        self.run_folder = run
        self.resuming = resume
        self.verbose = verbose
        self.progress = progress
        self.num_threads = num_threads
        self.extra_callbacks = list(callbacks)
        self.after_eval = list(after_eval)
        self.command = command
        self.log = log
        self.env: VecEnv | None = None
        self.eval_env: VecEnv | None = None
        self.model: BaseAlgorithm | None = None
        self.resumed_at: int | None = None
        # What a resume may unpickle: this session's choice (-i reads config.trust_pickle).
        self.trust_pickle = trust_pickle

    # -- creating ---------------------------------------------------------------
    @classmethod
    def create(
        cls, config: ExperimentConfig, log_folder: str | Path = "logs", **options: Any
    ) -> Experiment:
        """A fresh run in the next free ``<log_folder>/<algo>/<env>_<N>``."""
        config.validate()
        if config.tensorboard_log:
            try:
                import tensorboard  # noqa: F401
            except ImportError as error:
                raise UsageError(
                    "--tensorboard-log needs TensorBoard: pip install tensorboard"
                ) from error
            ensure_writable(Path(config.tensorboard_log))  # not after the first step
        run = RunFolder.create(log_folder, config.algo, config.env)
        run.write_config(config.to_dict())
        return cls(config, run, **options)

    @classmethod
    def resume(
        cls,
        run_dir: str | Path,
        n_timesteps: int | None = None,
        overrides: dict[str, Any] | None = None,
        device: str | None = None,
        trust_pickle: bool = False,
        **options: Any,
    ) -> Experiment:
        """Continue ``run_dir`` from its newest readable checkpoint.

        Its files load without unpickling anything unless ``trust_pickle`` (this
        session's choice: config.yml's ``trust_pickle`` is a file's word, not the user's).

        ``n_timesteps`` extends (or shortens) the run; ``device`` moves it (a checkpoint
        loads on any device). ``overrides`` are settings the
        caller asked for (``seed``, ``hyperparams.learning_rate``, ``env_kwargs.x``...):
        any that differs from the saved configuration is a UsageError, since the run
        could not honour it.
        """
        run = RunFolder.existing(run_dir)
        config = ExperimentConfig.from_dict(run.read_config())
        for key, value in (overrides or {}).items():
            field, _, name = key.partition(".")
            saved = getattr(config, field)
            if name:
                saved = saved.get(name, "<not set>")
            if value != saved:
                raise UsageError(
                    f"--resume {run.path}: {key} {value!r} contradicts the run's saved "
                    f"{key} {saved!r}; start a new run to change it"
                )
        if not run.checkpoints():
            raise UsageError(f"--resume {run.path}: no checkpoint in {run.checkpoint_dir}")
        if n_timesteps is not None:
            reached = run.checkpoints()[0][0]
            if n_timesteps < reached:
                raise UsageError(
                    f"--resume {run.path} -n {n_timesteps}: its newest checkpoint is at "
                    f"{reached} steps already; -n is the total to reach"
                )
            config.n_timesteps = n_timesteps
        if device is not None:
            config.device = device
        ensure_writable(run.path)
        if config.tensorboard_log:
            ensure_writable(Path(config.tensorboard_log))
        run.write_config(config.to_dict())
        return cls(config, run, resume=True, trust_pickle=trust_pickle, **options)

    # -- building ---------------------------------------------------------------
    @property
    def seeds(self) -> SeedPlan:
        try:
            return SeedPlan(self.config.seed, self.config.n_envs)
        except ValueError as error:
            raise UsageError(str(error)) from error

    def _build_envs(
        self, started_at: int, normalizer: Callable[[VecEnv], VecNormalize] | None
    ) -> None:
        """The training and evaluation envs of a session that starts at env step
        ``started_at``, seeded as the run's seed plan says."""
        config = self.config
        env = make_training_env(
            config.env,
            n_envs=config.n_envs,
            seed=self.seeds.training(started_at)[0],
            env_kwargs=config.env_kwargs,
            vec_env=config.vec_env,
            monitor_dir=str(self.run_folder.monitor_dir),
            append_monitor=self.resuming,
            reward_time_step=reward_time_step(config.hyperparams),
        )
        self.env = env
        if normalizer is not None:  # saved statistics to go on from
            self.env = normalizer(env)
        elif config.normalize:
            options = config.normalize if isinstance(config.normalize, dict) else {}
            gamma = config.hyperparams.get("gamma", 0.99)
            self.env = VecNormalize(env, gamma=gamma, **options)
        self.eval_env = make_eval_env(
            config.env,
            seed=self.seeds.evaluation(started_at)[0],
            env_kwargs=config.env_kwargs,
            normalize=config.normalize,
        )

    def _fresh_model(self) -> BaseAlgorithm:
        return new_model(self.config, self.env)

    def build(self) -> None:
        """The training env, the model (fresh or from a checkpoint) and the eval env."""
        config = self.config
        if self.resuming:
            model, normalizer, steps = load_newest_checkpoint(
                self.run_folder, config, trust_pickle=self.trust_pickle, log=self.log
            )
            self.resumed_at = steps
            self.run_folder.rewind_logs(steps, self.log)
            # New episodes after a resume: the plan's seeds for a session from `steps`.
            self._build_envs(steps, normalizer)
            model.set_env(self.env, force_reset=True)
            model.tensorboard_log = config.tensorboard_log
            self.model = model
        else:
            if config.trained_agent:
                self._build_envs(0, trained_agent_normalizer(config))
                self.model = load_trained_agent(config, self.env, self.log)
            else:
                self._build_envs(0, None)
                self.model = self._fresh_model()
            # SB3 seeds a model's env with the model's seed (env i: seed + i) when it sets
            # the model up; its first reset plays the plan's training seeds instead.
            self.env.seed(self.seeds.training(0)[0])
        self._configure_logger()

    def _configure_logger(self) -> None:
        from stable_baselines3.common.logger import (
            CSVOutputFormat,
            HumanOutputFormat,
            Logger,
            TensorBoardOutputFormat,
        )

        run = self.run_folder
        formats: list = [CSVOutputFormat(str(run.progress(self.resumed_at)))]
        if self.verbose >= 1:
            formats.append(HumanOutputFormat(sys.stdout))
        if self.config.tensorboard_log:
            formats.append(
                TensorBoardOutputFormat(str(Path(self.config.tensorboard_log) / run.name))
            )
        self.model.set_logger(Logger(str(run.path), formats))

    def _callbacks(self) -> CallbackList:
        from minitaur_env.training.callbacks import (
            CheckpointEveryCallback,
            DivergenceGuardCallback,
            PromoteBestModel,
            PublishEvaluations,
            ResumableEvalCallback,
            VideoRecorderCallback,
            schedules,
        )
        from minitaur_env.training.progress import TrainingProgress

        config, run = self.config, self.run_folder
        callbacks: list[BaseCallback] = [DivergenceGuardCallback()]
        callbacks += schedules(config)
        evaluation = None
        if config.eval_freq:
            # SB3 writes both in place; they are staged and then moved over atomically.
            run.staging_dir.mkdir(exist_ok=True)
            evaluation = ResumableEvalCallback(
                self.eval_env,
                n_eval_episodes=config.eval_episodes,
                eval_freq=max(config.eval_freq // config.n_envs, 1),
                log_path=str(run.staging_dir),
                best_model_save_path=str(run.staging_dir),
                deterministic=True,
                callback_on_new_best=PromoteBestModel(run),
                callback_after_eval=CallbackList([PublishEvaluations(run), *self.after_eval]),
                verbose=self.verbose,
            )
            if self.resuming:
                evaluation.continue_from(
                    run.evaluations, run.best_model, self.resumed_at or 0, config.n_envs
                )
            callbacks.append(evaluation)
        if config.save_freq:
            # After the evaluation of the same step: a checkpoint at step N then has N's
            # evaluation on disk; before it, a kill between the two lost that evaluation.
            callbacks.append(CheckpointEveryCallback(run, config.save_freq))
        if config.video_freq:
            callbacks.append(
                VideoRecorderCallback(
                    config.env,
                    config.env_kwargs,
                    video_freq=config.video_freq,
                    video_length=config.video_length,
                    run_videos_dir=run.videos_dir,
                    shared_dir=Path("videos"),
                    name_prefix=run.name,
                    seed=self.seeds.video()[0],
                    verbose=1,
                )
            )
        # After the EvalCallback, so that an evaluation is shown on the step it ends.
        callbacks.append(TrainingProgress(self.progress, config.n_timesteps, run.name, evaluation))
        return CallbackList(callbacks + self.extra_callbacks)

    def close(self) -> None:
        for env in (self.env, self.eval_env):
            if env is not None:
                env.close()

    # -- running ------------------------------------------------------------------
    def _save_final(self, model: BaseAlgorithm) -> None:
        run = self.run_folder
        newest = run.checkpoints()
        if self.config.save_freq and (not newest or newest[0][0] != model.num_timesteps):
            # With its replay buffer, so that --resume -n can extend the run exactly.
            save_checked_checkpoint(model, run)
        save_model(model, run.zoo_model)
        normalizer = model.get_vec_normalize_env()
        if normalizer is not None:
            save_normalizer(normalizer, run.zoo_vecnormalize)

    def run(self) -> RunResult:
        """Train to ``config.n_timesteps``; Ctrl-C and SIGTERM end in a checked checkpoint."""
        config = self.config
        set_torch_threads(self.num_threads, config.policy)
        run = self.run_folder
        started = time.perf_counter()
        lock = exclusive(run.lock_file, f"run folder {run.path}")
        with stop_signals_as_exceptions(), lock:
            try:
                self.build()
                callbacks = self._callbacks()
            except BaseException as error:
                self.close()
                if not self.resuming:
                    shutil.rmtree(run.path, ignore_errors=True)  # a run that never started
                if isinstance(error, KeyboardInterrupt):
                    return RunResult(
                        "interrupted",
                        run,
                        0,
                        0,
                        time.perf_counter() - started,
                        signal=signal_of(error),
                        message="interrupted before training started; nothing was saved",
                    )
                raise
            if self.command:
                run.append_command(self.command)
            model = self.model
            start_steps = model.num_timesteps
            remaining = self.config.n_timesteps - start_steps
            self.log(
                f"training {self.config.algo} on {self.config.env} for {remaining} steps "
                f"(from {start_steps}) into {run.path}"
            )
            started = time.perf_counter()
            status, checkpoint, stop_signal, message = "completed", None, None, ""
            usage_error = False
            try:
                try:
                    if remaining > 0:
                        model.learn(
                            total_timesteps=remaining,
                            callback=callbacks,
                            reset_num_timesteps=not self.resuming,
                        )
                except ValueError as error:
                    # torch's distributions reject NaN parameters with a ValueError.
                    if weights_finite(model):
                        raise
                    raise TrainingDiverged(" ".join(str(error).split())) from error
                except KeyboardInterrupt as error:
                    status, stop_signal = "interrupted", signal_of(error)
                    with ignoring_more_signals():
                        checkpoint = save_checked_checkpoint(model, run)
                    message = f"interrupted: saved {checkpoint} (resume with --resume {run.path})"
                if status == "completed":
                    self._save_final(model)
            except TrainingDiverged as error:
                status = "diverged"
                last = run.checkpoints()
                kept = f"last good checkpoint: {last[0][1]}" if last else "no checkpoint was saved"
                message = f"training diverged: {str(error)[:300]}; {kept}"
            except Exception as error:
                # An env, a disk, a callback (video, TensorBoard) or a setting SB3 rejects
                # late: the model is sound, so keep it and say how to go on once it is fixed.
                status = "failed"
                usage_error = isinstance(error, USAGE_ERRORS) and not isinstance(error, OSError)
                checkpoint, message = save_after_failure(model, run, error)
            finally:
                self.close()
            elapsed = time.perf_counter() - started
            result = RunResult(
                status,
                run,
                model.num_timesteps,
                model.num_timesteps - start_steps,
                elapsed,
                checkpoint=checkpoint,
                signal=stop_signal,
                message=message,
                usage_error=usage_error,
            )
            result.read_evaluations(self.config.env)
            return result


def new_model(config: ExperimentConfig, env: VecEnv) -> BaseAlgorithm:
    """The algorithm with the run's hyperparameters on ``env``; what SB3 rejects in them is
    one UsageError."""
    try:
        return algorithm_class(config.algo, config.backend)(
            resolve_policy(
                config.algo, config.policy, config.backend, config.hyperparams.get("policy_kwargs")
            ),
            env,
            seed=config.seed,
            device=config.device,
            tensorboard_log=config.tensorboard_log,
            verbose=0,
            **algorithm_kwargs(config.hyperparams),
        )
    except (TypeError, ValueError, AssertionError) as error:
        message = " ".join(str(error).split())
        raise UsageError(f"invalid hyperparameters for {config.algo}: {message}") from error


def check_buildable(config: ExperimentConfig) -> None:
    """Refuse, as train.py does at its start, settings that could not make the env or the
    model: a sweep calls this before it starts Ray, so that a typo is one line, not a trial
    that fails behind Ray's start-up and tracebacks."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from minitaur_env.training.single_env import make_env

    config.validate()
    env = DummyVecEnv([lambda: make_env(config.env, config.env_kwargs)])
    try:
        # One env stands in for n_envs here: SB3's warnings on the rollout size would
        # name the wrong numbers, and the trial's own build warns with the right ones.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            new_model(config, env)
    finally:
        env.close()
