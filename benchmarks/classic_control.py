"""The tutorials' other tasks, each trained over seeds by the sweep command with its
shipped hyperparameter entry: steps and wall-clock to each task's threshold.

    python benchmarks/classic_control.py                      # all tasks, 3 seeds each
    python benchmarks/classic_control.py --tasks ppo:CartPole-v1 --seeds 5
    python benchmarks/classic_control.py --summarize-only     # the table again

Each task is one ``python -m minitaur_env.sweep --algo A --env E --seeds N --milestones T``
(Ray Tune; the run folders and its own summary land in ``<-f>/<algo>-<env>/``). The
threshold is judged on the periodic deterministic evaluations (10 episodes, mean return),
so "steps to T" is the first evaluation at or above T, at the evaluation's granularity.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

# (algo, env id, threshold, evaluation every N env steps)
TASKS = [
    ("ppo", "CartPole-v1", 475.0, 5_000),
    ("sac", "Pendulum-v1", -200.0, 1_000),
    ("tqc", "Pendulum-v1", -200.0, 1_000),
    ("sac", "MountainCarContinuous-v0", 90.0, 2_500),
    ("tqc", "MountainCarContinuous-v0", 90.0, 2_500),
]


def sweep_folder(storage: str, algo: str, env_id: str) -> Path:
    return Path(storage) / f"{algo}-{env_id}"


def run_task(args: argparse.Namespace, algo: str, env_id: str, threshold: float, freq: int) -> int:
    command = [
        sys.executable,
        "-m",
        "minitaur_env.sweep",
        "--algo",
        algo,
        "--env",
        env_id,
        "--seeds",
        str(args.seeds),
        "--eval-freq",
        str(freq),
        "--eval-episodes",
        "10",
        "--save-freq",
        "0",
        "--milestones",
        str(threshold),
        "-f",
        args.storage,
        "--name",
        sweep_folder(args.storage, algo, env_id).name,
        "--max-concurrent",
        str(args.max_concurrent),
    ]
    print("$", " ".join(command[1:]), flush=True)
    return subprocess.run(command, cwd=REPO, check=False).returncode


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", metavar="ALGO:ENV", help="a subset of the tasks")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("-f", "--storage", default="logs/classic")
    parser.add_argument("--max-concurrent", type=int, default=2, help="trials at once")
    parser.add_argument("--summarize-only", action="store_true", help="train nothing")
    args = parser.parse_args()
    tasks = TASKS
    if args.tasks:
        known = {f"{algo}:{env}" for algo, env, _, _ in TASKS}
        unknown = sorted(set(args.tasks) - known)
        if unknown:
            parser.error(f"unknown task {unknown[0]}; tasks: {', '.join(sorted(known))}")
        tasks = [task for task in TASKS if f"{task[0]}:{task[1]}" in args.tasks]
    if not args.summarize_only:
        for algo, env_id, threshold, freq in tasks:
            if run_task(args, algo, env_id, threshold, freq) != 0:
                print(f"{algo} on {env_id}: the sweep failed", file=sys.stderr)

    from minitaur_env.training.sweep_summary import summarize

    print(
        "\n| task | algo | threshold | seeds reaching it | env steps to it, per seed | "
        "median steps | median minutes | final eval return, per seed |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for algo, env_id, threshold, _ in tasks:
        folder = sweep_folder(args.storage, algo, env_id)
        if not folder.is_dir():
            print(f"| {env_id} | {algo} | {threshold:g} | not run | | | | |")
            continue
        row = summarize(folder, (threshold,))[0]
        label = f"{threshold:g}"
        reached = row[f"reached_{label}"]
        cut = int(row["seeds_unfinished"]) + int(row["seeds_failed"])
        if cut:  # only finished seeds count; say that some are not
            reached += f" (+{cut} not finished)"
        steps, minutes = row[f"median_steps_to_{label}"], row[f"median_minutes_to_{label}"]
        print(
            f"| {env_id} | {algo} | {label} | {reached} | "
            f"{row[f'steps_to_{label}_per_seed']} | "
            f"{'-' if np.isnan(steps) else f'{steps:,.0f}'} | "
            f"{'-' if np.isnan(minutes) else f'{minutes:.1f}'} | {row['final_per_seed']} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
