"""Pick a policy to ship from trained runs, without peeking at the seeds it is reported on.

    python -m minitaur_env.ship logs/sac/MinitaurBulletEnv-v0_{1,2,3} --final-only \
        --json report.json --ship pretrained/sac/MinitaurBulletEnv-v0_1
    python -m minitaur_env.ship RUN --from-steps 200000          # checkpoints too

Each candidate plays ``--select-episodes`` deterministic episodes on selection seeds
(5000..), which neither training nor the report (12345..) uses; the one with the fewest
falls, then the highest mean, is chosen and only then played on the report seeds.
With ``--also-on KEY=VALUE...`` each candidate is also judged with those env kwargs
changed (e.g. a policy trained under randomization, on the classic dynamics too).
Candidates are each run's best model, final model and checkpoints from ``--from-steps``
on, or with ``--final-only`` the final models alone (what the training command ends
with). ``--ship`` writes the chosen model as a zoo run folder with its statistics,
policy.onnx and provenance.yml (then ``python -m minitaur_env.package`` makes its Hub
folder).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from minitaur_env.training import OneLineErrorParser, commands


def main(argv: list[str] | None = None) -> int:
    parser = OneLineErrorParser(
        prog="python -m minitaur_env.ship",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add = parser.add_argument
    add("runs", nargs="+", type=Path, help="run folders to choose from")
    add("--final-only", action="store_true", help="candidates: the final models only")
    add("--from-steps", type=int, default=200_000, help="checkpoints from N steps on")
    add("--steps", type=int, nargs="+", help="only these checkpoints")
    add("--episodes", type=int, default=20, help="report episodes (default: 20)")
    add(
        "--select-episodes", type=int,
        help="episodes per candidate on the selection seeds (default: --episodes); more "
        "of them tell a policy that falls once in 40 from one that never falls",
    )  # fmt: skip
    add(
        "--also-on", nargs="+", action="append", metavar="KEY=VALUE",
        help="also judge each candidate on its env with these --env-kwargs (repeatable); "
        "falls are summed and means averaged over its own env and these",
    )  # fmt: skip
    add("--select-seed", type=int, default=5000, help="seed of selection episode 0")
    add("--report-seed", type=int, default=12345, help="seed of report episode 0")
    add("--json", type=Path, help="write the whole report here")
    add("--ship", type=Path, help="write the chosen model here (a zoo run folder)")
    add(
        "--trust-pickle", action="store_true",
        help="load pickles (SBX models, statistics without their JSON): trusted runs only",
    )  # fmt: skip
    return commands.ship(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
