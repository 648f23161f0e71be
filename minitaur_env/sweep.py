"""Many training runs on Ray Tune: a configuration over seeds, or a hyperparameter search.

    python -m minitaur_env.sweep --seeds 5 -n 300000                 # 5 seeds of default SAC
    python -m minitaur_env.sweep --search space.yml --trials 20 --scheduler asha
    python -m minitaur_env.sweep -f sweeps --name my-sweep --resume   # after Ctrl-C
    python -m minitaur_env.sweep --summarize sweeps/my-sweep          # the table again
    python -m minitaur_env.sweep --summarize sweeps/a sweeps/a-more-seeds  # one table
    RAY_ADDRESS=head:6379 python -m minitaur_env.sweep -f /shared/sweeps ...   # a cluster

Each trial writes the run folder train.py writes, under ``<-f>/<name>/runs/<trial>/``.
At the end it prints (and writes to ``<-f>/<name>/summary.csv``) one row per
configuration: seeds done and failed, final and best eval return per seed, median, IQM
with its 95 % bootstrap CI, and steps and minutes to 5 and 15 (``--milestones``);
``curves.png`` shows the IQM learning curves. Needs ``pip install 'minitaur-env[ray]'``.
"""

from __future__ import annotations

import argparse
import sys

from minitaur_env.training import OneLineErrorParser, UsageError, commands, missing_dependency
from minitaur_env.training.cli import add_experiment_arguments


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = OneLineErrorParser(
        prog="python -m minitaur_env.sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_experiment_arguments(parser)
    add = parser.add_argument
    add("--seeds", nargs="+", type=int, default=[3], help="N seeds (0..N-1), or a list: 0 4 7")
    add("--first-seed", type=int, default=0, help="with --seeds N: seeds K..K+N-1, e.g. one seed")
    add("--search", metavar="FILE.yml", help="search this YAML space with Optuna TPE")
    add("--trials", type=int, default=8, help="configurations a --search samples (default: 8)")
    add("--scheduler", default="none", choices=["none", "asha"], help="asha: stop bad trials")
    add("--cpus-per-trial", type=float, default=1.0, help="CPUs reserved per trial (default 1)")
    add("--gpus-per-trial", type=float, default=0.0, help="GPUs reserved per trial (default 0)")
    add("--max-concurrent", type=int, default=0, help="trials at once; 0: as resources allow")
    add("--save-freq", type=int, default=10_000, help="trial checkpoint every N env steps")
    add("-f", "--storage", default="sweeps", help="storage folder, shared on a cluster")
    add("--name", default=None, help="sweep name (default: <algo>-<env>)")
    add("--resume", action="store_true", help="continue the interrupted sweep -f/--name")
    add(
        "--address",
        default=None,
        help="an existing Ray cluster (default: $RAY_ADDRESS, else local)",
    )
    add(
        "--summarize", nargs="+", metavar="SWEEP_DIR",
        help="only print and write a finished sweep's table; several folders (more seeds "
        "of one configuration) make one table, written into the first",
    )  # fmt: skip
    add(
        "--milestones",
        nargs="+",
        type=float,
        metavar="RETURN",
        help="returns whose first crossing the table reports in steps and minutes "
        "(default: 5 15 on the Minitaur ids, else the env's reward threshold)",
    )
    return parser.parse_args(argv)


SWEEP_MODULES = ("ray", "optuna", "rliable", "arch", "pandas")  # the ray extra


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    try:
        return commands.sweep(args, argv)
    except ModuleNotFoundError as error:
        if error.name not in SWEEP_MODULES:  # the env-only install: no SB3, torch, ...
            print(missing_dependency("python -m minitaur_env.sweep", error), file=sys.stderr)
            return 1
        print(
            f"sweep: error: {error.name} is not installed; sweeps need the ray extra: "
            "pip install 'minitaur-env[ray]'",
            file=sys.stderr,
        )
        return 2
    except UsageError as error:
        print(f"sweep: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sweep: interrupted; continue it with --resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
