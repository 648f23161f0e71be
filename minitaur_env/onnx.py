"""Export a trained policy's deterministic actor as ONNX, its normalization folded in.

``python -m minitaur_env.onnx``: the same command as ``minitaur onnx``, whose flags
``minitaur_env.cli`` defines.
"""

from __future__ import annotations

import sys

from minitaur_env.cli import run


def main(argv: list[str] | None = None) -> int:
    return run("onnx", argv, prog="python -m minitaur_env.onnx")


if __name__ == "__main__":
    sys.exit(main())
