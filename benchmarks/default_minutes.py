"""How long the default commands take on this machine: training, evaluations, and the
wait for a walking Minitaur, as a ratio to PPO's.

A run evaluates its policy every ``eval_freq`` env steps on ``eval_episodes`` episodes,
and a policy that walks plays every episode to the 1000-step limit. This script times,
in one process and in turns:

- evaluation: the shipped SAC and PPO policies playing full episodes on
  MinitaurBulletEnv-v0, deterministic, one env (as a run's evaluation plays them);
- training: PPO's default entry (8 envs in ``GroupedSubprocVecEnv``, one torch thread,
  as ``train.py`` runs it) and SAC's default entry as ``train.py`` builds it (its
  observations, replay buffer and update pattern; one torch thread; SB3 and SBX), and
  each candidate for SAC's default: the same entry with its ``--hyperparams``.

It prints what evaluations cost each default command over its whole budget at each
``--settings FREQ:EPISODES`` (10000:20 were the flags' defaults until 2026-11-28), and
then the minutes to a periodic evaluation of 15 and of the whole run at the entry's own
settings: the kept runs' median steps to 15 (the benchmark table's runs of each command,
``KEPT_RUNS``) priced at the rates just measured. SAC's first ``learning_starts`` steps
(random actions, no updates) and the evaluations are priced at the evaluation rate, and
every evaluation episode as a full one, so early evaluations (whose episodes fall) are
counted high: the figures are a machine's minutes for the runs' steps, not a rerun.

    python benchmarks/default_minutes.py [--episodes 5] [--sac-steps 1500]
                                         [--settings 10000:20 10000:10 25000:10]
"""

from __future__ import annotations

import argparse
import time
from glob import glob
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from training_speed import learning_rate_of, measure_ppo, model_as_trained

import minitaur_env  # noqa: F401  (registers the ids)
from minitaur_env.training.aggregate import RunCurve
from minitaur_env.training.config import ExperimentConfig
from minitaur_env.training.evaluation import load_policy, playing_kwargs, run_episodes
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.seeds import REPORT_SEED
from minitaur_env.training.single_env import make_env

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
ENV = "MinitaurBulletEnv-v0"
SHIPPED = {algo: REPO / "pretrained" / algo / f"{ENV}_1" / f"{ENV}.zip" for algo in ("sac", "ppo")}
WALKS = 15.0


class Command(NamedTuple):
    algo: str
    backend: str
    hyperparams: dict[str, Any]  # the command's --hyperparams
    kept_runs: list[str]  # under benchmarks/results: the runs it was measured by


# Each default command, then each candidate for a default, with the kept runs of its
# entry (the benchmark table's rows, benchmarks/tables.yml). PPO's is the reference.
COMMANDS = {
    "python train.py": Command("sac", "sb3", {}, ["sb3-gs4/seed*"]),
    # the default until 2026-12-07 (minitaur-history-nstep): twice the updates
    "python train.py --hyperparams gradient_steps=8": Command(
        "sac", "sb3", {"gradient_steps": 8}, ["sb3-h3-n10to5/seed*"]
    ),
    "python train.py --backend sbx --hyperparams gradient_steps=8": Command(
        "sac", "sbx", {"gradient_steps": 8}, ["sbx-h3-n10to5/seed*"]
    ),
    # a candidate, not chosen (it ended lower; docs/results.md): the default's updates on
    # 8 envs stepped together, 4 updates per 8 transitions as before (GroupedSubprocVecEnv,
    # as train.py runs several envs)
    "python train.py --n-envs 8 --hyperparams train_freq=1": Command(
        "sac", "sb3", {"n_envs": 8, "train_freq": 1}, ["sb3-gs4-8env/seed*"]
    ),
    "python train.py --algo ppo": Command("ppo", "sb3", {}, ["ppo-lin/seed*"]),
}


def evaluation_rate(algo: str, episodes: int) -> tuple[float, int]:
    """Env steps/s of the shipped ``algo`` policy playing ``episodes`` deterministic
    episodes, and how many of them fell."""
    policy = load_policy(SHIPPED[algo], device="cpu")
    env = make_env(ENV, playing_kwargs(policy, {}))  # the env it was trained on
    try:
        run_episodes(policy, env, 1, REPORT_SEED)  # start-up, not timed
        start = time.perf_counter()
        records = run_episodes(policy, env, episodes, REPORT_SEED + 1)
        elapsed = time.perf_counter() - start
    finally:
        env.close()
    return sum(r["length"] for r in records) / elapsed, sum(int(r["fell"]) for r in records)


def training_rate(command: str, sac_steps: int, ppo_steps: int) -> float:
    algo, backend, hyperparams, _ = COMMANDS[command]
    if algo == "ppo":
        return measure_ppo(ppo_steps, "grouped", 1)
    # The entry's own model (history, n-step returns, mirrored replay, normalized
    # observations) with the command's settings, one torch thread, updates from 300 steps on.
    torch.set_num_threads(1)
    config = ExperimentConfig.resolve(
        algo,
        ENV,
        backend=backend,
        hyperparams={**hyperparams, "learning_starts": 300},
        seed=0,
        device="cpu",
    )
    with model_as_trained(config) as model:
        return learning_rate_of(model, sac_steps)


def median_steps_to(milestone: float, patterns: list[str]) -> tuple[float, int]:
    """The kept runs' median env steps to their first evaluation at ``milestone`` (NaN
    if fewer than half got there), and how many runs there are."""
    runs = [Path(p) for pattern in patterns for p in sorted(glob(str(RESULTS / pattern)))]
    runs = [run for run in runs if RunFolder.is_run(run)]
    steps = []
    for run in runs:
        reached = RunCurve.read(run).reached(milestone)
        steps.append(reached[0] if reached else np.inf)
    return (float(np.median(steps)) if steps else np.nan), len(runs)


def settings_pair(text: str) -> tuple[int, int]:
    try:
        freq, episodes = (int(part) for part in text.split(":"))
    except ValueError:
        message = f"{text!r}: expected FREQ:EPISODES, e.g. 10000:20"
        raise argparse.ArgumentTypeError(message) from None
    if freq < 1 or episodes < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: both must be >= 1")
    return freq, episodes


class Pricing:
    """Minutes of a default command's steps at the measured rates."""

    def __init__(self, command: str, train_rate: float, eval_rate: float) -> None:
        algo, backend, hyperparams, _ = COMMANDS[command]
        self.config = ExperimentConfig.resolve(algo, ENV, backend=backend, hyperparams=hyperparams)
        self.random_steps = int(self.config.hyperparams.get("learning_starts", 0))
        self.train_rate, self.eval_rate = train_rate, eval_rate

    def training(self, steps: float) -> float:
        random = min(steps, self.random_steps)
        return (random / self.eval_rate + (steps - random) / self.train_rate) / 60

    def evaluations(self, steps: float, freq: int, episodes: int) -> float:
        return (steps // freq) * episodes * 1000 / self.eval_rate / 60

    def minutes(self, steps: float) -> float:
        config = self.config
        return self.training(steps) + self.evaluations(
            steps, config.eval_freq or np.inf, config.eval_episodes
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5, help="timed evaluation episodes")
    parser.add_argument("--sac-steps", type=int, default=1500, help="timed SAC learning steps")
    parser.add_argument("--ppo-steps", type=int, default=16384, help="timed PPO env steps")
    parser.add_argument(
        "--settings",
        nargs="+",
        type=settings_pair,
        default=[(10_000, 20), (10_000, 10), (25_000, 10)],
        metavar="FREQ:EPISODES",
    )
    args = parser.parse_args()

    eval_rates = {}
    for algo in ("sac", "ppo"):
        rate, falls = evaluation_rate(algo, args.episodes)
        eval_rates[algo] = rate
        print(
            f"evaluation, shipped {algo.upper()} ({args.episodes} episodes, {falls} fell): "
            f"{rate:.0f} env steps/s"
        )
    prices = {}
    for command, (algo, *_) in COMMANDS.items():
        rate = training_rate(command, args.sac_steps, args.ppo_steps)
        print(f"training, {command}: {rate:.0f} env steps/s")
        prices[command] = Pricing(command, rate, eval_rates[algo])

    print()
    print(
        "| command | budget | training (min) | evaluations: every N steps x episodes | "
        "evaluation (min) | evaluation's share of the run |"
    )
    print("|---|---|---|---|---|---|")
    for command, price in prices.items():
        budget = price.config.n_timesteps
        train_min = price.training(budget)
        for freq, episodes in args.settings:
            eval_min = price.evaluations(budget, freq, episodes)
            share = eval_min / (train_min + eval_min)
            print(
                f"| `{command}` | {budget // 1000}k | {train_min:.1f} | {freq // 1000}k x "
                f"{episodes} | {eval_min:.1f} | {share:.0%} |"
            )

    print()
    print(
        f"| command | evaluations | kept runs | median steps to {WALKS:g} | minutes to "
        f"{WALKS:g} | ratio to PPO | whole run (min) | ratio to PPO |"
    )
    print("|---|---|---|---|---|---|---|---|")
    rows = {}
    for command, price in prices.items():
        steps, runs = median_steps_to(WALKS, COMMANDS[command].kept_runs)
        rows[command] = (steps, runs, price.minutes(steps), price.minutes(price.config.n_timesteps))
    ppo = rows["python train.py --algo ppo"]
    for command, (steps, runs, to_walk, whole) in rows.items():
        config = prices[command].config
        print(
            f"| `{command}` | {config.eval_freq // 1000}k x {config.eval_episodes} | {runs} | "
            f"{steps / 1000:.0f}k | {to_walk:.1f} | {to_walk / ppo[2]:.2f} | {whole:.1f} | "
            f"{whole / ppo[3]:.2f} |"
        )


if __name__ == "__main__":
    main()
