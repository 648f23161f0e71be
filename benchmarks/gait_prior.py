"""What the trotting generator does alone: the gait prior's policy outputting zeros.

For each generator setting, plays the zero action for whole episodes on the trotting
ids and prints the return, the speed and the falls, under the classic dynamics, Tan et
al.'s randomization (``MinitaurBulletTrotRandomized-v0``) and that with pushes. The
baseline, measured in the same run: the classic env holding its zero action (every leg
at rest), which is what a policy outputting zeros does without the prior.

``--push-forces`` also measures how hard the pushes are: at each fixed force, every 1.2 s
under the classic dynamics, in a random horizontal direction or in each of
``--push-directions`` (degrees; 0 forward, 90 to the left), how many pushes the legs at
rest and the open-loop trot take, and how many episodes end in a fall.

    python benchmarks/gait_prior.py [--episodes 5] [--frequency 2.5 4] [--extension 0.6]
        [--swing 0.3] [--push-forces 40 80 120 160] [--push-directions 0 45 90]
"""

from __future__ import annotations

import argparse
import itertools
from typing import Any

import gymnasium as gym
import numpy as np

import minitaur_env  # registers the ids
from minitaur_env.training.evaluation import run_episodes

CONDITIONS = {
    "classic": ("MinitaurBulletTrot-v0", {}),
    "tan2018": ("MinitaurBulletTrotRandomized-v0", {}),
    "tan2018 + pushes": ("MinitaurBulletTrotRandomized-v0", {"realism": {"pushes": True}}),
}


def zero_action_episodes(
    env_id: str, kwargs: dict[str, Any], episodes: int, action_size: int
) -> list[dict[str, float]]:
    """The zero action's episodes on seeds 0.. (``run_episodes``' records)."""
    env = gym.make(env_id, **kwargs)
    try:
        return run_episodes(lambda _: np.zeros(action_size), env, episodes, seed=0)
    finally:
        env.close()


def play(env_id: str, kwargs: dict[str, Any], episodes: int, action_size: int) -> str:
    """Mean return, mean speed and falls of the zero action over seeded episodes."""
    records = zero_action_episodes(env_id, kwargs, episodes, action_size)
    returns = [record["return"] for record in records]
    speeds = [record["speed"] for record in records]
    falls = int(sum(record["fell"] for record in records))
    return f"{np.mean(returns):6.2f} at {np.mean(speeds):4.2f} m/s, {falls} falls"


def pushes_taken(
    env_id: str, force: float, direction: float | None, episodes: int, action_size: int
) -> str:
    """Pushes begun and falls over seeded episodes, every push of ``force`` newtons."""
    pushes = {"force": [force, force], "direction": direction}
    records = zero_action_episodes(env_id, {"realism": {"pushes": pushes}}, episodes, action_size)
    begun = int(sum(record["pushes"] for record in records))
    return f"{begun} pushes, {int(sum(record['fell'] for record in records))} falls"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5, help="seeds 0..N-1 per cell")
    parser.add_argument("--frequency", type=float, nargs="+", default=[minitaur_env.Trot.frequency])
    parser.add_argument("--extension", type=float, nargs="+", default=[minitaur_env.Trot.extension])
    parser.add_argument("--swing", type=float, nargs="+", default=[minitaur_env.Trot.swing])
    parser.add_argument(
        "--conditions",
        nargs="+",
        choices=list(CONDITIONS),
        default=list(CONDITIONS),
        help="the worlds played (default: all)",
    )
    parser.add_argument("--push-forces", type=float, nargs="*", default=[], metavar="N")
    parser.add_argument("--push-directions", type=float, nargs="+", metavar="DEG")
    args = parser.parse_args()

    print(f"zero action, {args.episodes} episodes (seeds 0-{args.episodes - 1}) per cell")
    classic_ids = {"classic": "MinitaurBulletEnv-v0", "tan2018": "MinitaurBulletRandomized-v0"}
    conditions = {name: CONDITIONS[name] for name in args.conditions}
    for condition, (_, kwargs) in conditions.items():
        env_id = classic_ids.get(condition, "MinitaurBulletRandomized-v0")
        print(f"baseline, no generator, {condition}: {play(env_id, kwargs, args.episodes, 8)}")
    for frequency, extension, swing in itertools.product(
        args.frequency, args.extension, args.swing
    ):
        gait = {"frequency": frequency, "extension": extension, "swing": swing}
        for condition, (env_id, kwargs) in conditions.items():
            figures = play(env_id, {**kwargs, "gait": gait}, args.episodes, 11)
            print(
                f"trot {frequency:g} Hz, extension {extension:g}, swing {swing:g}, "
                f"{condition}: {figures}"
            )
    for force, direction in itertools.product(args.push_forces, args.push_directions or [None]):
        rest = pushes_taken("MinitaurBulletEnv-v0", force, direction, args.episodes, 8)
        trot = pushes_taken("MinitaurBulletTrot-v0", force, direction, args.episodes, 11)
        towards = "random directions" if direction is None else f"{direction:g} degrees"
        print(f"pushes of {force:g} N, {towards}: legs at rest {rest}; default trot {trot}")


if __name__ == "__main__":
    main()
