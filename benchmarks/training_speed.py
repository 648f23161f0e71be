"""SAC training throughput on MinitaurBulletEnv-v0, against SB3's SAC defaults.

Every variant trains SAC with the same algorithmic settings as SB3's defaults (batch 256,
(256, 256) actor and critics, one gradient step per env step) and differs only in how
the work is executed: torch threads, updates batched in time, or SBX (the JAX
implementation of SAC by SB3's maintainers, ``pip install sbx-rl``). Each is measured in
this one process, one after the other, over the learning phase (from 200 updates after
``learning_starts``, so JAX's compilation is not counted). Also prints the memory of a 1M
transition replay buffer.

    python benchmarks/training_speed.py [--steps 1500] [--warmup 300]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback

import minitaur_env  # noqa: F401


class _LearningPhaseTimer(BaseCallback):
    def __init__(self, start_at: int) -> None:
        super().__init__()
        self.start_at = start_at
        self.started = 0.0
        self.steps_at_start = 0

    def _on_step(self) -> bool:
        if self.num_timesteps == self.start_at:
            self.started = time.perf_counter()
            self.steps_at_start = self.num_timesteps
        return True


def measure(steps: int, warmup: int, threads: int, backend: str = "sb3", **sac_kwargs) -> float:
    """Env steps/s of the learning phase, timed from 200 updates in (after JIT warm-up)."""
    torch.set_num_threads(threads)
    env = gym.make("MinitaurBulletEnv-v0")
    if backend == "sbx":
        from sbx import SAC as algorithm

        sac_kwargs.setdefault("policy_kwargs", {"net_arch": [256, 256]})
    else:
        algorithm = SAC
    model = algorithm("MlpPolicy", env, learning_starts=warmup, seed=0, device="cpu", **sac_kwargs)
    timer = _LearningPhaseTimer(warmup + 200)
    model.learn(total_timesteps=warmup + steps, callback=timer)
    elapsed = time.perf_counter() - timer.started
    env.close()
    return (model.num_timesteps - timer.steps_at_start) / elapsed


def replay_buffer_bytes(size: int = 1_000_000) -> int:
    env = gym.make("MinitaurBulletEnv-v0")
    buffer = ReplayBuffer(size, env.observation_space, env.action_space, device="cpu")
    env.close()
    arrays = (buffer.observations, buffer.next_observations, buffer.actions, buffer.rewards)
    return sum(a.nbytes for a in arrays) + buffer.dones.nbytes + buffer.timeouts.nbytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="learning-phase steps")
    parser.add_argument("--warmup", type=int, default=300, help="random steps before learning")
    args = parser.parse_args()
    default_threads = torch.get_num_threads()

    baseline = measure(args.steps, args.warmup, default_threads)
    print(f"SB3 SAC defaults ({default_threads} torch threads): {baseline:.1f} env steps/s")
    variants = {
        "1 torch thread": dict(threads=1),
        "1 thread, 64 updates every 64 steps": dict(threads=1, train_freq=64, gradient_steps=64),
        "SBX (JAX) SAC": dict(threads=default_threads, backend="sbx"),
        "SBX (JAX) SAC, 8 updates every 8 steps": dict(
            threads=default_threads, backend="sbx", train_freq=8, gradient_steps=8
        ),
    }
    for name, settings in variants.items():
        rate = measure(args.steps, args.warmup, **settings)
        print(f"{name}: {rate:.1f} env steps/s; ratio {rate / baseline:.2f}x the defaults")
    mib = replay_buffer_bytes() / 2**20
    print(f"replay buffer of 1M transitions (float32 observations): {mib:.0f} MiB")


if __name__ == "__main__":
    main()
