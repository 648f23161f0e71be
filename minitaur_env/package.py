"""Write a trained agent as a Hugging Face Hub model folder, offline.

    python -m minitaur_env.package logs/sac/MinitaurBulletEnv-v0_3      # its best model
    python -m minitaur_env.package pretrained/sac/MinitaurBulletEnv-v0_1/best_model.zip -o hub

writes ``<out>/<algo>-<env>/``: the model zip, config.yml, env_kwargs.yml,
vec_normalize.pkl and its pickle-free vec_normalize.json, policy.onnx (the deterministic
actor, normalization folded in), results.json (20 unseen episodes), replay.mp4 and a
README.md model card, the layout of rl-baselines3-zoo's push_to_hub. Nothing is unpickled
unless --trust-pickle. Push it yourself, e.g.
``huggingface-cli upload <user>/sac-MinitaurBulletEnv-v0 hub/sac-MinitaurBulletEnv-v0``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from minitaur_env.training import OneLineErrorParser, commands


def main(argv: list[str] | None = None) -> int:
    parser = OneLineErrorParser(
        prog="python -m minitaur_env.package",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add = parser.add_argument
    add("run_or_model", type=Path, help="a run folder (its best model) or a model zip")
    add("-o", "--out", type=Path, default=Path("hub"), help="parent folder (default: hub)")
    add("--env", help="env id (default: the one the model was trained on)")
    add("--episodes", type=int, default=20, help="evaluation episodes (default: 20)")
    add("--seed", type=int, default=12345, help="seed of episode 0 (default: 12345)")
    add("--video-steps", type=int, default=1000, help="env steps in replay.mp4 (default: 1000)")
    add(
        "--trust-pickle",
        action="store_true",
        help="load pickles in or beside the model (they can run code: trusted files only)",
    )
    return commands.package(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
