"""Evaluate a trained policy: statistics over N episodes, and optionally its video.

The card's script: the same command as ``minitaur evaluate``; ``python evaluate.py
--help`` lists its flags. With no arguments it plays the best shipped policy in
pretrained/, else the best model of the most recent run under logs/.
"""

from __future__ import annotations

import sys

from minitaur_env.cli import run


def main(argv: list[str] | None = None) -> int:
    return run("evaluate", argv, prog="evaluate.py")


if __name__ == "__main__":
    sys.exit(main())
