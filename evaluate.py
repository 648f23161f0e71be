"""Evaluate a trained policy: statistics over N episodes, and optionally its video.

With no arguments: the best shipped policy in pretrained/, else the best model of the
most recent run under logs/. Evaluation always reports the env's raw return.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from datetime import datetime
from pathlib import Path

from minitaur_env.training import UsageError
from minitaur_env.training.algorithms import ALGORITHMS
from minitaur_env.training.cli import OneLineErrorParser

DEFAULT_ENV = "MinitaurBulletEnv-v0"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = OneLineErrorParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add = parser.add_argument
    which = parser.add_argument_group("which policy")
    which.add_argument("--model", type=Path, help="a model .zip (overrides the options below)")
    which.add_argument("-f", "--log-folder", help="root of the run folders, e.g. logs")
    which.add_argument("--algo", choices=list(ALGORITHMS), help="algorithm (default: from model)")
    which.add_argument("--env", help=f"env id (default: the model's, else {DEFAULT_ENV})")
    which.add_argument("--exp-id", type=int, default=0, help="run number N; 0: the latest")
    load = which.add_mutually_exclusive_group()
    load.add_argument("--load-best", action="store_true", help="the run's best_model.zip")
    load.add_argument("--load-checkpoint", type=int, metavar="N", help="rl_model_N_steps.zip")
    load.add_argument("--load-last-checkpoint", action="store_true", help="the newest checkpoint")
    add("--episodes", type=int, default=20, help="evaluation episodes (default: 20)")
    add("--seed", type=int, default=12345, help="seed of episode 0; episode i uses seed + i")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--deterministic",
        dest="deterministic",
        action="store_true",
        default=True,
        help="act with the policy's mean action (default)",
    )
    mode.add_argument(
        "--stochastic", dest="deterministic", action="store_false", help="sample actions"
    )
    add("--json", type=Path, metavar="PATH", help="also write the statistics as JSON")
    add("--env-kwargs", nargs="+", metavar="KEY=VALUE", help="keyword arguments for the env")
    add("--render-video", action="store_true", help="write an mp4 of --video-episodes episodes")
    add("-o", "--output", type=Path, help="video path (default: videos/<env>_<algo>_<time>.mp4)")
    add("--video-episodes", type=int, default=3, help="episodes in the video (default: 3)")
    add("--video-fps", type=float, default=50.0, help="frames per second, real time (default 50)")
    add("--width", type=int, default=640, help="video width (default: 640)")
    add("--height", type=int, default=480, help="video height (default: 480)")
    add("--gif", action="store_true", help="also write a small GIF beside the mp4")
    add("--gui", action="store_true", help="watch --video-episodes episodes in the PyBullet GUI")
    add("--device", default="cpu", help="torch device (default: cpu)")
    args = parser.parse_args(argv)
    if args.episodes < 0:
        parser.error("--episodes must be >= 0")
    if args.video_episodes < 1:
        parser.error("--video-episodes must be >= 1")
    if not (0 < args.width <= 4096 and 0 < args.height <= 4096):
        parser.error("--width and --height must be in 1..4096")
    if args.video_fps <= 0:
        parser.error("--video-fps must be > 0")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from minitaur_env.training.envs import make_env
    from minitaur_env.training.evaluation import (
        find_model,
        format_table,
        load_policy,
        run_episodes,
        summarize,
    )
    from minitaur_env.training.hyperparams import parse_overrides
    from minitaur_env.training.run_folder import ensure_writable
    from minitaur_env.training.video import atomic_path, record_video

    try:
        path = args.model or find_model(
            args.log_folder,
            args.algo,
            args.env,
            args.exp_id,
            args.load_best,
            args.load_checkpoint,
            args.load_last_checkpoint,
        )
        policy = load_policy(Path(path), args.algo, args.device)
        env_id = args.env or policy.env_id or DEFAULT_ENV
        # Judge on the registered episode length, whatever the training run used.
        env_kwargs = {k: v for k, v in policy.env_kwargs.items() if k != "max_episode_steps"}
        env_kwargs.update(parse_overrides(args.env_kwargs, "--env-kwargs"))
        video_path = None
        if args.render_video:
            stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
            default = Path("videos") / f"{env_id.split(':')[-1]}_{policy.algo}_{stamp}.mp4"
            video_path = args.output or default
            ensure_writable(video_path.parent)
        if args.json is not None:
            ensure_writable(args.json.parent)
        details = [policy.algo] + (["sbx"] if policy.backend == "sbx" else [])
        if policy.normalizer is not None and policy.normalizer.norm_obs:
            details.append("observations normalized")
        print(f"policy: {policy.path} ({', '.join(details)}) on {env_id}")

        results = None
        if args.episodes:
            env = make_env(env_id, env_kwargs)
            try:
                records = run_episodes(policy, env, args.episodes, args.seed, args.deterministic)
            finally:
                env.close()
            summary = summarize(records)
            mode = "deterministic" if args.deterministic else "stochastic"
            print(f"{args.episodes} episodes, {mode}, seeds {args.seed}..")
            print(format_table(summary, args.episodes))
            results = {
                "model": str(policy.path),
                "algo": policy.algo,
                "env": env_id,
                "episodes": args.episodes,
                "seed": args.seed,
                "deterministic": args.deterministic,
                "summary": summary,
                "per_episode": records,
            }
            if args.json is not None:
                with atomic_path(args.json) as temp:
                    temp.write_text(json.dumps(results, indent=2))
                print(f"statistics: {args.json}")

        if video_path is not None:
            env = make_env(
                env_id, env_kwargs, render_mode="rgb_array", width=args.width, height=args.height
            )
            started = time.perf_counter()
            try:
                stats = record_video(
                    env,
                    lambda obs: policy.act(obs, args.deterministic),
                    video_path,
                    episodes=args.video_episodes,
                    max_steps=env.spec.max_episode_steps or 1000,
                    fps=args.video_fps,
                    seed=args.seed,
                    gif_path=video_path.with_suffix(".gif") if args.gif else None,
                )
            finally:
                env.close()
            elapsed = time.perf_counter() - started
            gif = f"; gif: {video_path.with_suffix('.gif')}" if args.gif else ""
            print(
                f"video: {video_path} ({stats['frames']} frames at {stats['fps']:g} fps, "
                f"{elapsed:.1f} s to write){gif}"
            )
        if args.gui:
            env = make_env(env_id, env_kwargs, render_mode="human")
            try:
                run_episodes(policy, env, args.video_episodes, args.seed, args.deterministic)
            finally:
                env.close()
    except UsageError as error:
        print(f"evaluate.py: error: {error}", file=sys.stderr)
        return 2
    except RuntimeError as error:  # e.g. the GUI without a display
        print(f"evaluate.py: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("evaluate.py: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
