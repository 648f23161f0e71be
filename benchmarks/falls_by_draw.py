"""Where policies fall: deterministic episodes of each policy's own env, every episode's drawn
dynamics and realism recorded, the falls and returns tallied by the drawn control step and
control latency, the policies side by side (the first is the baseline).

    python benchmarks/falls_by_draw.py --csv falls.csv \\
        --policy entry=benchmarks/results/trot-lin/seed1/MinitaurBulletTrotRandomized-v0.zip \\
        --policy hard=benchmarks/results/trot-hard/seed1/MinitaurBulletTrotRandomized-v0.zip

The episodes are what ``python evaluate.py --model M --episodes N --seed 20000`` plays
(seeds from ``FALLS_SEED``, a judging block of their own), so policies of the same env meet
the same draws. A fall rate is printed with its 95 % Wilson interval: at a few falls in
150 episodes two policies seldom differ by more than chance.

A policy already studied need not play again: ``--policy entry=falls.csv`` takes the
episodes of ``entry`` from an earlier ``--csv`` table (they must be the same seeds, and
every policy's env the same), so a new policy is compared in half the time.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from minitaur_env.cli import add_trust_pickle, labelled_files, refuse_in_one_line
from minitaur_env.training import OneLineErrorParser, UsageError
from minitaur_env.training.evaluation import load_policy, playing_kwargs, run_episodes
from minitaur_env.training.files import atomic_path
from minitaur_env.training.seeds import FALLS_SEED, judging_block
from minitaur_env.training.single_env import make_env

# What the table groups episodes by, in ms, and its default bin edges: the range of
# the Tan 2018 preset split where the falls of docs/sim-to-real.md were read.
GROUPED_BY = {
    "control_time_step": ("control step", (3.0, 8.0, 12.0, 16.0, 20.0)),
    "control_latency": ("control latency", (0.0, 10.0, 20.0, 30.0, 40.0)),
}


def drawn(info: dict[str, Any]) -> dict[str, float]:
    """An episode's drawn dynamics and realism from its reset's info, one number a field
    (a per-motor or per-axis draw as its mean)."""
    fields: dict[str, float] = {}
    for key in ("dynamics", "realism"):
        if info.get(key) is None:
            continue
        for name, value in dataclasses.asdict(info[key]).items():
            if value is not None:
                fields[name] = float(np.mean(value))
    return fields


def wilson_interval(falls: int, episodes: int, z: float = 1.96) -> tuple[float, float]:
    """The 95 % Wilson score interval of a fall rate (sound at 0 or a few falls)."""
    share = falls / episodes
    centre = (share + z * z / (2 * episodes)) / (1 + z * z / episodes)
    half = z * math.sqrt(share * (1 - share) / episodes + z * z / (4 * episodes**2))
    half /= 1 + z * z / episodes
    return max(0.0, centre - half), min(1.0, centre + half)


def bin_labels(edges: tuple[float, ...]) -> list[str]:
    """The bins' labels in order, below and above the edges included."""
    inside = [f"{low:g}-{high:g} ms" for low, high in itertools.pairwise(edges)]
    return [f"< {edges[0]:g} ms", *inside, f"> {edges[-1]:g} ms"]


def bin_label(value_ms: float, edges: tuple[float, ...]) -> str:
    """A bin holds its upper edge, the first also its lower one: the control step is drawn
    in whole physics steps, so 8 ms goes with 4-6 ms as in docs/sim-to-real.md's table."""
    if value_ms == edges[0]:
        return bin_labels(edges)[1]
    return bin_labels(edges)[int(np.searchsorted(edges, value_ms, side="left"))]


def tally(records: dict[str, list[dict[str, float]]], field: str, edges: tuple[float, ...]) -> str:
    """A markdown table: per bin of ``field``, each policy's falls, episodes and mean return."""
    cells: dict[str, dict[str, list[dict[str, float]]]] = {}
    for label, episodes in records.items():
        for record in episodes:
            group = bin_label(round(1000 * record[field], 6), edges)
            cells.setdefault(group, {}).setdefault(label, []).append(record)
    name = GROUPED_BY[field][0]
    columns = [f"{label}: falls / episodes (mean return)" for label in records]
    lines = [
        f"| {name} drawn | " + " | ".join(columns) + " |",
        "|---" * (len(records) + 1) + "|",
    ]
    for group in [group for group in bin_labels(edges) if group in cells] + ["all"]:
        row = []
        for label in records:
            played = records[label] if group == "all" else cells[group].get(label, [])
            falls = int(sum(record["fell"] for record in played))
            mean = np.mean([record["return"] for record in played]) if played else float("nan")
            row.append(f"{falls} / {len(played)} ({mean:.2f})")
        lines.append(f"| {group} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def play(policy: Any, model: Path, seeds: range) -> list[dict[str, float]]:
    """The policy's deterministic episodes on ``seeds`` of its own env, each with its draws."""
    env = make_env(policy.env_id, playing_kwargs(policy, {}))
    try:
        missing = [field for field in GROUPED_BY if field not in drawn(env.reset()[1])]
        if missing:
            raise UsageError(
                f"{model}: its env ({policy.env_id}) draws no {' or '.join(missing)} "
                "per episode, so there is nothing to group its falls by"
            )
        return run_episodes(policy, env, len(seeds), seeds.start, from_reset=drawn)
    finally:
        env.close()


def recorded_episodes(table: Path, label: str, seeds: range) -> tuple[str, list[dict[str, float]]]:
    """``label``'s episodes from an earlier ``--csv`` (its env and records), refused unless
    they are the episodes asked for: the same seeds, in order."""
    with table.open(newline="") as file:
        rows = list(csv.DictReader(file))
    labels = list(dict.fromkeys(row.get("policy") for row in rows))
    mine = [row for row in rows if row.get("policy") == label]
    if not mine:
        raise UsageError(f"{table} holds no episodes of {label!r} (its policies: {labels})")
    needed = {"env", "episode_seed", "return", "fell", *GROUPED_BY}
    if not needed <= set(mine[0]):
        missing = ", ".join(sorted(needed - set(mine[0])))
        raise UsageError(f"{table} is not a falls_by_draw.py --csv table: it has no {missing}")
    held = [int(row["episode_seed"]) for row in mine]
    if held != list(seeds):
        raise UsageError(
            f"{table} holds {label!r} on seeds {held[0]}..{held[-1]} ({len(held)} episodes), "
            f"not the {seeds.start}..{seeds.stop - 1} asked (--seed, --episodes)"
        )
    envs = {row["env"] for row in mine}
    if len(envs) > 1:
        raise UsageError(f"{table} holds {label!r} on more than one env: {sorted(envs)}")
    skipped = {"policy", "env", "episode_seed"}
    records = []
    for row in mine:
        record = {}
        for name, value in row.items():
            if name in skipped or not value:
                continue
            try:
                record[name] = float(value)
            except ValueError:
                raise UsageError(
                    f"{table}: {label!r} episode {row['episode_seed']} has {name} {value!r}, "
                    "not a number"
                ) from None
        records.append(record)
    return envs.pop(), records


def main(argv: list[str] | None = None) -> int:
    parser = OneLineErrorParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--policy",
        action="append",
        required=True,
        metavar="LABEL=MODEL.zip|TABLE.csv",
        help="a policy to play, or its episodes in an earlier --csv table; give it more than "
        "once to compare (the first is the baseline)",
    )
    parser.add_argument("--episodes", type=int, default=150)
    parser.add_argument("--seed", type=int, default=FALLS_SEED, help="seed of episode 0")
    parser.add_argument("--csv", type=Path, help="also write every episode, one row each")
    add_trust_pickle(parser)
    args = parser.parse_args(argv)
    return refuse_in_one_line(parser.prog, lambda: study(args))


def study(args: argparse.Namespace) -> int:
    if args.episodes < 1:
        raise UsageError(f"--episodes must be at least 1, got {args.episodes}")
    try:
        seeds = judging_block(args.seed, args.episodes)
    except ValueError as error:
        raise UsageError(str(error)) from error
    sources = labelled_files(args.policy, "--policy")
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)

    # Every refusal comes before the first episode: a study can take hours.
    recorded: dict[str, list[dict[str, float]]] = {}
    policies: dict[str, Any] = {}
    env_ids: dict[str, str] = {}
    for label, source in sources.items():
        if source.suffix == ".csv":
            env_ids[label], recorded[label] = recorded_episodes(source, label, seeds)
        else:
            policies[label] = load_policy(source, trust_pickle=args.trust_pickle)
            env_ids[label] = policies[label].env_id
    if len(set(env_ids.values())) > 1:
        envs = ", ".join(f"{label}: {env_id}" for label, env_id in env_ids.items())
        raise UsageError(f"the policies' episodes come from different envs ({envs})")

    records: dict[str, list[dict[str, float]]] = {}
    for label, source in sources.items():
        if label in recorded:
            records[label] = recorded[label]
        else:
            records[label] = play(policies[label], source, seeds)
        played = records[label]
        falls = int(sum(record["fell"] for record in played))
        low, high = wilson_interval(falls, len(played))
        print(
            f"{label}: {falls} falls in {len(played)} episodes ({100 * falls / len(played):.1f} %, "
            f"95 % interval {100 * low:.1f}-{100 * high:.1f} %), mean return "
            f"{np.mean([record['return'] for record in played]):.2f}; {source}",
            flush=True,
        )

    baseline = next(iter(records))
    print(f"\nepisodes: seeds {seeds.start}..{seeds.stop - 1}; baseline: {baseline}")
    for field, (_, edges) in GROUPED_BY.items():
        print()
        print(tally(records, field, edges))
    if args.csv:
        columns = ["policy", "env", "episode_seed"]
        for played in records.values():
            columns += [name for name in played[0] if name not in columns]
        with atomic_path(args.csv) as staged, staged.open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=columns)
            writer.writeheader()
            for label, played in records.items():
                for seed, record in zip(seeds, played, strict=True):
                    row = {"policy": label, "env": env_ids[label], "episode_seed": seed}
                    writer.writerow({**row, **record})
    return 0


if __name__ == "__main__":
    sys.exit(main())
