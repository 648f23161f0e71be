"""What periodic evaluations cost a default run, against what its training costs.

A run evaluates its policy every ``eval_freq`` env steps on ``eval_episodes`` episodes,
and a policy that walks plays every episode to the 1000-step limit. This script times,
in one process and in turns:

- evaluation: the shipped SAC and PPO policies playing full episodes on
  MinitaurBulletEnv-v0, deterministic, one env (as a run's evaluation plays them);
- training: PPO's default entry (8 envs in ``GroupedSubprocVecEnv``, one torch thread,
  as ``train.py`` runs it) and SAC with the default entry's update pattern (8 gradient
  steps every 8 env steps, batch 256, (256, 256), one torch thread; SB3 and SBX).

Then prints, for each default command, its minutes of training and of evaluation on
this machine over the entry's whole budget, with the evaluation settings given as
``--settings FREQ:EPISODES`` (the old flags' defaults, 10000:20, are the baseline).
Episodes that fall end early, so early in a run evaluations cost less than this: the
figures are what evaluations cost once the policy walks, which is most of a run.

    python benchmarks/evaluation_cost.py [--episodes 5] [--sac-steps 1500]
                                         [--settings 10000:20 10000:10 25000:10]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from training_speed import measure, measure_ppo

import minitaur_env  # noqa: F401  (registers the ids)
from minitaur_env.training.evaluation import load_policy, run_episodes
from minitaur_env.training.hyperparams import load_hyperparams
from minitaur_env.training.seeds import REPORT_SEED
from minitaur_env.training.single_env import make_env

REPO = Path(__file__).resolve().parents[1]
ENV = "MinitaurBulletEnv-v0"
SHIPPED = {algo: REPO / "pretrained" / algo / f"{ENV}_1" / f"{ENV}.zip" for algo in ("sac", "ppo")}


def evaluation_rate(algo: str, episodes: int) -> tuple[float, int]:
    """Env steps/s of the shipped ``algo`` policy playing ``episodes`` deterministic
    episodes, and how many of them fell."""
    policy = load_policy(SHIPPED[algo], device="cpu")
    env = make_env(ENV, {})
    try:
        run_episodes(policy, env, 1, REPORT_SEED)  # start-up, not timed
        start = time.perf_counter()
        records = run_episodes(policy, env, episodes, REPORT_SEED + 1)
        elapsed = time.perf_counter() - start
    finally:
        env.close()
    return sum(r["length"] for r in records) / elapsed, sum(int(r["fell"]) for r in records)


def settings_pair(text: str) -> tuple[int, int]:
    try:
        freq, episodes = (int(part) for part in text.split(":"))
    except ValueError:
        message = f"{text!r}: expected FREQ:EPISODES, e.g. 10000:20"
        raise argparse.ArgumentTypeError(message) from None
    if freq < 1 or episodes < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: both must be >= 1")
    return freq, episodes


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

    rates = {}
    for algo in ("sac", "ppo"):
        rate, falls = evaluation_rate(algo, args.episodes)
        rates[algo] = rate
        print(
            f"evaluation, shipped {algo.upper()} ({args.episodes} episodes, {falls} fell): "
            f"{rate:.0f} env steps/s"
        )
    update_pattern = dict(threads=1, train_freq=8, gradient_steps=8)
    training = {
        "python train.py": measure(args.sac_steps, 300, **update_pattern),
        "python train.py --backend sbx": measure(
            args.sac_steps, 300, backend="sbx", **update_pattern
        ),
        "python train.py --algo ppo": measure_ppo(args.ppo_steps, "grouped", 1),
    }
    for command, rate in training.items():
        print(f"training, {command}: {rate:.0f} env steps/s")

    print()
    print(
        "| command | budget | training (min) | evaluations: every N steps x episodes | "
        "evaluation (min) | evaluation's share of the run |"
    )
    print("|---|---|---|---|---|---|")
    for command, rate in training.items():
        algo = "ppo" if "ppo" in command else "sac"
        budget = int(load_hyperparams(algo, ENV)["n_timesteps"])
        train_min = budget / rate / 60
        for freq, episodes in args.settings:
            eval_min = (budget // freq) * episodes * 1000 / rates[algo] / 60
            share = eval_min / (train_min + eval_min)
            print(
                f"| `{command}` | {budget // 1000}k | {train_min:.1f} | {freq // 1000}k x "
                f"{episodes} | {eval_min:.1f} | {share:.0%} |"
            )


if __name__ == "__main__":
    main()
