"""Evaluate a trained policy: statistics over N episodes, and optionally its video.

With no arguments: the best shipped policy in pretrained/, else the best model of the
most recent run under logs/. Evaluation always reports the env's raw return.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from minitaur_env.training import ALGORITHM_NAMES, DEFAULT_ENV, OneLineErrorParser, commands


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = OneLineErrorParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add = parser.add_argument
    which = parser.add_argument_group("which policy")
    which.add_argument("--model", type=Path, help="a model .zip (overrides the options below)")
    which.add_argument("-f", "--log-folder", help="root of the run folders, e.g. logs")
    which.add_argument("--algo", choices=ALGORITHM_NAMES, help="algorithm (default: from model)")
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
    add(
        "--realism",
        action="store_true",
        help="also the shares of steps with a motor at its torque or velocity limit, and "
        "the foot slip (minitaur_env.realism)",
    )
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
    add(
        "--trust-pickle",
        action="store_true",
        help="also load pickles: cloudpickled entries of the zip, a vecnormalize.pkl without "
        "its vecnormalize.json, SBX models. A pickle can run code from the file: only "
        "files you trust (by default none is unpickled)",
    )
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
    return commands.evaluate(parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
