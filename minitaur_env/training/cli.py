"""Command-line pieces shared by train.py and the sweep: flags, config, one-line errors."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from minitaur_env.training import ALGORITHM_NAMES, BACKENDS, DEFAULT_ENV, UsageError


def add_experiment_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags that define what is trained: shared by train.py and the sweep."""
    add = parser.add_argument
    add("--algo", default="sac", choices=list(ALGORITHM_NAMES), help="RL algorithm (default: sac)")
    add(
        "--backend",
        default="sb3",
        choices=list(BACKENDS),
        help="sb3 (PyTorch) or sbx (SB3's JAX implementations: sac td3 ppo tqc crossq)",
    )
    add("--env", default=DEFAULT_ENV, help=f"gymnasium env id (default: {DEFAULT_ENV})")
    add("-n", "--n-timesteps", type=int, help="env steps to train (default: from the config)")
    add(
        "--eval-freq",
        type=int,
        help="evaluate every N env steps; 0: never (default: the entry's, else 10000)",
    )
    add(
        "--eval-episodes",
        type=int,
        help="episodes per evaluation (default: the entry's, else 10)",
    )
    add("--conf-file", default=None, help="YAML hyperparameter file (default: the packaged one)")
    add(
        "--config",
        metavar="ENTRY",
        help="a named entry of the hyperparameter file instead of the env's, e.g. tutorial",
    )
    add(
        "--hyperparams",
        nargs="+",
        metavar="KEY=VALUE",
        help="override hyperparameters, as YAML values: "
        "learning_rate=1e-3 'policy_kwargs={net_arch: [64]}'",
    )
    add_env_kwargs(parser)


def add_env_kwargs(parser: argparse.ArgumentParser) -> None:
    """``--env-kwargs KEY=VALUE...``, as training, sweeps and evaluation all take it."""
    parser.add_argument(
        "--env-kwargs",
        nargs="+",
        metavar="KEY=VALUE",
        help="keyword arguments for the env, as YAML values: max_episode_steps=500 "
        "preset=tan2018 'realism={control_latency: 0.02}'",
    )


def config_from_args(args: argparse.Namespace, **settings: Any) -> Any:
    """An ExperimentConfig from the shared flags (plus ``settings`` for the other fields)."""
    from minitaur_env.training.config import ExperimentConfig
    from minitaur_env.training.hyperparams import parse_overrides

    return ExperimentConfig.resolve(
        args.algo,
        args.env,
        entry=args.config,
        conf_file=args.conf_file,
        hyperparams=parse_overrides(args.hyperparams, "--hyperparams"),
        n_timesteps=args.n_timesteps,
        backend=args.backend,
        env_kwargs=parse_overrides(args.env_kwargs, "--env-kwargs"),
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        **settings,
    )


def given_flags(build_parser: Callable[[bool], argparse.ArgumentParser], argv: list[str]) -> set:
    """The destinations of the flags that ``argv`` sets explicitly."""
    return set(vars(build_parser(True).parse_args(argv)))


def suppress_defaults(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The parser, with every default removed so that parsing shows what was typed."""
    for action in parser._actions:
        action.default = argparse.SUPPRESS
    return parser


# Flags that may accompany --resume: they change how a session runs, not what is trained.
HARMLESS_ON_RESUME = {
    "resume",
    "n_timesteps",
    "progress",
    "num_threads",
    "device",
    "verbose",
    "trust_pickle",
}
# Flags that name config.yml fields one to one.
CONFIG_FLAGS = (
    "algo",
    "backend",
    "env",
    "seed",
    "n_envs",
    "vec_env",
    "eval_freq",
    "eval_episodes",
    "save_freq",
    "video_freq",
    "video_length",
    "tensorboard_log",
    "trained_agent",
)


def resume_overrides(args: argparse.Namespace, given: set) -> dict[str, Any]:
    """What the flags given beside --resume ask of the run, to check against config.yml."""
    from minitaur_env.training.hyperparams import RUN_KEYS, parse_overrides

    overrides: dict[str, Any] = {}
    for name in sorted(given - HARMLESS_ON_RESUME):
        if name in CONFIG_FLAGS:
            overrides[name] = getattr(args, name)
        elif name in ("config", "conf_file", "log_folder"):
            flag = {"config": "--config", "conf_file": "--conf-file", "log_folder": "-f"}[name]
            raise UsageError(f"{flag} cannot be combined with --resume: the run keeps its own")
    if "hyperparams" in given:
        for key, value in parse_overrides(args.hyperparams, "--hyperparams").items():
            overrides[key if key in RUN_KEYS else f"hyperparams.{key}"] = value
    if "env_kwargs" in given:
        for key, value in parse_overrides(args.env_kwargs, "--env-kwargs").items():
            overrides[f"env_kwargs.{key}"] = value
    return overrides
