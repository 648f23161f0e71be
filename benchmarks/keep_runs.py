"""Copy finished runs into ``benchmarks/results/<name>/seed<S>/``, small enough to commit.

Keeps what anyone needs to judge a run again and to redraw its curves: the final model in
the zoo's layout (``<env>.zip``, ``<env>/vecnormalize.pkl`` and the zoo's settings), the
run's ``config.yml``, ``command.txt``, ``evaluations.npz``, monitor files and, for a sweep
trial, ``trial.yml``, and ``minitaur_table.py``'s judgement of the final model
(``final_model_report*.json``) where the run was judged in place. Checkpoints, replay
buffers and the best model stay behind. ``--curves-only`` keeps a run without its model: a
run stopped before its end (a screen; what a "curves" table of ``tables.yml`` reads), or
one whose model is too large to commit (an SBX model, 9.5 MB), judged first with
``minitaur_table.py --row LABEL=RUN_FOLDER`` so that its figures stay in the tables.
``--resumable`` keeps a stopped run with its newest checkpoint (model, statistics, replay
buffer) and its best model, so that a run longer than a session goes on from a clone:
copy the kept folder out and ``python train.py --resume COPY``.

    python benchmarks/keep_runs.py logs/sweeps/NAME/runs/* --into benchmarks/results/NAME
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from minitaur_env.training.files import replaced_folder
from minitaur_env.training.run_folder import RunFolder, normalizer_json
from minitaur_env.training.trial import TRIAL_FILE


def run_folders(path: Path) -> list[RunFolder]:
    """The run folder at ``path``, or those of a sweep trial folder (``<algo>/<env>_N``)."""
    if RunFolder.is_run(path):
        return [RunFolder(path)]
    return RunFolder.found_under(path)


def resume_files(run: RunFolder) -> list[Path]:
    """The newest checkpoint's files (model, statistics and their JSON, replay buffer) and
    the best model's: what ``--resume`` reads, and what it compares new evaluations with."""
    checkpoints = run.checkpoints()
    if not checkpoints:
        sys.exit(f"keep_runs.py: {run} has no checkpoint to resume from")
    steps, model = checkpoints[0]
    statistics = run.vecnormalize(steps)
    best = [run.best_model, run.vecnormalize_beside(run.best_model)]
    candidates = [model, statistics, normalizer_json(statistics), run.replay_buffer(steps), *best]
    candidates.append(normalizer_json(best[1]))
    return [path for path in candidates if path.is_file()]


def keep(
    run: RunFolder, destination: Path, curves_only: bool = False, resumable: bool = False
) -> None:
    curves_only = curves_only or resumable
    resumed_from = resume_files(run) if resumable else []  # refused before anything is copied
    if not curves_only and not run.zoo_model.is_file():
        sys.exit(
            f"keep_runs.py: {run} has no final model {run.zoo_model.name}; unfinished? "
            "(--curves-only keeps a stopped run's evaluations)"
        )
    if not run.evaluations.is_file():
        sys.exit(f"keep_runs.py: {run} has no {run.evaluations.name}: nothing to keep")
    # Written aside and swapped in whole: a copy that fails part-way leaves the folder kept
    # before as it was, and a kept run can be kept again into its own folder (a resumed
    # run finishing where its resumable checkpoint was kept) without deleting its source.
    with replaced_folder(destination) as staged:
        files = [run.config, run.command, run.evaluations]
        files += [
            report for live in (False, True) if (report := run.final_model_report(live)).is_file()
        ]
        for source in files if curves_only else [*files, run.zoo_model]:
            shutil.copy2(source, staged / source.name)
        kept = RunFolder(staged)  # its env name comes from the copied config.yml
        if not curves_only:
            shutil.copytree(run.zoo_dir, kept.zoo_dir)
        shutil.copytree(run.monitor_dir, kept.monitor_dir)
        # A sweep run's record lies in <trial>/<algo>/<env>_N's trial folder; a kept run
        # that was resumed from a copy carries it inside.
        for trial in (run.path.parents[1] / TRIAL_FILE, run.path / TRIAL_FILE):
            if trial.is_file():
                shutil.copy2(trial, kept.path / trial.name)
                break
        for source in resumed_from:
            target = kept.path / source.relative_to(run.path)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders or sweep trial folders")
    parser.add_argument("--into", type=Path, required=True, help="e.g. benchmarks/results/NAME")
    parser.add_argument(
        "--curves-only",
        action="store_true",
        help="keep runs stopped before their end: evaluations and monitors, no model",
    )
    parser.add_argument(
        "--resumable",
        action="store_true",
        help="keep a stopped run with its newest checkpoint and best model, to go on with "
        "train.py --resume from a copy of the kept folder",
    )
    args = parser.parse_args(argv)
    found = [run for path in args.runs for run in run_folders(path)]
    if not found:
        sys.exit(f"keep_runs.py: no run folder (config.yml) under {' '.join(map(str, args.runs))}")
    seeds = [int(run.read_config()["seed"]) for run in found]
    if len(set(seeds)) != len(seeds):
        sys.exit(f"keep_runs.py: two runs share a seed ({sorted(seeds)}); keep them apart")
    for run, seed in zip(found, seeds, strict=True):
        keep(run, args.into / f"seed{seed}", args.curves_only, args.resumable)
        print(f"{run} -> {args.into / f'seed{seed}'}")


if __name__ == "__main__":
    main()
