"""Robustness of trained policies to the sim-to-real knobs: one row per policy, one column
per condition, each cell the mean +- std return and the falls over unseen episodes.

    python benchmarks/robustness.py                          # the shipped policies
    python benchmarks/robustness.py --policy preset-ppo=logs/preset/ppo/M_1/best_model.zip

Every cell is what ``python evaluate.py --model M --episodes 20 --seed 12345
--env MinitaurBulletEnv-v0 --env-kwargs K`` reports, with K the column's keyword
arguments (printed below the table). The episodes' seeds (12345..) are the docs'
report seeds, never used in training or selection; the env is ``MinitaurBulletEnv-v0``
whatever the policy was trained on, or ``MinitaurBulletTrot-v0`` (the same env under the
gait prior) for a policy trained with the gait prior, whose actions only it takes. Of the
policy's own env kwargs only those that say what it observes and how it acts (``INTERFACE``)
are kept; the world is the column's.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from minitaur_env import RANDOMIZED_KWARGS
from minitaur_env.cli import add_trust_pickle, labelled_files, refuse_in_one_line
from minitaur_env.gait import has_gait_prior
from minitaur_env.training import OneLineErrorParser
from minitaur_env.training.evaluation import load_policy, pretrained_models
from minitaur_env.training.seeds import REPORT_SEED
from minitaur_env.training.shipping import condition_label, judge

INTERFACE = ("observation", "history", "gait", "observe_control_step")
ENV_ID = "MinitaurBulletEnv-v0"
GAIT_ENV_ID = "MinitaurBulletTrot-v0"
CONDITIONS: dict[str, dict[str, Any]] = {
    "nominal": {},
    "latency 20 ms": {"realism": {"control_latency": 0.02}},
    "latency 40 ms": {"realism": {"control_latency": 0.04}},
    "motor strength 80 %": {"dynamics_ranges": {"motor_strength": [0.8, 0.8]}},
    "contact friction 0.5": {"dynamics_ranges": {"foot_friction": [0.5, 0.5]}},
    "pushes": {"realism": {"pushes": True}},
    "sagittal pushes": {"realism": {"pushes": "sagittal"}},
    "walking pushes": {"realism": {"pushes": "walking"}},
    "full preset": dict(RANDOMIZED_KWARGS),
}


def main(argv: list[str] | None = None) -> int:
    parser = OneLineErrorParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="LABEL=MODEL.zip",
        help="a policy to judge (default: every shipped policy)",
    )
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=REPORT_SEED)
    parser.add_argument("--conditions", nargs="+", choices=list(CONDITIONS), metavar="NAME")
    parser.add_argument("--json", type=Path, help="also write the cells as JSON")
    add_trust_pickle(parser)
    args = parser.parse_args(argv)
    return refuse_in_one_line(parser.prog, lambda: judge_all(args))


def shipped_policies() -> dict[str, Path]:
    """Every shipped policy, labelled by its folder: pretrained/ppo holds more than one."""
    return {
        f"shipped {model.parents[1].name}/{model.parent.name}": model
        for _, model in pretrained_models()
    }


def judge_all(args: argparse.Namespace) -> int:
    policies = labelled_files(args.policy, "--policy") if args.policy else shipped_policies()
    conditions = {name: CONDITIONS[name] for name in args.conditions or CONDITIONS}

    cells: dict[str, dict[str, dict[str, float]]] = {}
    for label, model in policies.items():
        policy = load_policy(model, trust_pickle=args.trust_pickle)
        env_id = GAIT_ENV_ID if has_gait_prior(policy.env_id or ENV_ID) else ENV_ID
        interface = {k: v for k, v in policy.env_kwargs.items() if k in INTERFACE}
        for name, kwargs in conditions.items():
            played_on = (env_id, {**interface, **kwargs})
            cell = judge(
                model, args.episodes, args.seed, env=played_on, trust_pickle=args.trust_pickle
            )
            cells.setdefault(label, {})[name] = cell
            print(
                f"{label:24s} {name:22s} {cell['mean']:6.2f} +- {cell['std']:5.2f}  "
                f"falls {cell['falls']}/{args.episodes}",
                flush=True,
            )

    print(
        f"\n| policy ({args.episodes} episodes, seeds {args.seed}..) | "
        + " | ".join(conditions)
        + " |"
    )
    print("|---" * (len(conditions) + 1) + "|")
    for label, row in cells.items():
        texts = [f"{c['mean']:.2f} ± {c['std']:.2f} ({c['falls']} falls)" for c in row.values()]
        print(f"| {label} | " + " | ".join(texts) + " |")
    print()
    for name, kwargs in conditions.items():
        flags = condition_label(kwargs)
        print(f"{name}: --env-kwargs {flags}" if flags else f"{name}: (no --env-kwargs)")
    if args.json:
        args.json.write_text(json.dumps(cells, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
