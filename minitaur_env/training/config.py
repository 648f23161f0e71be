"""What a run depends on, as written to its config.yml, and checked before anything starts."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import gymnasium as gym

from minitaur_env.training import VEC_ENVS, UsageError
from minitaur_env.training.algorithms import OFF_POLICY, algorithm_class, infer_algo
from minitaur_env.training.hyperparams import (
    HARD_DRAWS_KEY,
    N_STEPS_AFTER_KEY,
    REWARD_TIME_STEP_KEY,
    RUN_KEYS,
    algorithm_kwargs,
    entropy_decay,
    hard_draws,
    load_hyperparams,
    mirrored,
    n_steps_after,
    noise_color_until,
    push_curriculum,
    reward_time_step,
)
from minitaur_env.training.single_env import make_env, qualified_env_id


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
    eval_episodes: int = 10
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
        ``normalize``, ``policy``, ``eval_freq`` and ``eval_episodes``; ``settings`` are
        the other fields (``eval_freq``/``eval_episodes`` None: the entry's). An entry's
        ``env_kwargs`` (a recipe's env settings) are the defaults of ``env_kwargs``.
        """
        table = load_hyperparams(algo, env, conf_file, entry)
        table.update(hyperparams or {})
        run = {key: table.pop(key) for key in RUN_KEYS if key in table}
        entry_env_kwargs = table.pop("env_kwargs", None) or {}
        if not isinstance(entry_env_kwargs, dict):
            raise UsageError(f"env_kwargs of the {entry or env} entry must be a mapping")
        settings["env_kwargs"] = {**entry_env_kwargs, **(settings.get("env_kwargs") or {})}
        if n_timesteps is not None:
            run["n_timesteps"] = n_timesteps
        if n_envs is not None:
            run["n_envs"] = n_envs
        for key in ("eval_freq", "eval_episodes"):  # a flag given wins over the entry
            if settings.get(key) is None:
                settings.pop(key, None)
                if key in run:
                    settings[key] = _whole_number(run[key], key)
        config = cls(
            algo=algo,
            env=env,
            config=entry or env,
            n_timesteps=_whole_number(run.get("n_timesteps", 100_000), "n_timesteps"),
            n_envs=_whole_number(run.get("n_envs", 1), "n_envs"),
            normalize=run.get("normalize", False),
            policy=run.get("policy", "MlpPolicy"),
            hyperparams=table,
            **settings,
        )
        config.validate()
        return config

    @property
    def env_pushes(self) -> Any:
        """The env's ``pushes`` setting (in ``realism`` or, deprecated, a keyword of its
        own): the registered id's, unless ``env_kwargs`` sets it."""
        kwargs = {**gym.spec(self.env).kwargs, **self.env_kwargs}
        realism = kwargs.get("realism")
        within = realism.get("pushes") if isinstance(realism, dict) else None
        within = getattr(realism, "pushes", None) if within is None else within
        return kwargs.get("pushes") if within is None else within

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
        if not (isinstance(self.seed, int) and 0 <= self.seed < 2**32):
            raise UsageError(f"--seed {self.seed}: must be an integer in 0..2**32-1")
        options = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon"}
        if not isinstance(self.normalize, (bool, dict)) or (
            isinstance(self.normalize, dict) and not set(self.normalize) <= options
        ):
            raise UsageError(
                f"--hyperparams normalize={self.normalize!r}: must be true, false or a "
                f"mapping of VecNormalize's options ({', '.join(sorted(options))})"
            )
        _check_device(self.device)
        algorithm_class(self.algo, self.backend)
        algorithm_kwargs(self.hyperparams)
        if mirrored(self.hyperparams) and self.algo not in OFF_POLICY:
            raise UsageError(
                f"mirror: {self.algo} has no replay buffer to store mirror images in; "
                f"it is for {', '.join(sorted(OFF_POLICY))}"
            )
        entropy_decay(self.hyperparams, self.algo)
        noise_color_until(self.hyperparams)
        if N_STEPS_AFTER_KEY in self.hyperparams and self.algo not in OFF_POLICY:
            raise UsageError(
                f"{N_STEPS_AFTER_KEY}: {self.algo} has no n-step returns to shorten; it is "
                f"for {', '.join(sorted(OFF_POLICY))}"
            )
        n_steps_after(self.hyperparams)
        if reward_time_step(self.hyperparams) is not None:
            self._check_control_step()
        _check_ranges(self.hyperparams)
        qualified_env_id(self.env)
        push_curriculum(self.hyperparams, self.env_pushes)
        groups = hard_draws(self.hyperparams, self.n_envs)
        if groups is not None:
            self._check_hard_draws([realism for _, realism in groups])
        if self.trained_agent:
            self._check_trained_agent(Path(self.trained_agent))

    def _check_hard_draws(self, groups: list[dict[str, Any]]) -> None:
        """The env refuses ranges outside its own; ask one env now, not every worker later."""
        env = make_env(self.env, self.env_kwargs)
        own = getattr(env.unwrapped, "realism", None)
        try:
            for realism in groups:
                env.unwrapped.narrow_realism(realism)
                env.unwrapped.realism = own  # each group narrows the env's own ranges
        except (AttributeError, ValueError) as error:
            raise UsageError(f"{HARD_DRAWS_KEY}: {error}") from error
        finally:
            env.close()

    def _check_control_step(self) -> None:
        """reward_time_step reads the env's ``dt`` at every step; refuse an env without one
        now, not at the first step of training."""
        env = make_env(self.env, self.env_kwargs)
        try:
            dt = getattr(env.unwrapped, "dt", None)
        finally:
            env.close()
        if not isinstance(dt, (int, float)) or not dt > 0:
            raise UsageError(
                f"{REWARD_TIME_STEP_KEY}: {self.env} has no control step to scale by "
                "(its unwrapped env has no dt in seconds)"
            )

    def _check_trained_agent(self, path: Path) -> None:
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
        """From a config.yml. Keys that older versions wrote and this one dropped are
        ignored: runs kept in benchmarks/results carry one (``overlap_updates``)."""
        fields = {field.name for field in dataclasses.fields(cls)}
        return cls(**{key: value for key, value in values.items() if key in fields})


def _whole_number(value: Any, name: str) -> int:
    """``value`` as an int when it is one (3, 3.0, "3e5"), never by truncating 250.9."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if isinstance(value, bool) or not number.is_integer():
        raise UsageError(f"{name}={value!r}: must be a whole number")
    return int(number)


def _check_device(device: str) -> None:
    """SB3 runs a CUDA device that is not there on the CPU, while config.yml would say
    cuda: refuse instead, as a device torch does not know."""
    import torch

    try:
        wanted = torch.device(device) if device != "auto" else None
    except (RuntimeError, TypeError) as error:
        raise UsageError(f"--device {device!r}: not a torch device (auto, cpu, cuda)") from error
    if wanted is not None and wanted.type == "cuda" and not torch.cuda.is_available():
        raise UsageError(f"--device {device}: torch sees no CUDA device here; use cpu or auto")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _check_ranges(hyperparams: dict[str, Any]) -> None:
    """What SB3 accepts and only fails on later, at the first gradient step or never: a
    batch of 0, a buffer smaller than a batch, gamma or tau outside (0, 1]."""
    rules = {
        "batch_size": (
            lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1,
            "an integer >= 1",
        ),
        "gamma": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
        "tau": (lambda v: _is_number(v) and 0 < v <= 1, "a number in (0, 1]"),
        # -1: as many gradient steps as env steps collected (SB3's convention)
        "gradient_steps": (lambda v: _is_int(v) and (v >= 1 or v == -1), "an integer >= 1, or -1"),
        "learning_starts": (lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
        "n_steps": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
        "train_freq": (lambda v: not _is_number(v) or (_is_int(v) and v >= 1), "an integer >= 1"),
    }
    for name, (valid, rule) in rules.items():
        if name in hyperparams and not valid(hyperparams[name]):
            raise UsageError(f"--hyperparams {name}={hyperparams[name]!r}: must be {rule}")
    buffer, batch = hyperparams.get("buffer_size"), hyperparams.get("batch_size", 1)
    if buffer is not None and not (isinstance(buffer, int) and buffer >= batch):
        raise UsageError(
            f"--hyperparams buffer_size={buffer!r}: must be an integer >= batch_size ({batch})"
        )
