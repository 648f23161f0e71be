"""How often can a policy whose only job is not to fall survive the env's pushes?

An upper bound for a pushes goal (<= 2 falls in 20 episodes under
``realism={pushes: true}``): PPO (the Minitaur entry's settings) learns to stay up
under Tan et al.'s pushes (130-220 N for 0.06 s every 1.2 s, any horizontal direction)
with a reward of 1 per step survived instead of the env's. Nothing else asks anything of
it: it may stand, crouch or walk. The training pushes grow from 0 to full force over the first
``--ramp`` of the steps; evaluations push at full force. It sees roll, pitch, their
rates and the motor angles (``observation="imu"``) for the last ``--history`` steps.

Prints, every ``--eval-freq`` steps and at the end on the 20 report seeds
(12345-12364, never used in training): falls, pushes begun per episode, and the share of
pushes survived. The baseline, measured in the same run before training: the legs held
at rest (the zero action).

With ``--forces F ...`` it also prints, for the zero action and the trained policy, the
share survived of pushes of exactly F newtons each, in the direction ``pushes`` sets
(``--env-kwargs 'realism={pushes: {direction: 90}}'`` trains and tests on pushes from the
side only) or in each of ``--directions`` (degrees, 0 forward). ``-n 0`` trains nothing:
the zero action alone, e.g. ``-n 0 --forces 60 130 220 --directions 0 45 90``. Every
figure is over ``--report-episodes`` (20) episodes from the report seeds.

    python benchmarks/push_bound.py [--env MinitaurBulletEnv-v0] [-n 1000000]
        [--env-kwargs dynamics_ranges=classic] [--seed 0] [--forces 60 130 220]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch
from gymnasium.wrappers import FlattenObservation, FrameStackObservation
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import minitaur_env  # noqa: F401  (registers the ids)
from minitaur_env import Pushes
from minitaur_env.training.callbacks import PushCurriculum
from minitaur_env.training.evaluation import run_episodes
from minitaur_env.training.hyperparams import (
    RUN_KEYS,
    algorithm_kwargs,
    load_hyperparams,
    parse_overrides,
)
from minitaur_env.training.seeds import REPORT_SEED, judging_block


class SurvivalReward(gym.Wrapper):
    """1 per step survived in place of the env's reward."""

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observation, _, terminated, truncated, info = self.env.step(action)
        return observation, 1.0, terminated, truncated, info


def with_pushes(kwargs: dict[str, Any], pushes: Any) -> dict[str, Any]:
    """``kwargs`` with its realism's ``pushes`` set to ``pushes``."""
    return {**kwargs, "realism": {**kwargs.get("realism", {}), "pushes": pushes}}


def make_env(env_id: str, kwargs: dict[str, Any], history: int) -> gym.Env:
    pushes = kwargs.get("realism", {}).get("pushes", True)
    env = gym.make(env_id, **{"observation": "imu", **with_pushes(kwargs, pushes)})
    if history > 1:
        env = FlattenObservation(FrameStackObservation(env, history))
    return SurvivalReward(env)


class Tally(NamedTuple):
    falls: int
    pushes_per_episode: float
    survived: float  # share of pushes begun that the robot was still up after
    unpushed_falls: int  # falls before any push: the policy's own, not the pushes'

    def line(self, episodes: int) -> str:
        own = f"  ({self.unpushed_falls} before any push)" if self.unpushed_falls else ""
        return (
            f"falls {self.falls}/{episodes}  pushes begun {self.pushes_per_episode:.1f}/episode"
            f"  survived {self.survived:.1%}{own}"
        )


def play(policy: Any, env: gym.Env, seeds: range) -> Tally:
    """Falls, pushes begun per episode and the share of pushes survived."""
    records = run_episodes(policy, env, len(seeds), seed=seeds.start)
    falls = sum(int(record["fell"]) for record in records)
    pushes = sum(int(record["pushes"]) for record in records)
    unpushed = sum(int(record["fell"] and not record["pushes"]) for record in records)
    survived = 1.0 - (falls - unpushed) / max(pushes, 1)
    return Tally(falls, pushes / len(seeds), survived, unpushed)


class Evaluation(BaseCallback):
    """Prints falls and pushes survived at full force every ``freq`` steps."""

    def __init__(self, env: gym.Env, freq: int, episodes: int) -> None:
        super().__init__()
        self.env, self.freq, self.episodes, self._next = env, freq, episodes, freq
        self.started = time.monotonic()

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next = (self.num_timesteps // self.freq + 1) * self.freq
            report(f"{self.num_timesteps:>9,}", self.model, self.env, range(self.episodes))
            print(f"{'':>9}  ({(time.monotonic() - self.started) / 60:.1f} min)", flush=True)
        return True


def deterministic_policy(model: PPO) -> Callable[[np.ndarray], np.ndarray]:
    normalizer = model.get_env()

    def policy(observation: np.ndarray) -> np.ndarray:
        normalized = normalizer.normalize_obs(observation[None])
        return model.predict(normalized, deterministic=True)[0][0]

    return policy


def report(label: str, model: PPO, env: gym.Env, seeds: range) -> None:
    print(f"{label}  {play(deterministic_policy(model), env, seeds).line(len(seeds))}", flush=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="MinitaurBulletEnv-v0")
    parser.add_argument("--env-kwargs", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("-n", "--timesteps", type=int, default=1_000_000, help="0: no training")
    parser.add_argument("--ramp", type=float, default=0.5, help="share of steps to full force")
    parser.add_argument("--history", type=int, default=4)
    parser.add_argument("--eval-freq", type=int, default=100_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--report-episodes", type=int, default=20, help="episodes from the report seeds"
    )
    parser.add_argument(
        "--forces",
        type=float,
        nargs="*",
        default=[],
        metavar="N",
        help="at the end, the share survived of pushes of exactly N newtons, per N",
    )
    parser.add_argument(
        "--directions",
        type=float,
        nargs="*",
        default=[],
        metavar="DEGREES",
        help="with --forces: per direction of the pushes (default: the pushes' own)",
    )
    args = parser.parse_args(argv)
    if args.timesteps < 0:
        parser.error(f"-n must be 0 or more steps, got {args.timesteps}")
    if args.directions and not args.forces:
        parser.error("--directions needs --forces")
    if args.report_episodes < 1:
        parser.error(f"--report-episodes must be 1 or more, got {args.report_episodes}")
    torch.set_num_threads(1)
    report_seeds = judging_block(REPORT_SEED, args.report_episodes)
    kwargs = parse_overrides(args.env_kwargs, "--env-kwargs")
    if not isinstance(kwargs.get("realism", {}), dict):
        parser.error(
            "--env-kwargs realism must be a mapping of fields, e.g. 'realism={pushes: sagittal}'"
        )

    evaluation_env = make_env(args.env, kwargs, args.history)
    zeros = np.zeros(evaluation_env.action_space.shape)
    tally = play(lambda _: zeros, evaluation_env, report_seeds)
    print(f"baseline, zero action on the report seeds: {tally.line(len(report_seeds))}", flush=True)
    policies: dict[str, Callable[[np.ndarray], np.ndarray]] = {"zero action": lambda _: zeros}
    if args.timesteps == 0:
        by_force(args, kwargs, policies)
        return

    # The PPO entry of the Minitaur (ppo.yml), on the survival reward.
    entry = load_hyperparams("ppo", args.env, entry="minitaur")
    envs = [lambda: make_env(args.env, kwargs, args.history)] * entry["n_envs"]
    venv = DummyVecEnv(envs)
    venv.seed(args.seed)
    venv = VecNormalize(venv, gamma=entry["gamma"])
    settings = {key: value for key, value in entry.items() if key not in RUN_KEYS}
    model = PPO(entry["policy"], venv, seed=args.seed, **algorithm_kwargs(settings))
    callbacks = [
        PushCurriculum(start=0.0, full_at=int(args.ramp * args.timesteps)),
        Evaluation(evaluation_env, args.eval_freq, args.eval_episodes),
    ]
    model.learn(args.timesteps, callback=callbacks)
    venv.training = False
    report(f"report seeds ({len(report_seeds)})", model, evaluation_env, report_seeds)
    by_force(args, kwargs, {**policies, "trained": deterministic_policy(model)})


def by_force(
    args: argparse.Namespace,
    kwargs: dict[str, Any],
    policies: dict[str, Callable[[np.ndarray], np.ndarray]],
) -> None:
    """Per force (and direction) and policy: the share of pushes survived on the report seeds."""
    report_seeds = judging_block(REPORT_SEED, args.report_episodes)
    pushes = dataclasses.asdict(Pushes.coerce(kwargs.get("realism", {}).get("pushes", True)))
    directions = args.directions or [pushes.get("direction")]
    for force in args.forces:
        for direction in directions:
            setting = {**pushes, "force": (force, force), "direction": direction}
            env = make_env(args.env, with_pushes(kwargs, setting), args.history)
            label = f"{force:>6.0f} N" + (f"  {direction:>4.0f} deg" if args.directions else "")
            for name, policy in policies.items():
                tally = play(policy, env, report_seeds)
                print(f"{label}  {name:<12}  {tally.line(len(report_seeds))}", flush=True)


if __name__ == "__main__":
    main()
