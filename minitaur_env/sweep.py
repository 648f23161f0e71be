"""Many training runs on Ray Tune: a configuration over seeds, or a hyperparameter search.

``python -m minitaur_env.sweep``: the same command as ``minitaur sweep``, whose flags
``minitaur_env.cli`` defines.
"""

from __future__ import annotations

import sys

from minitaur_env.cli import run


def main(argv: list[str] | None = None) -> int:
    return run("sweep", argv, prog="python -m minitaur_env.sweep")


if __name__ == "__main__":
    sys.exit(main())
