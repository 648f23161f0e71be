"""Train an SB3 / sb3-contrib agent (SAC on MinitaurBulletEnv-v0 by default).

The card's script: the same command as ``minitaur train``; ``python train.py --help``
lists its flags, ``minitaur_env.cli`` defines them and ``minitaur_env.training.Experiment``
does the work.
"""

from __future__ import annotations

import argparse
import sys

from minitaur_env.cli import run, train_parser


def build_parser(without_defaults: bool = False) -> argparse.ArgumentParser:
    return train_parser("train.py", without_defaults)


def main(argv: list[str] | None = None) -> int:
    return run("train", argv, prog="train.py")


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # before main() could take over, e.g. during imports
        sys.exit(130)
