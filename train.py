"""Train an SB3 / sb3-contrib agent on a gymnasium env (SAC on MinitaurBulletEnv-v0 by default).

Each run gets its own folder, ``<log-folder>/<algo>/<env>_<N>/``, holding the resolved
config and command line, evaluations.npz, best_model.zip, checkpoints (model, replay
buffer, VecNormalize), monitor and progress CSVs, the final model, a learning-curve
PNG and policy videos. ``--resume RUN_DIR [-n N]`` continues a run from its newest
checkpoint (to N steps). Ctrl-C and SIGTERM save a checked checkpoint first.

The work is done by ``minitaur_env.training.Experiment``; this script parses flags.
"""

from __future__ import annotations

import argparse
import sys

from minitaur_env.training import PROGRESS_MODES, VEC_ENVS, OneLineErrorParser, commands
from minitaur_env.training.cli import add_experiment_arguments, given_flags, suppress_defaults


def build_parser(without_defaults: bool = False) -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_experiment_arguments(parser)
    add = parser.add_argument
    add("--seed", type=int, default=0, help="random seed of envs and networks (default: 0)")
    add("--n-envs", type=int, help="parallel training envs (default: from the config, else 1)")
    add(
        "--vec-env",
        default="auto",
        choices=VEC_ENVS,
        help="auto: several envs grouped over the CPU cores, one env in this process",
    )
    add("--save-freq", type=int, default=5_000, help="checkpoint every N env steps; 0: never")
    add("--video-freq", type=int, default=0, help="record a policy video every N env steps")
    add("--video-length", type=int, default=1000, help="max env steps per video (default: 1000)")
    add("-f", "--log-folder", default="logs", help="root of the run folders (default: logs)")
    add("--tensorboard-log", default=None, help="TensorBoard log folder (default: none)")
    add(
        "--progress",
        nargs="?",
        const="bar",
        default="auto",
        choices=PROGRESS_MODES,
        help="auto (default): a progress bar on a terminal, else one line per evaluation",
    )
    add("--device", default="auto", help="torch device: auto, cpu, cuda (default: auto)")
    add(
        "--num-threads",
        type=int,
        default=0,
        help="torch CPU threads; 0 (default): 1 for MLP policies, torch's default for CNNs "
        "(more threads spin against any other busy process)",
    )
    add(
        "-i",
        "--trained-agent",
        metavar="MODEL_ZIP",
        help="start from this model (and its VecNormalize statistics), e.g. a shipped one",
    )
    add(
        "--trust-pickle",
        action="store_true",
        help="with -i: also load the model's pickled entries, VecNormalize pickle and "
        "replay buffer (a pickle can run code from the file: only files you trust)",
    )
    add(
        "--resume",
        metavar="RUN_DIR",
        help="continue this run from its newest checkpoint (reads the run folder's own "
        "pickles: resume only run folders you trust)",
    )
    add("-v", "--verbose", type=int, default=0, help="1: SB3's logger tables too (default: 0)")
    return suppress_defaults(parser) if without_defaults else parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser().parse_args(argv)
    return commands.train(args, argv, given_flags(build_parser, argv))


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # before main() could take over, e.g. during imports
        sys.exit(130)
