"""Export a trained policy's deterministic actor as ONNX, its normalization folded in.

    python -m minitaur_env.onnx pretrained/sac/MinitaurBulletEnv-v0_1 -o policy.onnx
    python -m minitaur_env.onnx logs/ppo/MinitaurBulletEnv-v0_2/best_model.zip -o best.onnx
    python evaluate.py --model policy.onnx            # plays it with onnxruntime, no torch

A run folder exports its final model. Input ``obs``: raw float32 observations, shape
(batch, obs_dim); output ``action``: the action in env units. SAC, TQC, CrossQ and TD3
(tanh-squashed mean) and PPO and A2C (Gaussian mean, clipped to the bounds) export; the
file is written only after onnxruntime's actions match the model's ``predict`` to 1e-5.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from minitaur_env.training import OneLineErrorParser, commands

PROGRAM = "python -m minitaur_env.onnx"


def main(argv: list[str] | None = None) -> int:
    parser = OneLineErrorParser(
        prog=PROGRAM, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_or_model", type=Path, help="a run folder or a model zip")
    parser.add_argument(
        "-o", "--output", type=Path, default=Path("policy.onnx"), help="default: policy.onnx"
    )
    parser.add_argument(
        "--trust-pickle", action="store_true",
        help="load pickles in or beside the model (they can run code: trusted files only)",
    )  # fmt: skip
    return commands.export_onnx(parser.parse_args(argv), PROGRAM)


if __name__ == "__main__":
    sys.exit(main())
