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

import contextlib
import dataclasses
import pickle
import shutil
import signal
import sys
import threading
import time
import zipfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from minitaur_env.training import TrainingDiverged, UsageError
from minitaur_env.training.algorithms import OFF_POLICY, algorithm_class, load_model
from minitaur_env.training.envs import (
    VEC_ENVS,
    make_eval_env,
    make_training_env,
    qualified_env_id,
    resolve_vec_env,
)
from minitaur_env.training.hyperparams import RUN_KEYS, algorithm_kwargs, load_hyperparams
from minitaur_env.training.policies import resolve_policy
from minitaur_env.training.run_folder import RunFolder, load_pickle
from minitaur_env.training.safe_load import (
    TRUST_FLAG,
    attach,
    load_sb3_model,
    save_normalizer,
    training_normalizer,
)
from minitaur_env.training.vec_env import EnvWorkerError


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Python was when it arrived, so it unwinds like Ctrl-C."""


@dataclasses.dataclass
class ExperimentConfig:
    """Everything a run depends on; written to the run folder's config.yml."""

    algo: str = "sac"
    env: str = "MinitaurBulletEnv-v0"
    backend: str = "sb3"
    config: str | None = None  # the hyperparameter entry used (the env id by default)
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    seed: int = 0
    n_timesteps: int = 100_000
    n_envs: int = 1
    vec_env: str = "auto"
    normalize: bool | dict[str, Any] = False
    policy: str = "MlpPolicy"
    hyperparams: dict[str, Any] = dataclasses.field(default_factory=dict)
    eval_freq: int = 10_000
    eval_episodes: int = 20
    save_freq: int = 5_000
    video_freq: int = 0
    video_length: int = 1000
    device: str = "auto"
    tensorboard_log: str | None = None
    trained_agent: str | None = None  # a model zip to start from, as the zoo's -i
    # -i: also load the pickles in and beside that model (they can run code from the file)
    trust_pickle: bool = False

    @classmethod
    def resolve(
        cls,
        algo: str = "sac",
        env: str = "MinitaurBulletEnv-v0",
        *,
        entry: str | None = None,
        conf_file: str | None = None,
        hyperparams: dict[str, Any] | None = None,
        n_timesteps: int | None = None,
        n_envs: int | None = None,
        **settings: Any,
    ) -> ExperimentConfig:
        """The hyperparameter file's entry for ``env`` (or ``entry``), with overrides.

        ``hyperparams`` may also set the run keys ``n_timesteps``, ``n_envs``,
        ``normalize`` and ``policy``; ``settings`` are the other fields.
        """
        table = load_hyperparams(algo, env, conf_file, entry)
        table.update(hyperparams or {})
        run = {key: table.pop(key) for key in RUN_KEYS if key in table}
        if n_timesteps is not None:
            run["n_timesteps"] = n_timesteps
        if n_envs is not None:
            run["n_envs"] = n_envs
        config = cls(
            algo=algo,
            env=env,
            config=entry or env,
            n_timesteps=int(run.get("n_timesteps", 100_000)),
            n_envs=int(run.get("n_envs", 1)),
            normalize=run.get("normalize", False),
            policy=run.get("policy", "MlpPolicy"),
            hyperparams=table,
            **settings,
        )
        config.validate()
        return config

    def validate(self) -> None:
        """Raise a UsageError for what would only fail later, inside training."""
        for name in ("eval_freq", "save_freq", "video_freq"):
            if getattr(self, name) < 0:
                raise UsageError(f"--{name.replace('_', '-')} must be >= 0")
        for name in ("eval_episodes", "video_length", "n_envs"):
            if getattr(self, name) < 1:
                raise UsageError(f"--{name.replace('_', '-')} must be >= 1")
        if self.n_timesteps < 1:
            raise UsageError("-n/--n-timesteps must be >= 1")
        if self.vec_env not in VEC_ENVS:
            raise UsageError(f"--vec-env must be one of {', '.join(VEC_ENVS)}")
        algorithm_class(self.algo, self.backend)
        algorithm_kwargs(self.hyperparams)
        qualified_env_id(self.env)
        if self.trained_agent:
            self._check_trained_agent(Path(self.trained_agent))

    def _check_trained_agent(self, path: Path) -> None:
        from minitaur_env.training.evaluation import infer_algo

        if not path.is_file():
            raise UsageError(f"--trained-agent: no model file at {path}")
        algo, backend = infer_algo(path)
        if (algo, backend) != (self.algo, self.backend):
            raise UsageError(
                f"--trained-agent {path} is a {backend} {algo} model and this run trains "
                f"{self.backend} {self.algo}; pass --algo {algo} --backend {backend}"
            )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> ExperimentConfig:
        """From a config.yml; keys that older versions wrote and this one dropped are ignored."""
        fields = {field.name for field in dataclasses.fields(cls)}
        config = cls(**{key: value for key, value in values.items() if key in fields})
        if config.vec_env not in VEC_ENVS:  # e.g. "subproc", which grouped replaced
            config.vec_env = "auto"
        return config


@dataclasses.dataclass
class RunResult:
    """How a run ended: ``completed``, ``interrupted`` (Ctrl-C/SIGTERM), ``diverged`` or
    ``failed`` (an env raised)."""

    status: str
    run: RunFolder
    num_timesteps: int
    trained_steps: int
    elapsed_s: float
    checkpoint: Path | None = None
    signal: int | None = None
    message: str = ""
    last_eval: tuple[int, float, float] | None = None  # (steps, mean, std)
    best_eval: tuple[int, float] | None = None  # (steps, mean)

    @property
    def exit_code(self) -> int:
        """What a script should exit with: 0, 1 (diverged, failed), 130 (Ctrl-C), 143 (SIGTERM)."""
        if self.status == "completed":
            return 0
        if self.status == "interrupted":
            return 128 + (self.signal or signal.SIGINT)
        return 1

    def summary(self) -> str:
        lines = [f"run folder: {self.run}"]
        rate = self.trained_steps / max(self.elapsed_s, 1e-9)
        lines.append(
            f"env steps: {self.num_timesteps} ({self.trained_steps} this session, "
            f"{self.elapsed_s / 60:.1f} min, {rate:.0f} steps/s)"
        )
        if self.last_eval is not None and self.best_eval is not None:
            steps, mean, std = self.last_eval
            lines.append(
                f"last eval: {mean:.2f} +- {std:.2f} at {steps} steps; "
                f"best: {self.best_eval[1]:.2f} at {self.best_eval[0]} steps"
            )
        if self.run.learning_curve.is_file():
            lines.append(f"learning curve: {self.run.learning_curve}")
        return "\n".join(lines)


@contextlib.contextmanager
def sigterm_as_exception() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` (in the main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return

    def handler(signum: int, frame: Any) -> None:
        raise Terminated(signum)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def set_torch_threads(num_threads: int, config: ExperimentConfig) -> None:
    """``num_threads``, else one thread when grouped envs use the other cores."""
    import torch

    if num_threads > 0:
        torch.set_num_threads(num_threads)
    elif resolve_vec_env(config.vec_env, config.n_envs) == "grouped":
        # torch's idle threads spin-wait on the workers' cores: with PPO's 8 envs that
        # cost 40% of the speed.
        torch.set_num_threads(1)


class Experiment:
    """Build, train, checkpoint and summarize one run in its :class:`RunFolder`.

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
        verbose: int = 1,
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
        run = RunFolder.create(log_folder, config.algo, config.env)
        run.write_config(config.to_dict())
        return cls(config, run, **options)

    @classmethod
    def resume(
        cls,
        run_dir: str | Path,
        n_timesteps: int | None = None,
        overrides: dict[str, Any] | None = None,
        **options: Any,
    ) -> Experiment:
        """Continue ``run_dir`` from its newest readable checkpoint.

        ``n_timesteps`` extends (or shortens) the run. ``overrides`` are settings the
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
            if n_timesteps < 1:
                raise UsageError("-n/--n-timesteps must be >= 1")
            config.n_timesteps = n_timesteps
        from minitaur_env.training.run_folder import ensure_writable

        ensure_writable(run.path)
        run.write_config(config.to_dict())
        return cls(config, run, resume=True, **options)

    # -- building ---------------------------------------------------------------
    def _algorithm(self) -> type[BaseAlgorithm]:
        return algorithm_class(self.config.algo, self.config.backend)

    def _build_envs(self, seed: int, normalizer: Callable[[VecEnv], VecNormalize] | None) -> None:
        config = self.config
        env = make_training_env(
            config.env,
            n_envs=config.n_envs,
            seed=seed,
            env_kwargs=config.env_kwargs,
            vec_env=config.vec_env,
            monitor_dir=str(self.run_folder.monitor_dir),
            append_monitor=self.resuming,
        )
        self.env = env
        if normalizer is not None:  # saved statistics to go on from
            self.env = normalizer(env)
        elif config.normalize:
            options = config.normalize if isinstance(config.normalize, dict) else {}
            gamma = config.hyperparams.get("gamma", 0.99)
            self.env = VecNormalize(env, gamma=gamma, **options)
        self.eval_env = make_eval_env(
            config.env, seed=config.seed + 10_000, env_kwargs=config.env_kwargs,
            normalize=config.normalize,
        )  # fmt: skip

    def _fresh_model(self) -> BaseAlgorithm:
        config = self.config
        try:
            return self._algorithm()(
                resolve_policy(config.algo, config.policy, config.backend),
                self.env,
                seed=config.seed,
                device=config.device,
                tensorboard_log=config.tensorboard_log,
                verbose=0,
                **algorithm_kwargs(config.hyperparams),
            )
        except (TypeError, ValueError, AssertionError) as error:
            message = " ".join(str(error).split())
            raise UsageError(f"invalid hyperparameters for {config.algo}: {message}") from error

    def _trained_agent(self) -> BaseAlgorithm:
        """The model of ``config.trained_agent`` on this run's envs, with the run's
        hyperparameters (network shape aside) and its replay buffer where one lies beside
        it, as the zoo's ``--trained-agent`` does."""
        config = self.config
        path = Path(config.trained_agent)
        kwargs = algorithm_kwargs(config.hyperparams)
        kwargs.pop("policy_kwargs", None)  # the saved network decides its own shape
        try:
            model = load_sb3_model(
                self._algorithm(), path, config.trust_pickle, training=True, env=self.env,
                seed=config.seed, device=config.device, tensorboard_log=config.tensorboard_log,
                **kwargs,
            )  # fmt: skip
        except (ValueError, KeyError) as error:  # e.g. the spaces of another env
            message = " ".join(str(error).split())[:200]
            raise UsageError(
                f"--trained-agent {path} does not fit {config.env}: {message}"
            ) from error
        model.num_timesteps = 0  # -n counts this run's steps, as in the zoo
        buffer = RunFolder.replay_buffer_beside(path)
        if config.algo in OFF_POLICY and buffer.is_file():
            if config.trust_pickle:
                model.load_replay_buffer(buffer)
            else:
                self.log(f"{buffer} is a pickle (it can run code): starting with an empty "
                         f"replay buffer; pass {TRUST_FLAG} to load it")  # fmt: skip
        return model

    def _trained_agent_normalizer(self) -> Callable[[VecEnv], VecNormalize] | None:
        """The trained agent's VecNormalize statistics, to go on adapting from."""
        from minitaur_env.training.evaluation import normalizer_path_for

        path = normalizer_path_for(Path(self.config.trained_agent))
        if (path is None) == bool(self.config.normalize):
            raise UsageError(
                f"--trained-agent {self.config.trained_agent}: the model was trained "
                f"{'without' if path is None else 'with'} VecNormalize statistics and this "
                f"run has normalize={self.config.normalize}; set --hyperparams normalize="
                f"{'false' if path is None else 'true'}"
            )
        if path is None:
            return None
        return training_normalizer(path, self.config.trust_pickle)

    def _load_newest_checkpoint(
        self,
    ) -> tuple[BaseAlgorithm, Callable[[VecEnv], VecNormalize] | None, int]:
        """The newest checkpoint whose files all load; no env is built for torn ones."""
        algorithm = self._algorithm()
        for steps, path in self.run_folder.checkpoints():
            try:
                model = load_model(algorithm, path, device=self.config.device)
                normalizer = None
                if self.config.normalize:
                    normalizer = attach(load_pickle(self.run_folder.vecnormalize(steps)))
                buffer = self.run_folder.replay_buffer(steps)
                if self.config.algo in OFF_POLICY:
                    if buffer.exists():
                        model.load_replay_buffer(buffer)
                    else:
                        self.log(f"no replay buffer saved at step {steps}: starting an empty one")
                return model, normalizer, steps
            except (
                ValueError,
                OSError,
                EOFError,
                KeyError,
                zipfile.BadZipFile,
                pickle.PickleError,
            ) as error:
                # A kill -9 during a save leaves a torn zip or pickle behind.
                self.log(f"skipping unreadable checkpoint {path.name}: {error}", file=sys.stderr)
        raise UsageError(f"no readable checkpoint in {self.run_folder.checkpoint_dir}")

    def build(self) -> None:
        """The training env, the model (fresh or from a checkpoint) and the eval env."""
        config = self.config
        if self.resuming:
            model, normalizer, steps = self._load_newest_checkpoint()
            self.resumed_at = steps
            self.run_folder.rewind_logs(steps)
            # New episodes after a resume, from the same seed.
            self._build_envs(config.seed + steps, normalizer)
            model.set_env(self.env, force_reset=True)
            model.tensorboard_log = config.tensorboard_log
            self.model = model
        elif config.trained_agent:
            self._build_envs(config.seed, self._trained_agent_normalizer())
            self.model = self._trained_agent()
        else:
            self._build_envs(config.seed, None)
            self.model = self._fresh_model()
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
            SaveVecNormalizeCallback,
            VideoRecorderCallback,
        )
        from minitaur_env.training.progress import TrainingProgress

        config, run = self.config, self.run_folder
        callbacks: list[BaseCallback] = [DivergenceGuardCallback()]
        evaluation = None
        if config.save_freq:
            callbacks.append(CheckpointEveryCallback(run, config.save_freq))
        if config.eval_freq:
            on_new_best = None
            if config.normalize:
                # The zoo's enjoy --load-best reads <env>/vecnormalize.pkl, as the zoo
                # itself writes it: the best model's until the final model's replaces it.
                on_new_best = SaveVecNormalizeCallback(
                    run.vecnormalize_beside(run.best_model), run.zoo_vecnormalize
                )
            evaluation = EvalCallback(
                self.eval_env,
                n_eval_episodes=config.eval_episodes,
                eval_freq=max(config.eval_freq // config.n_envs, 1),
                log_path=str(run.path),
                best_model_save_path=str(run.path),
                deterministic=True,
                callback_on_new_best=on_new_best,
                callback_after_eval=CallbackList(self.after_eval) if self.after_eval else None,
                verbose=self.verbose,
            )
            if self.resuming and run.evaluations.exists():
                with np.load(run.evaluations) as data:
                    evaluation.evaluations_timesteps = list(data["timesteps"])
                    evaluation.evaluations_results = [list(r) for r in data["results"]]
                    evaluation.evaluations_length = [list(r) for r in data["ep_lengths"]]
                means = [np.mean(r) for r in evaluation.evaluations_results]
                evaluation.best_mean_reward = float(max(means)) if means else -np.inf
            if self.resuming:
                # EvalCallback counts its calls from 0; continue the run's count so that
                # evaluations stay on multiples of eval_freq, as before the stop.
                evaluation.n_calls = (self.resumed_at or 0) // config.n_envs
            callbacks.append(evaluation)
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
                    seed=config.seed + 20_000,
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
    def run(self) -> RunResult:
        """Train to ``config.n_timesteps``; Ctrl-C and SIGTERM end in a checked checkpoint."""
        from minitaur_env.training.callbacks import save_checked_checkpoint, weights_finite

        set_torch_threads(self.num_threads, self.config)
        run = self.run_folder
        started = time.perf_counter()
        with sigterm_as_exception():
            try:
                self.build()
                callbacks = self._callbacks()
            except BaseException as error:
                self.close()
                if not self.resuming:
                    shutil.rmtree(run.path, ignore_errors=True)  # a run that never started
                if isinstance(error, KeyboardInterrupt):
                    return RunResult(
                        "interrupted", run, 0, 0, time.perf_counter() - started,
                        signal=_signal_of(error),
                        message="interrupted before training started; nothing was saved",
                    )  # fmt: skip
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
                    status, stop_signal = "interrupted", _signal_of(error)
                    with _ignoring_more_signals():
                        checkpoint = save_checked_checkpoint(model, run)
                    message = f"interrupted: saved {checkpoint} (resume with --resume {run.path})"
            except EnvWorkerError as error:
                # The model is sound: keep it, so that the run can resume once the env is fixed.
                status = "failed"
                with _ignoring_more_signals():
                    checkpoint = save_checked_checkpoint(model, run)
                message = f"{error}; saved {checkpoint} (resume with --resume {run.path})"
            except TrainingDiverged as error:
                status = "diverged"
                last = run.checkpoints()
                kept = f"last good checkpoint: {last[0][1]}" if last else "no checkpoint was saved"
                message = f"training diverged: {str(error)[:300]}; {kept}"
            finally:
                self.close()
            elapsed = time.perf_counter() - started
            if status == "completed":
                newest = run.checkpoints()
                if self.config.save_freq and (not newest or newest[0][0] != model.num_timesteps):
                    # With its replay buffer, so that --resume -n can extend the run exactly.
                    save_checked_checkpoint(model, run)
                model.save(run.zoo_model)
                normalizer = model.get_vec_normalize_env()
                if normalizer is not None:
                    save_normalizer(normalizer, run.zoo_vecnormalize)
            result = RunResult(
                status, run, model.num_timesteps, model.num_timesteps - start_steps, elapsed,
                checkpoint=checkpoint, signal=stop_signal, message=message,
            )  # fmt: skip
            self._summarize(result)
            return result

    def _summarize(self, result: RunResult) -> None:
        import gymnasium as gym

        from minitaur_env.training.plotting import plot_learning_curve

        run = self.run_folder
        if not run.evaluations.exists():
            return
        with np.load(run.evaluations) as data:
            results, steps = data["results"], data["timesteps"]
        if not len(steps):
            return
        means = results.mean(axis=1)
        best = int(np.argmax(means))
        result.last_eval = (int(steps[-1]), float(means[-1]), float(results[-1].std()))
        result.best_eval = (int(steps[best]), float(means[best]))
        plot_learning_curve(
            run.evaluations,
            run.learning_curve,
            title=f"{run.path.parent.name} on {self.config.env}",
            reward_threshold=gym.spec(self.config.env).reward_threshold,
        )


def _signal_of(error: KeyboardInterrupt) -> int:
    return signal.SIGTERM if isinstance(error, Terminated) else signal.SIGINT


@contextlib.contextmanager
def _ignoring_more_signals() -> Iterator[None]:
    """While the interrupt checkpoint is written, a second Ctrl-C/SIGTERM must not tear it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
