"""Learning benchmark: a configuration over K seeds, return at fixed steps and wall-clock.

Runs ``train.py`` once per seed (one after the other), then prints, per run and as the
median over the runs that trained that far, the mean evaluation return (the run's
EvalCallback, deterministic, raw classic return) at the last evaluation at or before each
step count, and the wall-clock at which the evaluation return first reached each milestone.

    python benchmarks/learning.py --algo ppo -n 300000 --seeds 0 1 2 -- --eval-episodes 10
    python benchmarks/learning.py --summarize logs/ppo/MinitaurBulletEnv-v0_1 ...

Arguments after ``--`` go to train.py unchanged.
"""

from __future__ import annotations

import argparse
import csv
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def wall_clock_at(run_dir: Path, steps: np.ndarray) -> np.ndarray:
    """Seconds since the run started when it had made ``steps`` env steps (monitor logs)."""
    events = []
    for monitor in sorted((run_dir / "monitor").glob("*.monitor.csv")):
        with monitor.open() as handle:
            next(handle)  # the JSON header line
            events += [(float(row["t"]), int(row["l"])) for row in csv.DictReader(handle)]
    if not events:
        return np.full(len(steps), np.nan)
    events.sort()
    times = np.array([t for t, _ in events])
    done = np.cumsum([n for _, n in events])
    return np.interp(steps, done, times, right=np.nan)


def run_summary(run_dir: Path, at: list[int], milestones: list[float]) -> dict:
    with np.load(run_dir / "evaluations.npz") as data:
        steps, returns = data["timesteps"], data["results"].mean(axis=1)
    at_steps = []
    for target in at:
        earlier = np.nonzero(steps <= target)[0]
        trained_that_far = len(earlier) and steps[-1] >= target
        at_steps.append(float(returns[earlier[-1]]) if trained_that_far else np.nan)
    wall = wall_clock_at(run_dir, steps)
    reached = {}
    for milestone in milestones:
        hit = np.nonzero(returns >= milestone)[0]
        reached[milestone] = (int(steps[hit[0]]), float(wall[hit[0]])) if len(hit) else None
    best = int(np.argmax(returns))
    return {
        "run": run_dir,
        "at": at_steps,
        "reached": reached,
        "best": (float(returns[best]), int(steps[best])),
        "last_step": int(steps[-1]),
    }


def train(args: argparse.Namespace, seed: int, extra: list[str]) -> Path:
    command = [
        sys.executable, str(REPO / "train.py"), "--algo", args.algo, "--backend", args.backend,
        "-n", str(args.n_timesteps), "--seed", str(seed), "-f", args.log_folder, "-v", "0",
        *extra,
    ]  # fmt: skip
    print("$", " ".join(command), flush=True)
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    match = re.search(r"run folder: (\S+)", result.stdout)
    if result.returncode != 0 or not match:
        sys.exit(f"train.py failed for seed {seed}: {result.stderr.strip().splitlines()[-1:]}")
    return Path(match.group(1))


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="sac")
    parser.add_argument("--backend", default="sb3")
    parser.add_argument("-n", "--n-timesteps", type=int, default=300_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("-f", "--log-folder", default="logs/learning")
    parser.add_argument("--at", type=int, nargs="+", default=[100_000, 200_000, 300_000])
    parser.add_argument("--milestones", type=float, nargs="+", default=[5.0, 15.0])
    parser.add_argument("--summarize", type=Path, nargs="+", help="existing run folders only")
    args = parser.parse_args(argv)

    runs = args.summarize or [train(args, seed, extra) for seed in args.seeds]
    summaries = [run_summary(run, args.at, args.milestones) for run in runs]
    header = "".join(f"{f'@{s // 1000}k':>10}" for s in args.at)
    header += "".join(f"{f'>= {m:g}':>24}" for m in args.milestones)
    print(f"{'run':<48}{header}{'best':>18}")
    for summary in summaries:
        cells = "".join(f"{value:>10.2f}" for value in summary["at"])
        for milestone in args.milestones:
            hit = summary["reached"][milestone]
            text = f"{hit[0] // 1000}k steps, {hit[1] / 60:.0f} min" if hit else "not reached"
            cells += f"{text:>24}"
        best, step = summary["best"]
        print(f"{str(summary['run'])[-48:]:<48}{cells}{f'{best:.2f} @{step // 1000}k':>18}")
    table = np.array([s["at"] for s in summaries])
    medians, counts = "", ""
    for column in table.T:
        reached = column[~np.isnan(column)]
        medians += f"{np.median(reached):>10.2f}" if len(reached) else f"{'-':>10}"
        counts += f"{f'{len(reached)}/{len(column)}':>10}"
    print(f"{'median over the runs that got that far':<48}{medians}")
    print(f"{'runs that got that far':<48}{counts}")


if __name__ == "__main__":
    main()
