"""Train an SB3 / sb3-contrib agent on a gymnasium env (SAC on MinitaurBulletEnv-v0 by default).

Each run gets its own folder, ``<log-folder>/<algo>/<env>_<N>/``, holding the resolved
config and command line, evaluations.npz, best_model.zip, checkpoints (model, replay
buffer, VecNormalize), monitor and progress CSVs, the final model, a learning-curve
PNG and policy videos. ``--resume RUN_DIR`` continues a run from its last checkpoint.
"""

from __future__ import annotations

import argparse
import pickle
import re
import shlex
import shutil
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from minitaur_env.training import UsageError
from minitaur_env.training.cli import OneLineErrorParser
from minitaur_env.training.config import (
    ALGORITHMS,
    BACKENDS,
    OFF_POLICY,
    RUN_KEYS,
    VEC_ENVS,
    algorithm_class,
    load_hyperparams,
    load_model,
    parse_overrides,
)
from minitaur_env.training.runs import (
    checkpoints,
    ensure_writable,
    new_run_dir,
    replay_buffer_path,
    save_checkpoint,
    vecnormalize_path,
)

DEFAULT_ENV = "MinitaurBulletEnv-v0"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = OneLineErrorParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add = parser.add_argument
    add("--algo", default="sac", choices=list(ALGORITHMS), help="RL algorithm (default: sac)")
    add(
        "--backend",
        default="sb3",
        choices=list(BACKENDS),
        help="sb3 (PyTorch) or sbx (SB3's JAX implementations: sac td3 ppo tqc crossq)",
    )
    add("--env", default=DEFAULT_ENV, help=f"gymnasium env id (default: {DEFAULT_ENV})")
    add("-n", "--n-timesteps", type=int, help="env steps to train (default: from the config)")
    add("--seed", type=int, default=0, help="random seed of envs and networks (default: 0)")
    add("--n-envs", type=int, help="parallel training envs (default: from the config, else 1)")
    add(
        "--vec-env",
        default="auto",
        choices=VEC_ENVS,
        help="auto: several envs grouped over the CPU cores, one env in this process",
    )
    add(
        "--overlap-updates",
        action="store_true",
        help="off-policy only: step the env in a worker process while the gradient steps "
        "run (same settings; actions lag the policy by one round of updates)",
    )
    add("--eval-freq", type=int, default=10_000, help="evaluate every N env steps; 0: never")
    add("--eval-episodes", type=int, default=20, help="episodes per evaluation (default: 20)")
    add("--save-freq", type=int, default=5_000, help="checkpoint every N env steps; 0: never")
    add("--video-freq", type=int, default=0, help="record a policy video every N env steps")
    add("--video-length", type=int, default=1000, help="max env steps per video (default: 1000)")
    add("-f", "--log-folder", default="logs", help="root of the run folders (default: logs)")
    add("--tensorboard-log", default=None, help="TensorBoard log folder (default: none)")
    add("--progress", action="store_true", help="show a progress bar")
    add("--device", default="auto", help="torch device: auto, cpu, cuda (default: auto)")
    add("--num-threads", type=int, default=0, help="torch CPU threads; 0: torch's default")
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
    add("--env-kwargs", nargs="+", metavar="KEY=VALUE", help="keyword arguments for the env")
    add("--resume", metavar="RUN_DIR", help="continue this run from its last checkpoint")
    add("-v", "--verbose", type=int, default=1, help="SB3 verbosity (default: 1)")
    args = parser.parse_args(argv)
    for name in ("eval_freq", "save_freq", "video_freq"):
        if getattr(args, name) < 0:
            parser.error(f"--{name.replace('_', '-')} must be >= 0")
    for name in ("eval_episodes", "video_length"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.n_timesteps is not None and args.n_timesteps < 1:
        parser.error("-n/--n-timesteps must be >= 1")
    if args.overlap_updates and args.algo not in OFF_POLICY:
        parser.error(f"--overlap-updates needs an off-policy algorithm, not {args.algo}")
    if args.overlap_updates and args.vec_env not in ("auto", "subproc"):
        parser.error("--overlap-updates steps the env in a SubprocVecEnv; drop --vec-env")
    return args


def resolve_config(args: argparse.Namespace) -> dict[str, Any]:
    """Everything a run depends on, in one dict (written to config.yml)."""
    hyperparams = load_hyperparams(args.algo, args.env, args.conf_file, args.config)
    hyperparams.update(parse_overrides(args.hyperparams, "--hyperparams"))
    run = {key: hyperparams.pop(key) for key in RUN_KEYS if key in hyperparams}
    if args.n_timesteps is not None:
        run["n_timesteps"] = args.n_timesteps
    if args.n_envs is not None:
        run["n_envs"] = args.n_envs
    return {
        "algo": args.algo,
        "config": args.config or args.env,
        "backend": args.backend,
        "env": args.env,
        "env_kwargs": parse_overrides(args.env_kwargs, "--env-kwargs"),
        "seed": args.seed,
        "n_timesteps": int(run.get("n_timesteps", 100_000)),
        "n_envs": int(run.get("n_envs", 1)),
        "vec_env": args.vec_env,
        "overlap_updates": args.overlap_updates,
        "normalize": run.get("normalize", False),
        "policy": run.get("policy", "MlpPolicy"),
        "hyperparams": hyperparams,
        "eval_freq": args.eval_freq,
        "eval_episodes": args.eval_episodes,
        "save_freq": args.save_freq,
        "video_freq": args.video_freq,
        "video_length": args.video_length,
        "device": args.device,
        "tensorboard_log": args.tensorboard_log,
    }


def build(config: dict[str, Any], run_dir: Path, resume_from: int | None):
    """The training env, the model (fresh or from a checkpoint) and the eval env."""
    from stable_baselines3.common.vec_env import VecNormalize

    from minitaur_env.training.envs import make_eval_env, make_training_env
    from minitaur_env.training.pipeline import overlapped

    algo_cls = algorithm_class(config["algo"], config.get("backend", "sb3"))
    overlap = config.get("overlap_updates", False)
    if overlap:
        algo_cls = overlapped(algo_cls)
    seed = config["seed"] + (resume_from or 0)  # new episodes after a resume, same seed
    env = make_training_env(
        config["env"],
        n_envs=config["n_envs"],
        seed=seed,
        env_kwargs=config["env_kwargs"],
        vec_env=config["vec_env"],
        monitor_dir=str(run_dir / "monitor"),
        append_monitor=resume_from is not None,
        overlap_updates=overlap,
    )
    normalize = config["normalize"]
    if normalize:
        if resume_from is not None and vecnormalize_path(run_dir, resume_from).exists():
            env = VecNormalize.load(str(vecnormalize_path(run_dir, resume_from)), env)
        else:
            options = normalize if isinstance(normalize, dict) else {}
            gamma = config["hyperparams"].get("gamma", 0.99)
            env = VecNormalize(env, gamma=gamma, **options)
    eval_env = make_eval_env(
        config["env"], seed=config["seed"] + 10_000, env_kwargs=config["env_kwargs"],
        normalize=normalize,
    )  # fmt: skip

    if resume_from is not None:
        model_path = run_dir / "checkpoints" / f"rl_model_{resume_from}_steps.zip"
        model = load_model(algo_cls, model_path, env=env, device=config["device"])
        buffer = replay_buffer_path(run_dir, resume_from)
        if config["algo"] in OFF_POLICY:
            if buffer.exists():
                model.load_replay_buffer(buffer)
            else:
                print(f"no replay buffer saved at step {resume_from}: starting with an empty one")
        model.tensorboard_log = config["tensorboard_log"]
    else:
        try:
            model = algo_cls(
                config["policy"],
                env,
                seed=config["seed"],
                device=config["device"],
                tensorboard_log=config["tensorboard_log"],
                verbose=0,
                **config["hyperparams"],
            )
        except (TypeError, ValueError, AssertionError) as error:
            raise UsageError(f"invalid hyperparameters for {config['algo']}: {error}") from error
    return env, model, eval_env


def build_callbacks(config: dict[str, Any], run_dir: Path, model, eval_env, resumed: bool):
    from stable_baselines3.common.callbacks import CallbackList, EvalCallback

    from minitaur_env.training.callbacks import (
        DivergenceGuardCallback,
        LeanCheckpointCallback,
        SaveVecNormalizeCallback,
        VideoRecorderCallback,
    )

    n_envs = config["n_envs"]
    # Checking weights just before each checkpoint keeps a diverged model out of them.
    check_freq = config["save_freq"] or 10_000
    callbacks: list = [DivergenceGuardCallback(check_freq=check_freq)]
    if config["save_freq"]:
        callbacks.append(
            LeanCheckpointCallback(
                save_freq=max(config["save_freq"] // n_envs, 1),
                save_path=str(run_dir / "checkpoints"),
                save_replay_buffer=config["algo"] in OFF_POLICY,
                save_vecnormalize=bool(config["normalize"]),
            )
        )
    if config["eval_freq"]:
        evaluation = EvalCallback(
            eval_env,
            n_eval_episodes=config["eval_episodes"],
            eval_freq=max(config["eval_freq"] // n_envs, 1),
            log_path=str(run_dir),
            best_model_save_path=str(run_dir),
            deterministic=True,
            callback_on_new_best=SaveVecNormalizeCallback(run_dir / "best_model_vecnormalize.pkl")
            if config["normalize"]
            else None,
            verbose=config.get("verbose", 1),
        )
        evaluations = run_dir / "evaluations.npz"
        if resumed and evaluations.exists():
            with np.load(evaluations) as data:
                evaluation.evaluations_timesteps = list(data["timesteps"])
                evaluation.evaluations_results = [list(r) for r in data["results"]]
                evaluation.evaluations_length = [list(r) for r in data["ep_lengths"]]
            means = [np.mean(r) for r in evaluation.evaluations_results]
            evaluation.best_mean_reward = float(max(means)) if means else -np.inf
        callbacks.append(evaluation)
    if config["video_freq"]:
        callbacks.append(
            VideoRecorderCallback(
                config["env"],
                config["env_kwargs"],
                video_freq=config["video_freq"],
                video_length=config["video_length"],
                run_videos_dir=run_dir / "videos",
                shared_dir=Path("videos"),
                name_prefix=f"{Path(run_dir).parent.name}-{Path(run_dir).name}",
                seed=config["seed"] + 20_000,
                verbose=1,
            )
        )
    return CallbackList(callbacks)


def configure_logger(model, run_dir: Path, config: dict[str, Any], resumed_at: int | None):
    from stable_baselines3.common.logger import (
        CSVOutputFormat,
        HumanOutputFormat,
        Logger,
        TensorBoardOutputFormat,
    )

    # Keep the first session's progress.csv; each resumed session writes its own.
    name = "progress.csv" if resumed_at is None else f"progress-resumed-at-{resumed_at}.csv"
    formats: list = [CSVOutputFormat(str(run_dir / name))]
    if config["verbose"] >= 1:
        formats.append(HumanOutputFormat(sys.stdout))
    if config["tensorboard_log"]:
        folder = Path(config["tensorboard_log"]) / f"{run_dir.parent.name}-{run_dir.name}"
        formats.append(TensorBoardOutputFormat(str(folder)))
    model.set_logger(Logger(str(run_dir), formats))


def prepare_run(args: argparse.Namespace) -> tuple[dict[str, Any], Path, int | None]:
    """(config, run folder, checkpoint step to resume from or None)."""
    if args.resume:
        run_dir = Path(args.resume)
        config_path = run_dir / "config.yml"
        if not config_path.is_file():
            raise UsageError(f"--resume {run_dir}: no config.yml there; is it a run folder?")
        config = yaml.safe_load(config_path.read_text())
        found = checkpoints(run_dir)
        if not found:
            raise UsageError(f"--resume {run_dir}: no checkpoint in {run_dir / 'checkpoints'}")
        ensure_writable(run_dir)
        return config, run_dir, found[0][0]
    config = resolve_config(args)
    from minitaur_env.training.envs import qualified_env_id

    if config["tensorboard_log"]:
        try:
            import tensorboard  # noqa: F401
        except ImportError as error:
            raise UsageError(
                "--tensorboard-log needs TensorBoard: pip install tensorboard"
            ) from error

    qualified_env_id(config["env"])  # fail on an unknown id before creating folders
    algorithm_class(config["algo"], config["backend"])
    run_dir = new_run_dir(args.log_folder, config["algo"], config["env"])
    (run_dir / "config.yml").write_text(yaml.safe_dump(config, sort_keys=False))
    return config, run_dir, None


def load_latest_usable(config, run_dir: Path, start: int):
    """Build from the newest checkpoint that loads (a kill -9 can leave a torn one)."""
    for steps, path in checkpoints(run_dir):
        if steps > start:
            continue
        try:
            return (*build(config, run_dir, steps), steps)
        except (
            ValueError,
            OSError,
            EOFError,
            KeyError,
            zipfile.BadZipFile,
            pickle.PickleError,
        ) as error:
            # A kill -9 during a save leaves a torn zip or pickle behind.
            print(f"skipping unreadable checkpoint {path.name}: {error}", file=sys.stderr)
    raise UsageError(f"no readable checkpoint in {run_dir / 'checkpoints'}")


def summarize(run_dir: Path, model, elapsed: float, trained_steps: int, env_id: str) -> None:
    import gymnasium as gym

    from minitaur_env.training.plotting import plot_learning_curve

    lines = [f"run folder: {run_dir}"]
    lines.append(
        f"env steps: {model.num_timesteps} ({trained_steps} this session, "
        f"{elapsed / 60:.1f} min, {trained_steps / max(elapsed, 1e-9):.0f} steps/s)"
    )
    evaluations = run_dir / "evaluations.npz"
    if evaluations.exists():
        with np.load(evaluations) as data:
            results = data["results"]
            steps = data["timesteps"]
        if len(steps):
            means = results.mean(axis=1)
            best = int(np.argmax(means))
            lines.append(
                f"last eval: {means[-1]:.2f} +- {results[-1].std():.2f} at {steps[-1]} steps; "
                f"best: {means[best]:.2f} at {steps[best]} steps"
            )
            threshold = gym.spec(env_id).reward_threshold
            plot_learning_curve(
                evaluations,
                run_dir / "learning_curve.png",
                title=f"{run_dir.parent.name} on {env_id}",
                reward_threshold=threshold,
            )
            lines.append(f"learning curve: {run_dir / 'learning_curve.png'}")
    print("\n".join(lines))


def set_torch_threads(num_threads: int, config: dict[str, Any]) -> None:
    """``--num-threads``, else one thread when grouped envs use the other cores."""
    import torch

    from minitaur_env.training.envs import resolve_vec_env

    if num_threads > 0:
        torch.set_num_threads(num_threads)
    elif resolve_vec_env(config["vec_env"], config["n_envs"]) == "grouped":
        # torch's idle threads spin-wait on the workers' cores: with PPO's 8 envs that
        # cost 40% of the speed.
        torch.set_num_threads(1)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from minitaur_env.training.callbacks import TrainingDiverged

    run_dir = None
    try:
        config, run_dir, resume_from = prepare_run(args)
        set_torch_threads(args.num_threads, config)
        fresh = resume_from is None
        config["verbose"] = args.verbose
        if fresh:
            env, model, eval_env = build(config, run_dir, None)
        else:
            env, model, eval_env, resume_from = load_latest_usable(config, run_dir, resume_from)
        with (run_dir / "command.txt").open("a") as command:
            command.write(shlex.join([sys.argv[0], *sys.argv[1:]]) + "\n")
        configure_logger(model, run_dir, config, resume_from)
        callbacks = build_callbacks(config, run_dir, model, eval_env, not fresh)
    except UsageError as error:
        if run_dir is not None and not args.resume:
            shutil.rmtree(run_dir, ignore_errors=True)  # a run that never started
        print(f"train.py: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if run_dir is not None and not args.resume:
            shutil.rmtree(run_dir, ignore_errors=True)
        print("\ninterrupted before training started; nothing was saved", file=sys.stderr)
        return 130

    start_steps = model.num_timesteps
    remaining = config["n_timesteps"] - start_steps
    print(
        f"training {config['algo']} on {config['env']} for {remaining} steps "
        f"(from {start_steps}) into {run_dir}"
    )
    started = time.perf_counter()
    status = 0
    try:
        if remaining > 0:
            model.learn(
                total_timesteps=remaining,
                callback=callbacks,
                reset_num_timesteps=resume_from is None,
                progress_bar=args.progress,
            )
    except KeyboardInterrupt:
        path = save_checkpoint(model, run_dir, model.num_timesteps)
        print(f"\ninterrupted: saved {path} (resume with --resume {run_dir})", file=sys.stderr)
        status = 130
    except (TrainingDiverged, ValueError) as error:
        # VecCheckNan and torch's distributions raise ValueError on NaN/inf values.
        message = " ".join(str(error).split())
        if not isinstance(error, TrainingDiverged) and not re.search(r"\b(nan|inf)", message, re.I):
            raise
        last = checkpoints(run_dir)
        kept = f"last good checkpoint: {last[0][1]}" if last else "no checkpoint was saved"
        print(f"train.py: error: training diverged: {message[:300]}; {kept}", file=sys.stderr)
        return 1
    finally:
        env.close()
        eval_env.close()
    elapsed = time.perf_counter() - started
    if status == 0:
        model.save(run_dir / "final_model.zip")
        if config["normalize"]:
            model.get_vec_normalize_env().save(str(run_dir / "final_model_vecnormalize.pkl"))
    summarize(run_dir, model, elapsed, model.num_timesteps - start_steps, config["env"])
    return status


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # before main() could take over, e.g. during imports
        sys.exit(130)
