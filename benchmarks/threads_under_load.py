"""SAC training speed with one torch thread against torch's default, idle and beside a busy
process: the measurement behind train.py's default of one thread for MLP policies.

Each variant trains the tuned SAC entry's update pattern (batch 256, (256, 256) networks,
8 gradient steps every 8 env steps) on MinitaurBulletEnv-v0 in a fresh process and times
the learning phase. "Busy" runs one CPU-bound process per core beside it but one (another
training run, a test suite). Variants are interleaved, so drifts of a shared host hit all.

    python benchmarks/threads_under_load.py [--steps 1500] [--rounds 2]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import time

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
MEASURE = """
import sys, time, torch, gymnasium as gym
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
import minitaur_env
threads, steps, warmup, untimed = (int(value) for value in sys.argv[1:5])
if threads:
    torch.set_num_threads(threads)
class Timer(BaseCallback):
    started = 0.0
    def _on_step(self):
        if self.num_timesteps == warmup + untimed:  # the first updates are slower: not timed
            Timer.started = time.perf_counter()
        return True
model = SAC("MlpPolicy", gym.make("MinitaurBulletEnv-v0"), learning_starts=warmup,
            train_freq=8, gradient_steps=8, seed=0, device="cpu")
model.learn(warmup + untimed + steps, callback=Timer())
print(steps / (time.perf_counter() - Timer.started), torch.get_num_threads())
"""


def burn() -> None:
    while True:
        pass


def measure(threads: int, steps: int, warmup: int, untimed: int = 200) -> tuple[float, int]:
    # torch's default is what a user gets with nothing set: a caller's OMP_NUM_THREADS=1
    # (as our own runs set it) would silently make both variants one thread.
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    command = [sys.executable, "-c", MEASURE, *(str(n) for n in (threads, steps, warmup, untimed))]
    done = subprocess.run(command, capture_output=True, text=True, check=True, env=env)
    rate, used = done.stdout.split()[-2:]
    return float(rate), int(used)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1500, help="timed learning-phase steps")
    parser.add_argument("--rounds", type=int, default=2, help="interleaved repetitions")
    parser.add_argument("--warmup", type=int, default=300, help="random steps before learning")
    args = parser.parse_args()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    rates: dict[tuple[str, str], list[float]] = {}
    threads_used: dict[str, int] = {}
    for _ in range(args.rounds):
        for load in ("idle", "busy"):
            if load == "idle":
                # "idle" is only true if nothing else runs: the load average says whether it did.
                print(f"load average before the idle measurements: {os.getloadavg()[0]:.2f}")
            burners = []
            if load == "busy":
                burners = [mp.Process(target=burn, daemon=True) for _ in range(max(cores - 1, 1))]
                for process in burners:
                    process.start()
                time.sleep(1.0)
            try:
                for name, threads in (
                    ("1 thread (train.py's default)", 1),
                    ("torch's default threads", 0),
                ):
                    rate, used = measure(threads, args.steps, args.warmup)
                    rates.setdefault((name, load), []).append(rate)
                    threads_used[name] = used
            finally:
                for process in burners:
                    process.terminate()
    print(f"SAC, 8 updates every 8 steps, {cores} cores; env steps/s, median of {args.rounds}")
    print(f"{'variant':<34}{'threads':>8}{'idle':>10}{'busy':>10}")
    for name, used in threads_used.items():
        idle, busy = (statistics.median(rates[(name, load)]) for load in ("idle", "busy"))
        print(f"{name:<34}{used:>8}{idle:>10.1f}{busy:>10.1f}")


if __name__ == "__main__":
    main()
