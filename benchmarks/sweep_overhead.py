"""The sweep's overhead: the same trials through Ray Tune and through train.py in turn.

Runs ``--seeds`` seeds of a configuration twice, interleaved: once as
``python -m minitaur_env.sweep --max-concurrent 1`` (one trial at a time, as train.py
runs them) and once as one ``train.py`` per seed, one after the other; prints both
wall-clocks, the overhead, and the sweep's start-up (process start to the first trial's
run folder).

    python benchmarks/sweep_overhead.py [-n 3000] [--seeds 2] [--env Pendulum-v1]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SETTINGS = ["--eval-episodes", "2", "--hyperparams", "learning_starts=100"]


def timed(command: list[str], cwd: Path, first_run_glob: str | None = None) -> tuple[float, float]:
    """(seconds to finish, seconds until a file matching first_run_glob appeared)."""
    started = time.perf_counter()
    process = subprocess.Popen(command, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    first = float("nan")
    while process.poll() is None:
        if first != first and first_run_glob and list(cwd.glob(first_run_glob)):
            first = time.perf_counter() - started
        time.sleep(0.05)
    if process.returncode:
        sys.exit(f"{command[:3]} failed: {process.stderr.read().decode()[-500:]}")
    return time.perf_counter() - started, first


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", type=int, default=3000)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--env", default="Pendulum-v1")
    args = parser.parse_args()
    # A sweep needs at least one evaluation per trial: every 1000 steps, or at the end.
    common = [
        "--env",
        args.env,
        "-n",
        str(args.n),
        "--eval-freq",
        str(min(1000, args.n)),
        *SETTINGS,
    ]
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        sweep, startup = timed(
            [
                sys.executable,
                "-m",
                "minitaur_env.sweep",
                *common,
                "--seeds",
                str(args.seeds),
                "--max-concurrent",
                "1",
                "-f",
                str(work / "sweeps"),
            ],
            work,
            "sweeps/*/runs/*/*/*/config.yml",
        )
        scripts = sum(
            timed(
                [
                    sys.executable,
                    str(REPO / "train.py"),
                    *common,
                    "--seed",
                    str(seed),
                    "--num-threads",
                    "1",
                    "--vec-env",
                    "dummy",
                    "--device",
                    "cpu",
                    "-v",
                    "0",
                    "-f",
                    str(work / "logs"),
                ],
                work,
            )[0]
            for seed in range(args.seeds)
        )
    print(f"{args.seeds} trials of {args.n} steps on {args.env}, one at a time")
    print(f"train.py, one after the other: {scripts:.1f} s")
    print(f"sweep: {sweep:.1f} s; overhead {sweep - scripts:+.1f} s ({sweep / scripts - 1:+.0%})")
    print(f"sweep start-up to the first trial's run folder: {startup:.1f} s")


if __name__ == "__main__":
    main()
