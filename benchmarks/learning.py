"""Learning benchmark: configurations over seeds, return at fixed steps, IQM and wall-clock.

Trains a configuration over seeds with train.py (one after the other), or summarizes run
folders that exist already, grouped by label. Prints, per run, the mean evaluation return
(the run's EvalCallback: deterministic, raw classic return) at the last evaluation at or
before each step count; per group, the same table as the sweep's summary (final and best
return per seed, median, IQM with its 95 % bootstrap CI, steps and minutes to 5 and 15).
``--plot`` draws the IQM curves with their CI bands against env steps and wall-clock.

    python benchmarks/learning.py --algo ppo -n 300000 --seeds 0 1 2 -- --eval-episodes 10
    python benchmarks/learning.py --algo sac ppo -n 150000 --seeds 0 1 2   # timed side by side
    python benchmarks/learning.py --group sac logs/sac/M_4 logs/sac/M_5 --group ppo ... \\
        --at 50000 100000 150000 --plot learning.png

Several ``--algo`` train seed by seed in turn (sac seed 0, ppo seed 0, sac seed 1, ...) so
that a machine whose speed swings treats both alike, and the last lines give each
algorithm's steps and minutes to each milestone as a ratio to ``--baseline``'s (PPO's by
default). Arguments after ``--`` go to train.py unchanged. For many seeds or a search, use
``python -m minitaur_env.sweep``, which writes the same table.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from minitaur_env.training.aggregate import GroupSummary, RunCurve, format_rows, plot_iqm_curves

REPO = Path(__file__).resolve().parents[1]


def train(args: argparse.Namespace, algo: str, seed: int, extra: list[str]) -> Path:
    command = [
        sys.executable,
        str(REPO / "train.py"),
        "--algo",
        algo,
        "--backend",
        args.backend,
        "-n",
        str(args.n_timesteps),
        "--seed",
        str(seed),
        "-f",
        args.log_folder,
        "-v",
        "0",
        *extra,
    ]
    print("$", " ".join(command), flush=True)
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    match = re.search(r"run folder: (\S+)", result.stdout)
    if result.returncode != 0 or not match:
        sys.exit(f"train.py failed for seed {seed}: {result.stderr.strip().splitlines()[-1:]}")
    return Path(match.group(1))


def ratio_lines(rows: list[dict[str, object]], baseline: str) -> list[str]:
    """Each group's median steps and minutes to each milestone, as a ratio to the
    baseline group's (empty where there is no such group)."""
    base = next((row for row in rows if row["config"] == baseline), None)
    if base is None:
        return []
    lines = []
    milestones = [
        key.removeprefix("median_steps_to_") for key in base if key.startswith("median_steps_to_")
    ]
    for row in rows:
        if row is base:
            continue
        for milestone in milestones:
            cells = []
            for measure, shown in (("steps", "{:,.0f} steps"), ("minutes", "{:.1f} min")):
                key = f"median_{measure}_to_{milestone}"
                mine, theirs = float(row[key]), float(base[key])
                ratio = mine / theirs if theirs > 0 and np.isfinite(mine) else float("nan")
                mine_text, theirs_text = shown.format(mine), shown.format(theirs)
                cells.append(f"{mine_text} = {ratio:.2f}x {baseline}'s {theirs_text}")
            lines.append(f"{row['config']} to {milestone}: " + "; ".join(cells))
    return lines


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", nargs="+", default=["sac"], help="one or more algorithms")
    parser.add_argument("--baseline", default="ppo", help="the group ratios are taken to")
    parser.add_argument("--backend", default="sb3")
    parser.add_argument("-n", "--n-timesteps", type=int, default=300_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("-f", "--log-folder", default="logs/learning")
    parser.add_argument("--at", type=int, nargs="+", default=[100_000, 200_000, 300_000])
    parser.add_argument(
        "--group",
        nargs="+",
        action="append",
        metavar=("LABEL", "RUN_DIR"),
        help="summarize these existing run folders under LABEL (repeatable)",
    )
    parser.add_argument("--plot", type=Path, help="write the IQM curves to this PNG")
    parser.add_argument("--threshold", type=float, default=15.0)
    args = parser.parse_args(argv)

    if args.group:
        labelled = [(group[0], [Path(p) for p in group[1:]]) for group in args.group]
    else:
        runs: dict[str, list[Path]] = {algo: [] for algo in args.algo}
        for seed in args.seeds:  # in turn, so that the machine's swings hit all alike
            for algo in args.algo:
                runs[algo].append(train(args, algo, seed, extra))
        labelled = list(runs.items())
    groups = [GroupSummary(label, [RunCurve.read(r) for r in runs], []) for label, runs in labelled]

    header = "".join(f"{f'@{s // 1000}k':>10}" for s in args.at)
    print(f"{'group':<14}{'run':<44}{header}{'best':>16}")
    for group in groups:
        for curve in group.curves:
            cells = "".join(f"{curve.at(s):>10.2f}" for s in args.at)
            best, step = curve.best
            name = str(curve.run.path)[-43:]
            print(f"{group.name:<14}{name:<44}{cells}{f'{best:.2f} @{step // 1000}k':>16}")
        table = np.array([[c.at(s) for s in args.at] for c in group.curves])
        medians = "".join(
            f"{np.median(col[~np.isnan(col)]):>10.2f}" if (~np.isnan(col)).any() else f"{'-':>10}"
            for col in table.T
        )
        print(f"{group.name:<14}{'median over the runs that got that far':<44}{medians}")
    print()
    rows = [group.row() for group in groups]
    print(format_rows(rows))
    for line in ratio_lines(rows, args.baseline):
        print(line)
    if args.plot:
        plot_iqm_curves(groups, args.plot, args.threshold, by_minutes=True)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
