"""Write a trained agent as a Hugging Face Hub model folder, offline.

``python -m minitaur_env.package``: the same command as ``minitaur package``, whose flags
``minitaur_env.cli`` defines.
"""

from __future__ import annotations

import sys

from minitaur_env.cli import run


def main(argv: list[str] | None = None) -> int:
    return run("package", argv, prog="python -m minitaur_env.package")


if __name__ == "__main__":
    sys.exit(main())
