"""Pick a policy to ship from trained runs, without peeking at the seeds it is reported on.

``python -m minitaur_env.ship``: the same command as ``minitaur ship``, whose flags
``minitaur_env.cli`` defines.
"""

from __future__ import annotations

import sys

from minitaur_env.cli import run


def main(argv: list[str] | None = None) -> int:
    return run("ship", argv, prog="python -m minitaur_env.ship")


if __name__ == "__main__":
    sys.exit(main())
