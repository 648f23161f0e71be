"""SAC training throughput on MinitaurBulletEnv-v0, against SB3's SAC defaults.

Most variants train SAC with SB3's default algorithmic settings (batch 256, (256, 256)
actor and critics, one gradient step per env step) and differ only in how the work is
executed: torch threads, updates batched in time, SBX (the JAX implementation of SAC by
SB3's maintainers, ``pip install sbx-rl``). Two price a cheaper update instead: batch
128, and (128, 128) networks. Each is measured in
this one process, one after the other, over the learning phase (from ``--untimed`` (200)
updates after ``learning_starts``, so JAX's compilation is not counted). Also prints the
memory of a 1M transition replay buffer.

Then PPO with the tuned Minitaur config (8 envs), its envs in one process (SB3's
DummyVecEnv, torch's default threads) against ``GroupedSubprocVecEnv`` with one torch
thread (what ``train.py`` does by default for several envs).

    python benchmarks/training_speed.py [--steps 2000] [--warmup 300] [--untimed 200]
                                        [--ppo-steps 16384] [--ppo-rollout 256]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager

import gymnasium as gym
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback

import minitaur_env  # noqa: F401
from minitaur_env.training.config import ExperimentConfig
from minitaur_env.training.experiment import Experiment

ENV = "MinitaurBulletEnv-v0"


class _LearningPhaseTimer(BaseCallback):
    def __init__(self, start_at: int) -> None:
        super().__init__()
        self.start_at = start_at
        self.started = 0.0
        self.steps_at_start = 0

    def _on_step(self) -> bool:
        # >=: with several envs the count moves n_envs at a time and may step over start_at
        if not self.started and self.num_timesteps >= self.start_at:
            self.started = time.perf_counter()
            self.steps_at_start = self.num_timesteps
        return True


def measure(
    steps: int,
    warmup: int,
    threads: int,
    backend: str = "sb3",
    untimed: int = 200,
    **sac_kwargs,
) -> float:
    """Env steps/s of the learning phase, timed from ``untimed`` updates in (after JIT
    warm-up)."""
    torch.set_num_threads(threads)
    env = gym.make(ENV)
    if backend == "sbx":
        from sbx import SAC as algorithm

        sac_kwargs.setdefault("policy_kwargs", {"net_arch": [256, 256]})
    else:
        algorithm = SAC
    model = algorithm("MlpPolicy", env, learning_starts=warmup, seed=0, device="cpu", **sac_kwargs)
    try:
        return learning_rate_of(model, steps, untimed)
    finally:
        env.close()


def learning_rate_of(model: BaseAlgorithm, steps: int, untimed: int = 200) -> float:
    """Env steps/s of an off-policy ``model``'s learning phase over ``steps`` env steps,
    timed from ``untimed`` updates after its ``learning_starts``."""
    timer = _LearningPhaseTimer(model.learning_starts + untimed)
    model.learn(total_timesteps=model.learning_starts + untimed + steps, callback=timer)
    if not timer.started or model.num_timesteps == timer.steps_at_start:
        raise RuntimeError(f"no learning step was timed ({steps} steps after {timer.start_at})")
    elapsed = time.perf_counter() - timer.started
    return (model.num_timesteps - timer.steps_at_start) / elapsed


def measure_ppo(steps: int, vec_env: str, default_threads: int, rollout: int = 0) -> float:
    """Env steps/s of PPO with the tuned Minitaur config (8 envs), rollouts and updates;
    ``rollout`` > 0 replaces the config's steps per env and rollout (a smoke run's size)."""
    torch.set_num_threads(1 if vec_env == "grouped" else default_threads)  # as train.py does
    overrides = {}
    if rollout:
        entry = ExperimentConfig.resolve("ppo", ENV)
        overrides = {
            "n_steps": rollout,
            "batch_size": min(entry.hyperparams["batch_size"], rollout * entry.n_envs),
        }
    config = ExperimentConfig.resolve(
        "ppo", ENV, hyperparams=overrides, vec_env=vec_env, seed=0, device="cpu"
    )
    with model_as_trained(config) as model:
        steps_per_rollout = model.n_steps * model.n_envs
        model.learn(steps_per_rollout)  # first rollout and update: start-up, not timed
        start = time.perf_counter()
        timed = max(steps // steps_per_rollout, 1) * steps_per_rollout
        model.learn(timed, reset_num_timesteps=False)
        elapsed = time.perf_counter() - start
    return (model.num_timesteps - steps_per_rollout) / elapsed


@contextmanager
def model_as_trained(config: ExperimentConfig) -> Iterator[BaseAlgorithm]:
    """The model ``train.py`` builds for ``config`` (its envs, normalization, replay buffer
    and policy), in a throwaway run folder; its envs are closed on leaving."""
    with tempfile.TemporaryDirectory() as folder:
        experiment = Experiment.create(config, folder)
        try:
            experiment.build()
            yield experiment.model
        finally:
            experiment.close()


def torch_default_threads() -> int:
    """Torch's thread count in a process with no *_NUM_THREADS set: the defaults' baseline
    must not inherit the OMP_NUM_THREADS=1 that runs beside others export."""
    clean = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    probe = [sys.executable, "-c", "import torch; print(torch.get_num_threads())"]
    return int(subprocess.run(probe, capture_output=True, text=True, env=clean, check=True).stdout)


def replay_buffer_bytes(size: int = 1_000_000) -> int:
    env = gym.make(ENV)
    buffer = ReplayBuffer(size, env.observation_space, env.action_space, device="cpu")
    env.close()
    arrays = (buffer.observations, buffer.next_observations, buffer.actions, buffer.rewards)
    return sum(a.nbytes for a in arrays) + buffer.dones.nbytes + buffer.timeouts.nbytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="learning-phase steps")
    parser.add_argument("--warmup", type=int, default=300, help="random steps before learning")
    parser.add_argument(
        "--untimed", type=int, default=200, help="learning steps before timing (JIT compiles)"
    )
    parser.add_argument("--ppo-steps", type=int, default=16384, help="timed PPO env steps")
    parser.add_argument(
        "--ppo-rollout", type=int, default=0, help="PPO steps per env and rollout; 0: the config's"
    )
    args = parser.parse_args()
    default_threads = torch_default_threads()

    baseline = measure(args.steps, args.warmup, default_threads, untimed=args.untimed)
    print(f"SB3 SAC defaults ({default_threads} torch threads): {baseline:.1f} env steps/s")
    variants = {
        "1 torch thread": dict(threads=1),
        "1 thread, 64 updates every 64 steps": dict(threads=1, train_freq=64, gradient_steps=64),
        # What an update costs with less data or smaller networks, for the minutes goal:
        # the SAC entry's steps to 15 would have to hold with them.
        "batch 128": dict(threads=default_threads, batch_size=128),
        "actor and critics (128, 128)": dict(
            threads=default_threads, policy_kwargs={"net_arch": [128, 128]}
        ),
        "SBX (JAX) SAC": dict(threads=default_threads, backend="sbx"),
        "SBX (JAX) SAC, 8 updates every 8 steps": dict(
            threads=default_threads, backend="sbx", train_freq=8, gradient_steps=8
        ),
    }
    for name, settings in variants.items():
        rate = measure(args.steps, args.warmup, untimed=args.untimed, **settings)
        print(f"{name}: {rate:.1f} env steps/s; ratio {rate / baseline:.2f}x the defaults")
    dummy = measure_ppo(args.ppo_steps, "dummy", default_threads, args.ppo_rollout)
    grouped = measure_ppo(args.ppo_steps, "grouped", default_threads, args.ppo_rollout)
    rollout = args.ppo_rollout or ExperimentConfig.resolve("ppo", ENV).hyperparams["n_steps"]
    print(
        f"PPO, tuned config (8 envs, {rollout}-step rollouts, 10 epochs): DummyVecEnv {dummy:.0f} "
        f"env steps/s; GroupedSubprocVecEnv (2 processes, 1 torch thread) {grouped:.0f}; "
        f"ratio {grouped / dummy:.2f}x"
    )
    mib = replay_buffer_bytes() / 2**20
    print(f"replay buffer of 1M transitions (float32 observations): {mib:.0f} MiB")


if __name__ == "__main__":
    main()
