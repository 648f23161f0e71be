"""The Minitaur benchmark table and the SAC ablation table, from kept run folders.

Each row is a configuration over seeds; each seed a run folder kept by
``benchmarks/keep_runs.py`` (final model in the zoo's layout, evaluations, monitors).
Per row it prints:

- the final models (the model at ``n_timesteps``, no checkpoint picked) on ``--episodes``
  deterministic episodes from ``--report-seed`` (12345.., seeds no training, evaluation or
  selection uses): mean per seed, median, falls per seed, IQM over seeds with its 95 %
  stratified bootstrap CI (rliable);
- from the runs' periodic evaluations: the lowest evaluation and the largest drop below an
  earlier peak once 15 was first reached, steps and minutes to 5 and to 15 (median over
  the seeds that got there), and env steps/s (evaluations included).

Judging a final model plays its episodes once and stores the result beside it
(``final_model_report.json``, keyed by the model file's SHA-256); ``--rejudge`` plays
them again. ``--plot`` redraws figure 1 (IQM curves against env steps, left, and
wall-clock, right).

    python benchmarks/minitaur_table.py                      # the benchmark table
    python benchmarks/minitaur_table.py --table ablation     # the SAC ablation
    python benchmarks/minitaur_table.py --row "mine=logs/kept/seed*" --plot mine.png
    python benchmarks/minitaur_table.py --table sac-screen   # a "curves" table

A table of kind "curves" in tables.yml shows the runs' periodic evaluations at given
steps, a line per run or one line of medians, and plays no episodes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from glob import glob
from pathlib import Path

import gymnasium as gym
import numpy as np
import yaml

from minitaur_env.cli import refuse_in_one_line
from minitaur_env.training import OneLineErrorParser, UsageError
from minitaur_env.training.aggregate import GroupSummary, RunCurve, iqm_with_ci, plot_iqm_curves
from minitaur_env.training.files import atomic_path
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.seeds import REPORT_SEED
from minitaur_env.training.shipping import judge

RESULTS = Path(__file__).resolve().parent / "results"
# A row glob ending in this judges an actor_ema run's live actor: the model the same run
# ends with without the average, since the average does not change training.
LIVE = "#live-actor"
TABLES_FILE = Path(__file__).resolve().parent / "tables.yml"
TABLES: dict[str, dict] = yaml.safe_load(TABLES_FILE.read_text())
FALL_WINDOW = (50_000, 150_000)
REPORT_EPISODES = 20
NONE = "-"


def final_report(
    run: RunFolder,
    episodes: int,
    seed: int,
    rejudge: bool,
    live_actor: bool = False,
    trust: bool = False,
    stored_only: bool = False,
) -> dict | None:
    """The final model's result on the report episodes, or None if none was kept;
    ``stored_only`` refuses to play episodes for a result not stored yet."""
    model = run.final_model
    cache = run.final_model_report(live_actor)
    if not model.is_file():  # a run whose model was not kept may have a recorded result
        return json.loads(cache.read_text()) if cache.is_file() else None
    digest = hashlib.sha256(model.read_bytes()).hexdigest()
    key = {"model_sha256": digest, "episodes": episodes, "report_seed": seed}
    if cache.is_file() and not rejudge:
        stored = json.loads(cache.read_text())
        if all(stored.get(k) == v for k, v in key.items()):
            return stored
    if stored_only:
        raise UsageError(f"{model} has no stored report; run minitaur_table.py to judge it")
    result = {**key, **judge(model, episodes, seed, live_actor=live_actor, trust_pickle=trust)}
    with atomic_path(cache) as temp:  # a stopped judge leaves no half-written result
        temp.write_text(json.dumps(result, indent=1) + "\n")
    return result


def training_fall_share(run: RunFolder, low: int, high: int) -> float:
    """The share of exploring (training) episodes ending between env steps ``low`` and
    ``high`` that ended in a fall: before the env's time limit. A policy whose exploration
    noise topples the robot learns from falls while its deterministic evaluations walk."""
    config = run.read_config()
    # A run's training episodes end at its own time limit; training_episode_steps is
    # that of the kept sbx-mirror-g098-ep250 screen (the setting of commit 7843756).
    limit = (
        config.get("hyperparams", {}).get("training_episode_steps")
        or config.get("env_kwargs", {}).get("max_episode_steps")
        or gym.spec(config["env"]).max_episode_steps
    )
    episodes = sorted(run.monitor_episodes(), key=lambda episode: episode.training_time)
    ends = np.cumsum([episode.length for episode in episodes])  # env steps, all envs
    window = [e.length < limit for e, end in zip(episodes, ends, strict=True) if low < end <= high]
    return float(np.mean(window)) if window else np.nan


def cell(values: list[float], digits: int = 2) -> str:
    return " ".join(NONE if not np.isfinite(v) else f"{v:.{digits}f}" for v in values)


def median(values: list[float], scale: float = 1.0, digits: int = 1) -> str:
    finite = [v for v in values if np.isfinite(v)]
    return f"{np.median(finite) * scale:.{digits}f}" if finite else NONE


def kilo(text: str) -> str:
    return text if text == NONE else f"{text}k"


def row(
    label: str, runs: list[RunFolder], args: argparse.Namespace, live_actor: bool = False
) -> tuple[str, GroupSummary]:
    curves = [RunCurve.read(run) for run in runs]
    reports = [
        final_report(
            run,
            args.episodes,
            args.report_seed,
            args.rejudge,
            live_actor,
            args.trust_pickle,
            stored_only=getattr(args, "stored_only", False),
        )
        for run in runs
    ]
    means = [r["mean"] if r else np.nan for r in reports]
    falls = [float(r["falls"]) if r else np.nan for r in reports]
    iqm, low, high = iqm_with_ci(means)
    after = [c.after_reaching(15.0) for c in curves]
    to = {m: [c.reached(m) for c in curves] for m in (5.0, 15.0)}
    reached = {m: f"{sum(h is not None for h in hits)}/{len(hits)}" for m, hits in to.items()}

    def steps_to(m: float) -> list[float]:
        return [h[0] if h else np.nan for h in to[m]]

    def minutes_to(m: float) -> list[float]:
        return [h[1] / 60 if h else np.nan for h in to[m]]

    shown = label
    if live_actor:  # the periodic evaluations played the average, not this actor
        shown += " (evaluation columns: the averaged actor's)"
    if any(r and not run.final_model.is_file() for r, run in zip(reports, runs, strict=True)):
        shown += " (final models judged earlier, not kept)"
    text = " | ".join(
        [
            shown,
            str(len(runs)),
            str(int(max(c.steps[-1] for c in curves)) // 1000) + "k",
            cell(means),
            median(means, digits=2),
            cell(falls, 0),
            NONE if not np.isfinite(iqm) else f"{iqm:.2f} ({low:.2f} to {high:.2f})",
            cell([a[0] if a else np.nan for a in after]),
            cell([a[1] if a else np.nan for a in after]),
            f"{kilo(median(steps_to(5.0), 1e-3, 0))} ({reached[5.0]})",
            f"{kilo(median(steps_to(15.0), 1e-3, 0))} ({reached[15.0]})",
            median(minutes_to(5.0)),
            median(minutes_to(15.0)),
            median([c.steps_per_second for c in curves], digits=0),
            cell([100 * training_fall_share(run, *FALL_WINDOW) for run in runs], 0),
        ]
    )
    return f"| {text} |", GroupSummary(label, curves, [])


HEADER = (
    "| configuration | seeds | steps | final models: mean per seed | median | falls per seed "
    "| IQM (95 % CI) | lowest eval after 15 | largest drop after 15 | steps to 5 "
    "| steps to 15 | min to 5 | min to 15 | env steps/s "
    "| training episodes fallen 50k-150k (%) |\n" + "|---" * 15 + "|"
)


def render(specs: list[tuple[str, list[str]]], args: argparse.Namespace) -> tuple[str, list, list]:
    """The table of these (label, glob) rows: its markdown, the rows' curves, and the
    labels that have no run folders yet (left out of the table)."""
    lines, groups, missing = [HEADER], [], []
    for label, spec in specs:
        live_actor = any(pattern.endswith(LIVE) for pattern in spec)
        patterns = [pattern.removesuffix(LIVE) for pattern in spec]
        runs = run_folders(patterns)
        if not runs:
            missing.append(f"{label} ({' '.join(patterns)})")
            continue
        for run in runs:
            if not run.evaluations.is_file():
                raise UsageError(f"{run} has no evaluations.npz; not a finished run")
        line, group = row(label, runs, args, live_actor)
        lines.append(line)
        groups.append(group)
    return "\n".join(lines), groups, missing


def evaluation_falls(run: RunFolder) -> tuple[np.ndarray, np.ndarray, int]:
    """Each periodic evaluation's steps and falls (episodes that ended before the time
    limit), and the episodes per evaluation."""
    limit = gym.spec(run.read_config()["env"]).max_episode_steps
    with np.load(run.evaluations) as data:
        steps, lengths = data["timesteps"], data["ep_lengths"]
    return steps, (lengths < limit).sum(axis=1), lengths.shape[1]


def evaluations_with_a_fall(run: RunFolder) -> str:
    """How many periodic evaluations had an episode end before the time limit."""
    _, falls, _ = evaluation_falls(run)
    return f"{int((falls > 0).sum())} of {len(falls)}"


def falls_in_each_evaluation(run: RunFolder) -> str:
    """The falls of every periodic evaluation in order: what a run learned to survive
    and when, where the mean return hides it."""
    _, falls, episodes = evaluation_falls(run)
    return " ".join(str(int(f)) for f in falls) + f" of {episodes}"


def most_falls_in_the_second_half(run: RunFolder) -> str:
    """The most falls in one periodic evaluation after half the run's budget: a run that
    degrades at its end shows it there (issue 51's bar: at most 2 in 20)."""
    steps, falls, episodes = evaluation_falls(run)
    late = falls[steps > run.read_config()["n_timesteps"] / 2]
    return f"{int(late.max())} of {episodes}" if len(late) else ""


def stored_final_model(run: RunFolder) -> str:
    """The final model's stored result on the 20 report episodes, mean (falls): what
    ended a run beside how it got there. Plays no episodes (``--check-docs`` runs it)."""
    report = final_report(run, REPORT_EPISODES, REPORT_SEED, rejudge=False, stored_only=True)
    return "" if report is None else f"{report['mean']:.2f} ({report['falls']})"


def curve_cells(
    curves: list[RunCurve], table: dict, runs: list[RunFolder], medians: bool
) -> list[str]:
    """A line's cells after its label and seed: one run's, or the median over runs."""

    def shown(values: list[float]) -> str:
        finite = [v for v in values if np.isfinite(v)]
        if not finite:
            return ""
        return f"{np.median(finite):.2f}" if medians else cell(finite)

    cells = [shown([c.at(step) for c in curves]) for step in table["at"]]
    for column in table.get("columns", []):
        if column == "best":
            best = [c.best for c in curves]
            value = shown([b[0] for b in best])
            cells.append(value if medians else f"{value} @{best[0][1] // 1000}k")
        elif column == "last evaluation":
            cells.append(f"{int(np.median([c.steps[-1] for c in curves])) // 1000}k")
        elif column == "exploring episodes fallen":
            low, high = table["falls_between"]
            share = [100 * training_fall_share(run, low, high) for run in runs]
            finite = [v for v in share if np.isfinite(v)]
            cells.append(f"{np.median(finite):.0f} %" if finite else "")
        elif column == "evaluations with a fall":
            cells.append("" if medians else evaluations_with_a_fall(runs[0]))
        elif column == "falls in each evaluation":
            cells.append("" if medians else falls_in_each_evaluation(runs[0]))
        elif column == "most falls in an evaluation, second half":
            cells.append("" if medians else most_falls_in_the_second_half(runs[0]))
        elif column == "final model":
            cells.append("" if medians else stored_final_model(runs[0]))
        else:
            raise UsageError(f"tables.yml: no column {column!r} in a curves table")
    return cells


def run_folders(patterns: str | list[str | Path]) -> list[RunFolder]:
    """The run folders that globs match."""
    patterns = [patterns] if isinstance(patterns, str) else patterns
    found = [Path(p) for pattern in patterns for p in sorted(glob(str(pattern)))]
    return [RunFolder(p) for p in found if RunFolder.is_run(p)]


def render_curves(table: dict) -> str:
    """A table of periodic evaluations (no episodes played): a row's runs one line each,
    the label on the first and "the same" on the others; a row given as ``{median: GLOB}``
    is one line of medians over its runs."""
    columns = [table.get("label", "configuration"), "seed"]
    columns += [f"@{step // 1000}k" for step in table["at"]] + table.get("columns", [])
    lines = ["| " + " | ".join(columns) + " |", "|---" * len(columns) + "|"]
    for label, spec in table["rows"].items():
        medians = isinstance(spec, dict)
        patterns = spec["median"] if medians else spec
        patterns = [patterns] if isinstance(patterns, str) else patterns
        runs = run_folders([RESULTS / pattern for pattern in patterns])
        if not runs:
            raise UsageError(f"tables.yml: no run folders for the row {label!r} ({spec})")
        seeds = [str(run.read_config()["seed"]) for run in runs]
        curves = [RunCurve.read(run) for run in runs]
        if medians:
            groups = [(label, " ".join(seeds) + " (medians)", curves, runs)]
        else:
            groups = [
                (label if index == 0 else "the same", seed, [curve], [run])
                for index, (seed, curve, run) in enumerate(zip(seeds, curves, runs, strict=True))
            ]
        for shown_label, seed, group_curves, group_runs in groups:
            cells = curve_cells(group_curves, table, group_runs, medians)
            lines.append("| " + " | ".join([shown_label, seed, *cells]) + " |")
    return "\n".join(lines)


def render_robustness(table: dict) -> str:
    """A table of robustness.py's results: a row merges the columns of its sources
    ("FILE#POLICY", FILE a JSON that robustness.py wrote); each cell is the mean ± std
    return over the episodes and the falls in parentheses, "-" where not measured."""
    columns = table["columns"]
    lines = [
        "| " + " | ".join([table.get("label", "policy"), *columns]) + " |",
        "|---" * (len(columns) + 1) + "|",
    ]
    for label, sources in table["rows"].items():
        cells: dict[str, dict] = {}
        for source in [sources] if isinstance(sources, str) else sources:
            name, _, policy = source.partition("#")
            results = json.loads((RESULTS / name).read_text())
            if policy not in results:
                raise UsageError(f"tables.yml: {name} has no policy {policy!r}")
            cells.update(results[policy])
        shown = [
            f"{c['mean']:.2f} ± {c['std']:.2f} ({c['falls']})" if (c := cells.get(column)) else NONE
            for column in columns
        ]
        lines.append("| " + " | ".join([label, *shown]) + " |")
    return "\n".join(lines)


def render_table(name: str, args: argparse.Namespace) -> str:
    """Table ``name`` of tables.yml, by its kind."""
    table = TABLES[name]
    kind = table.get("kind", "final models")
    if kind == "curves":
        return render_curves(table)
    if kind == "robustness":
        return render_robustness(table)
    return render(table_specs(name), args)[0]


def table_specs(name: str) -> list[tuple[str, list[str]]]:
    """Each row's label and globs (a row is a glob or a list of globs, each run a line's seed
    in the order given)."""
    return [
        (label, [str(RESULTS / p) for p in ([spec] if isinstance(spec, str) else spec)])
        for label, spec in TABLES[name]["rows"].items()
    ]


def figure_groups(groups: list[GroupSummary], args: argparse.Namespace) -> list[GroupSummary]:
    """The rows figure 1 draws: the table's ``figure`` list, in its order, or every row
    (always every row of ``--row``)."""
    wanted = TABLES[args.table].get("figure")
    if args.row or not wanted:
        return groups
    by_name = {group.name: group for group in groups}
    unknown = [label for label in wanted if label not in by_name]
    if unknown:
        raise UsageError(f"tables.yml: figure of {args.table!r} names no row {unknown[0]!r}")
    return [by_name[label] for label in wanted]


def marked(name: str) -> tuple[str, str]:
    return f"<!-- table: {name} -->", "<!-- /table -->"


def docs_tables(args: argparse.Namespace, root: Path, write: bool) -> list[str]:
    """Each table of tables.yml against its page under ``root``: rewritten there when
    ``write``, else the tables whose page differs. Every table is rendered before any page
    is written, so a refusal leaves every page as it was."""
    differing = []
    pages: dict[Path, str] = {}
    for name, table in TABLES.items():
        page = root / table["page"]
        text = pages.setdefault(page, page.read_text())
        begin, end = marked(name)
        if text.count(begin) != 1 or text.count(end) < 1:
            raise UsageError(f"{table['page']} has no {begin} ... {end} for table {name!r}")
        head, rest = text.split(begin)
        old, tail = rest.split(end, 1)
        if "<!-- table: " in old:  # its end is missing: the next table's would be taken
            raise UsageError(f"{table['page']}: {begin} has no {end} before the next table")
        new = "\n" + render_table(name, args) + "\n"
        if new != old:
            differing.append(f"{name} ({table['page']})")
            pages[page] = head + begin + new + end + tail
    if write:
        for page, text in pages.items():
            if text != page.read_text():
                with atomic_path(page) as temp:
                    temp.write_text(text)
    return differing


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(description=__doc__.splitlines()[0])
    parser.add_argument("--table", choices=list(TABLES), default="benchmark")
    parser.add_argument(
        "--row",
        action="append",
        metavar="LABEL=GLOB",
        help="a row from these run folders instead of the table's own (repeatable); a GLOB "
        f"ending in {LIVE} judges the final models' live actor of an actor_ema run",
    )
    parser.add_argument("--episodes", type=int, default=REPORT_EPISODES)
    parser.add_argument("--report-seed", type=int, default=REPORT_SEED)
    parser.add_argument("--rejudge", action="store_true", help="play the final models again")
    parser.add_argument(
        "--trust-pickle",
        action="store_true",
        help="load pickles (statistics without their JSON): run folders you trust only",
    )
    parser.add_argument("--plot", type=Path, help="write the IQM curves (figure 1) to this PNG")
    docs = parser.add_mutually_exclusive_group()
    docs.add_argument(
        "--write-docs", action="store_true", help="print every table of tables.yml into its page"
    )
    docs.add_argument(
        "--check-docs",
        action="store_true",
        help="exit 1 if a page's table differs from its runs' (plays no episodes)",
    )
    args = parser.parse_args(argv)
    if args.write_docs or args.check_docs:
        args.stored_only = args.check_docs
        differing = docs_tables(args, TABLES_FILE.parents[1], write=args.write_docs)
        if args.check_docs and differing:
            sys.exit(
                f"minitaur_table.py: error: tables that differ from their runs: "
                f"{', '.join(differing)}; run minitaur_table.py --write-docs"
            )
        done = "rewrote " + ", ".join(differing) if differing else "every table matches its runs"
        print(done)
        return
    if TABLES[args.table].get("kind") in ("curves", "robustness") and not args.row:
        print(render_table(args.table, args))  # plays no episodes
        return
    specs: list[tuple[str, list[str]]] = []
    for text in args.row or []:
        label, sep, pattern = text.partition("=")
        if not sep or not label or not pattern:
            parser.error(f"--row expects LABEL=GLOB, got {text!r}")
        specs.append((label, [pattern]))
    table, groups, missing = render(specs or table_specs(args.table), args)
    print(table)
    if missing:
        print(f"\nno run folders yet for: {'; '.join(missing)}", file=sys.stderr)
    print(
        f"\nfinal models: {args.episodes} deterministic episodes from seed {args.report_seed}; "
        "'-': no final model kept, or the milestone never reached"
    )
    if args.plot and groups:
        plot_iqm_curves(figure_groups(groups, args), args.plot, 15.0, by_minutes=True)


if __name__ == "__main__":
    # A UsageError, e.g. a pickle that needs --trust-pickle, is one line.
    sys.exit(refuse_in_one_line("minitaur_table.py", main))
