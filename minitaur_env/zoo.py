"""Run an rl-baselines3-zoo script with this package's env ids registered.

``python -m minitaur_env.zoo SCRIPT ...``: the same command as ``minitaur zoo SCRIPT ...``.
"""

from __future__ import annotations

import sys

from minitaur_env.cli import run


def main(argv: list[str] | None = None) -> int:
    return run("zoo", argv, prog="python -m minitaur_env.zoo")


if __name__ == "__main__":
    sys.exit(main())
