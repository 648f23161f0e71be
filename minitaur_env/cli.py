"""The ``minitaur`` command: training, evaluation, sweeps, shipping and export in one tool.

    minitaur train                                  # SAC on MinitaurBulletEnv-v0
    minitaur train --algo ppo --seed 2
    minitaur evaluate --render-video                # the best shipped policy, as an mp4
    minitaur sweep --seeds 5 -n 300000              # five seeds on Ray Tune
    minitaur ship RUN... --ship pretrained/sac/MinitaurBulletEnv-v0_1
    minitaur package RUN                            # a Hugging Face Hub folder
    minitaur onnx RUN -o policy.onnx                # the actor, with no torch to play it
    minitaur zoo record_video ...                   # an rl-baselines3-zoo script

``minitaur COMMAND --help`` lists a command's flags. ``train.py``, ``evaluate.py`` and
``python -m minitaur_env.<command>`` are the same commands under their older names.
This module holds every command's flags and the one place where a user's mistake
becomes one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from minitaur_env.training import (
    ALGORITHM_NAMES,
    DEFAULT_ENV,
    PROGRESS_MODES,
    VEC_ENVS,
    OneLineErrorParser,
    UsageError,
    missing_dependency,
)
from minitaur_env.training.cli import (
    add_env_kwargs,
    add_experiment_arguments,
    given_flags,
    suppress_defaults,
)
from minitaur_env.training.seeds import REPORT_SEED, SELECTION_SEED

# The modules of the ray extra: a sweep without them names the extra, not the train one.
SWEEP_MODULES = ("ray", "optuna", "rliable", "arch", "pandas")


def add_trust_pickle(parser: argparse.ArgumentParser, what: str = "in or beside the model") -> None:
    parser.add_argument(
        "--trust-pickle",
        action="store_true",
        help=f"also load pickles {what}; a pickle can run code from the file, so only "
        "files you trust (by default nothing is unpickled)",
    )


def labelled_files(items: list[str], flag: str) -> dict[str, Path]:
    """The LABEL=FILE values of a repeated flag, in their order (a benchmark's policies);
    a malformed one, a missing file or a label given twice is a UsageError."""
    files: dict[str, Path] = {}
    for item in items:
        label, sep, path = item.partition("=")
        if not sep or not label or not Path(path).is_file():
            raise UsageError(f"{flag} expects LABEL=FILE with an existing file, got {item!r}")
        if label in files:
            raise UsageError(f"{flag} label {label!r} is given twice; each needs its own")
        files[label] = Path(path)
    return files


def refuse_in_one_line(prog: str, work: Callable[[], int | None]) -> int:
    """Do a command's work; a UsageError, the user's mistake, is one line naming it, exit 2."""
    try:
        return work() or 0
    except UsageError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2


def new_parser(prog: str, description: str | None) -> argparse.ArgumentParser:
    return OneLineErrorParser(
        prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )


TRAIN_DOC = """Train an SB3 / sb3-contrib agent (SAC on MinitaurBulletEnv-v0 by default).

Each run gets its own folder, ``<log-folder>/<algo>/<env>_<N>/``, holding the resolved
config and command line, evaluations.npz, best_model.zip, checkpoints (model, replay
buffer, VecNormalize), monitor and progress CSVs, the final model, a learning-curve
PNG and policy videos. ``--resume RUN_DIR [-n N]`` continues a run from its newest
checkpoint (to N steps). Ctrl-C and SIGTERM save a checked checkpoint first.
"""


def train_parser(prog: str = "train.py", without_defaults: bool = False) -> argparse.ArgumentParser:
    parser = new_parser(prog, TRAIN_DOC)
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
        help="torch and JAX CPU threads; 0 (default): 1 for MLP policies, torch's default "
        "for CNNs (more threads spin against any other busy process)",
    )
    add(
        "-i",
        "--trained-agent",
        metavar="MODEL_ZIP",
        help="start from this model (and its VecNormalize statistics), e.g. a shipped one",
    )
    add_trust_pickle(parser, "with -i: the model's pickled entries, statistics, replay buffer")
    add(
        "--resume",
        metavar="RUN_DIR",
        help="continue this run from its newest checkpoint (reads the run folder's own "
        "pickles: resume only run folders you trust)",
    )
    add("-v", "--verbose", type=int, default=0, help="1: SB3's logger tables too (default: 0)")
    return suppress_defaults(parser) if without_defaults else parser


def run_train(args: argparse.Namespace, argv: list[str], prog: str) -> int:
    from minitaur_env.training import commands

    if args.num_threads < 0:
        raise UsageError("--num-threads must be >= 0 (0: one thread for an MLP)")
    given = given_flags(lambda bare: train_parser(prog, bare), argv)
    return commands.train(args, prog, recorded_command(prog, argv), given)


EVALUATE_DOC = """Evaluate a trained policy: statistics over N episodes, and optionally its video.

With no arguments: the best shipped policy in pretrained/, else the best model of the
most recent run under logs/. Evaluation always reports the env's raw return.
"""


def evaluate_parser(prog: str = "evaluate.py") -> argparse.ArgumentParser:
    parser = new_parser(prog, EVALUATE_DOC)
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
    add(
        "--episodes",
        type=int,
        default=20,
        help="evaluation episodes (default: 20; 0 with --render-video or --gui: only those)",
    )
    add("--seed", type=int, default=REPORT_SEED, help="seed of episode 0; episode i uses seed + i")
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
    add_env_kwargs(parser)
    add("--render-video", action="store_true", help="write an mp4 of --video-episodes episodes")
    add("-o", "--output", type=Path, help="video path (default: videos/<env>_<algo>_<time>.mp4)")
    add("--video-episodes", type=int, default=3, help="episodes in the video (default: 3)")
    add("--video-fps", type=float, default=50.0, help="frames per second, real time (default 50)")
    add("--width", type=int, default=640, help="video width (default: 640)")
    add("--height", type=int, default=480, help="video height (default: 480)")
    add("--gif", action="store_true", help="also write a small GIF beside the mp4")
    add("--gui", action="store_true", help="watch --video-episodes episodes in the PyBullet GUI")
    add("--device", default="cpu", help="torch device (default: cpu)")
    add_trust_pickle(parser, "(the zip's cloudpickled entries, a vecnormalize.pkl without JSON)")
    return parser


def run_evaluate(args: argparse.Namespace, argv: list[str], prog: str) -> int:
    from minitaur_env.training import commands

    if args.episodes < 0:
        raise UsageError("--episodes must be >= 0")
    if args.episodes == 0 and args.json is not None:
        raise UsageError("--json: --episodes 0 plays no statistics to write")
    if args.episodes == 0 and not (args.render_video or args.gui):
        raise UsageError("--episodes 0 plays nothing; add --render-video or --gui")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: episode seeds must be >= 0")
    if args.video_episodes < 1:
        raise UsageError("--video-episodes must be >= 1")
    if not (0 < args.width <= 4096 and 0 < args.height <= 4096):
        raise UsageError("--width and --height must be in 1..4096")
    if args.video_fps <= 0:
        raise UsageError("--video-fps must be > 0")
    return commands.evaluate(args, prog)


SWEEP_DOC = """Many training runs on Ray Tune: a configuration over seeds, or a search.

    minitaur sweep --seeds 5 -n 300000                 # 5 seeds of default SAC
    minitaur sweep --search space.yml --trials 20 --scheduler asha
    minitaur sweep -f sweeps --name my-sweep --resume   # after Ctrl-C
    minitaur sweep --summarize sweeps/my-sweep          # the table again
    minitaur sweep --summarize sweeps/a sweeps/a-more-seeds  # one table
    RAY_ADDRESS=head:6379 minitaur sweep -f /shared/sweeps ...   # a cluster

Each trial writes the run folder train.py writes, under ``<-f>/<name>/runs/<trial>/``.
At the end it prints (and writes to ``<-f>/<name>/summary.csv``) one row per
configuration: seeds done and failed, final and best eval return per seed, median, IQM
with its 95 % bootstrap CI, and steps and minutes to 5 and 15 (``--milestones``);
``curves.png`` shows the IQM learning curves. Needs ``pip install 'minitaur-env[ray]'``.
"""


def sweep_parser(prog: str = "minitaur sweep") -> argparse.ArgumentParser:
    parser = new_parser(prog, SWEEP_DOC)
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
    add_trust_pickle(parser, "when a trial resumes its run: older runs' pickled files")
    add("--address", help="an existing Ray cluster (default: $RAY_ADDRESS, else local)")
    add(
        "--summarize",
        nargs="+",
        metavar="SWEEP_DIR",
        help="only print and write a finished sweep's table; several folders (more seeds "
        "of one configuration) make one table, written into the first",
    )
    add(
        "--milestones",
        nargs="+",
        type=float,
        metavar="RETURN",
        help="returns whose first crossing the table reports in steps and minutes "
        "(default: 5 15 on the Minitaur ids, else the env's reward threshold)",
    )
    return parser


def run_sweep(args: argparse.Namespace, argv: list[str], prog: str) -> int:
    from minitaur_env.training import commands

    return commands.sweep(args, recorded_command(prog, argv), prog)


SHIP_DOC = """Pick a policy to ship from trained runs, without peeking at its report seeds.

    minitaur ship logs/sac/MinitaurBulletEnv-v0_{1,2,3} --final-only \\
        --json report.json --ship pretrained/sac/MinitaurBulletEnv-v0_1
    minitaur ship RUN --from-steps 200000          # checkpoints too

Each candidate plays ``--select-episodes`` deterministic episodes on selection seeds
(5000..), which neither training nor the report (12345..) uses; the one with the fewest
falls, then the highest mean, is chosen and only then played on the report seeds.
With ``--also-on KEY=VALUE...`` each candidate is also judged with those env kwargs
changed (e.g. a policy trained under randomization, on the classic dynamics too).
Candidates are each run's best model, final model and checkpoints from ``--from-steps``
on, or with ``--final-only`` the final models alone (what the training command ends
with). ``--ship`` writes the chosen model as a zoo run folder with its statistics,
policy.onnx and provenance.yml (then ``minitaur package`` makes its Hub folder).
"""


def ship_parser(prog: str = "minitaur ship") -> argparse.ArgumentParser:
    parser = new_parser(prog, SHIP_DOC)
    add = parser.add_argument
    add("runs", nargs="+", type=Path, help="run folders to choose from")
    add("--final-only", action="store_true", help="candidates: the final models only")
    add("--from-steps", type=int, default=200_000, help="checkpoints from N steps on")
    add("--steps", type=int, nargs="+", help="only these checkpoints")
    add("--episodes", type=int, default=20, help="report episodes (default: 20)")
    add(
        "--select-episodes",
        type=int,
        help="episodes per candidate on the selection seeds (default: --episodes); more "
        "of them tell a policy that falls once in 40 from one that never falls",
    )
    add(
        "--also-on",
        nargs="+",
        action="append",
        metavar="KEY=VALUE",
        help="also judge each candidate on its env with these --env-kwargs (repeatable); "
        "falls are summed and means averaged over its own env and these",
    )
    add("--select-seed", type=int, default=SELECTION_SEED, help="seed of selection episode 0")
    add("--report-seed", type=int, default=REPORT_SEED, help="seed of report episode 0")
    add("--json", type=Path, help="write the whole report here")
    add("--ship", type=Path, help="write the chosen model here (a zoo run folder)")
    add("--replace", action="store_true", help="let --ship replace a folder already there")
    add_trust_pickle(parser, "(SBX zips saved without their JAX state, statistics without JSON)")
    return parser


def run_ship(args: argparse.Namespace, argv: list[str], prog: str) -> int:
    from minitaur_env.training import commands

    return commands.ship(args)


PACKAGE_DOC = """Write a trained agent as a Hugging Face Hub model folder, offline.

    minitaur package logs/sac/MinitaurBulletEnv-v0_3      # its final model
    minitaur package pretrained/sac/MinitaurBulletEnv-v0_1/best_model.zip -o hub

writes ``<out>/<algo>-<env>/``: the model zip, config.yml, env_kwargs.yml,
vec_normalize.pkl and its pickle-free vec_normalize.json, policy.onnx (the deterministic
actor, normalization folded in), results.json (20 unseen episodes), replay.mp4 and a
README.md model card, the layout of rl-baselines3-zoo's push_to_hub. Nothing is unpickled
unless --trust-pickle. Push it yourself, e.g.
``huggingface-cli upload <user>/sac-MinitaurBulletEnv-v0 hub/sac-MinitaurBulletEnv-v0``.
"""


def package_parser(prog: str = "minitaur package") -> argparse.ArgumentParser:
    parser = new_parser(prog, PACKAGE_DOC)
    add = parser.add_argument
    add("run_or_model", type=Path, help="a run folder (its final model) or a model zip")
    add("-o", "--out", type=Path, default=Path("hub"), help="parent folder (default: hub)")
    add("--env", help="env id (default: the one the model was trained on)")
    add("--episodes", type=int, default=20, help="evaluation episodes (default: 20)")
    add("--seed", type=int, default=REPORT_SEED, help="seed of episode 0 (default: %(default)s)")
    add("--video-steps", type=int, default=1000, help="env steps in replay.mp4 (default: 1000)")
    add("--replace", action="store_true", help="replace an <out>/<algo>-<env>/ already there")
    add_trust_pickle(parser)
    return parser


def run_package(args: argparse.Namespace, argv: list[str], prog: str) -> int:
    from minitaur_env.training import commands

    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: episode seeds must be >= 0")
    return commands.package(args)


ONNX_DOC = """Export a trained policy's deterministic actor as ONNX, its normalization folded in.

    minitaur onnx pretrained/sac/MinitaurBulletEnv-v0_1 -o policy.onnx
    minitaur onnx logs/ppo/MinitaurBulletEnv-v0_2/best_model.zip -o best.onnx
    minitaur evaluate --model policy.onnx            # plays it with onnxruntime, no torch

A run folder exports its final model. Input ``obs``: raw float32 observations, shape
(batch, obs_dim); output ``action``: the action in env units. SAC, TQC, CrossQ and TD3
(tanh-squashed mean) and PPO and A2C (Gaussian mean, clipped to the bounds) export; the
file is written only after onnxruntime's actions match the model's ``predict`` to 1e-5.
"""


def onnx_parser(prog: str = "minitaur onnx") -> argparse.ArgumentParser:
    parser = new_parser(prog, ONNX_DOC)
    parser.add_argument("run_or_model", type=Path, help="a run folder or a model zip")
    parser.add_argument(
        "-o", "--output", type=Path, default=Path("policy.onnx"), help="default: policy.onnx"
    )
    add_trust_pickle(parser)
    return parser


def run_onnx(args: argparse.Namespace, argv: list[str], prog: str) -> int:
    from minitaur_env.training import commands

    return commands.export_onnx(args)


ZOO_DOC = """Run an rl-baselines3-zoo script with this package's env ids registered.

    minitaur zoo record_video -f logs --algo sac --env MinitaurBulletEnv-v0 -n 1000

``rl_zoo3.train`` and ``rl_zoo3.enjoy`` take ``--gym-packages minitaur_env``; the zoo's
other scripts (``record_video``, ``push_to_hub``, ...) have no such flag, so they run
through this command, which hands every argument after the script's name to the zoo.
"""


def zoo_parser(prog: str = "minitaur zoo") -> argparse.ArgumentParser:
    parser = new_parser(prog, ZOO_DOC)
    parser.add_argument("script", help="an rl_zoo3 script, e.g. record_video, enjoy, train")
    parser.add_argument("zoo_args", nargs=argparse.REMAINDER, help="the script's own arguments")
    return parser


def run_zoo(args: argparse.Namespace, argv: list[str], prog: str) -> int:
    import importlib.util
    import runpy

    import minitaur_env  # noqa: F401  (registers the env ids)

    script = args.script.removeprefix("rl_zoo3.")
    if importlib.util.find_spec("rl_zoo3") is None:
        raise UsageError("rl_zoo3 is not installed (pip install 'minitaur-env[zoo]')")
    if importlib.util.find_spec(f"rl_zoo3.{script}") is None:
        raise UsageError(f"rl_zoo3 has no script {script!r}")
    sys.argv = [f"rl_zoo3.{script}", *args.zoo_args]
    try:
        runpy.run_module(f"rl_zoo3.{script}", run_name="__main__", alter_sys=True)
    except SystemExit as done:  # the zoo's scripts end with sys.exit or argparse's exit
        return done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    return 0


@dataclass(frozen=True)
class Command:
    summary: str
    parser: Callable[[str], argparse.ArgumentParser]
    run: Callable[[argparse.Namespace, list[str], str], int]
    interrupted: str = "interrupted"


COMMANDS: dict[str, Command] = {
    "train": Command("train an agent (SAC on the Minitaur by default)", train_parser, run_train),
    "evaluate": Command(
        "statistics, video or GUI of a trained or shipped policy", evaluate_parser, run_evaluate
    ),
    "sweep": Command(
        "many seeds or a hyperparameter search on Ray Tune",
        sweep_parser,
        run_sweep,
        "interrupted; continue it with --resume",
    ),
    "ship": Command("choose a policy on selection seeds and ship it", ship_parser, run_ship),
    "package": Command("a Hugging Face Hub model folder, offline", package_parser, run_package),
    "onnx": Command("export the deterministic actor as ONNX", onnx_parser, run_onnx),
    "zoo": Command("run an rl-baselines3-zoo script on these envs", zoo_parser, run_zoo),
}


def recorded_command(prog: str, argv: list[str]) -> str:
    """The command line a run folder records: how to type this run again."""
    words = shlex.split(prog)
    if words[0].endswith(".py"):
        words.insert(0, "python")
    return shlex.join([*words, *argv])


def run(name: str, argv: list[str] | None = None, prog: str | None = None) -> int:
    """Parse ``argv`` for command ``name`` and run it; a user's mistake is one line, exit 2."""
    argv = sys.argv[1:] if argv is None else list(argv)
    command = COMMANDS[name]
    prog = prog or f"minitaur {name}"
    args = command.parser(prog).parse_args(argv)
    try:
        return refuse_in_one_line(prog, lambda: command.run(args, argv, prog))
    except OSError as error:  # the machine's, not the user's: a full disk, a read-only folder
        print(f"{prog}: error: {' '.join(str(error).split())}", file=sys.stderr)
        return 1
    except ModuleNotFoundError as error:  # an install without the extra this command needs
        if name == "sweep" and error.name in SWEEP_MODULES:
            print(
                f"{prog}: error: {error.name} is not installed; sweeps need the ray extra: "
                "pip install 'minitaur-env[ray]'",
                file=sys.stderr,
            )
            return 2
        print(missing_dependency(prog, error), file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{prog}: {command.interrupted}", file=sys.stderr)
        return 130


def main_parser() -> argparse.ArgumentParser:
    from minitaur_env import __version__

    width = max(map(len, COMMANDS))
    listing = "\n".join(f"  {name:<{width}}  {c.summary}" for name, c in COMMANDS.items())
    parser = OneLineErrorParser(
        prog="minitaur",
        description=__doc__.split("\n\n")[0],
        epilog=f"commands:\n{listing}\n\n'minitaur COMMAND --help' shows a command's flags.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        usage="minitaur [-h] [--version] COMMAND ...",
    )
    parser.add_argument("--version", action="version", version=f"minitaur-env {__version__}")
    parser.add_argument("command", choices=list(COMMANDS), metavar="COMMAND", help="see below")
    parser.add_argument("arguments", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    return parser


def main(argv: list[str] | None = None) -> int:
    """The ``minitaur`` console script."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:
        main_parser().print_help()
        return 2
    args = main_parser().parse_args(argv[:1])
    return run(args.command, argv[1:])


if __name__ == "__main__":
    sys.exit(main())
