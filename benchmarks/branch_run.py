"""Branch a run at one of its checkpoints, with some hyperparameters changed: a paired screen.

Runs of one seed and one setting are identical until something differs, and a resumed run
goes another way from its resume on; so a change to the second half of training, compared
with another run of the same seed, is confounded with a different state at the point where
it starts. A branch continues the very state the other arm continues: this copies the run
folder as it was at checkpoint ``--at`` (later checkpoints, a best model saved later and the
finished run's final model and reports left out), sets the changed keys in its
``config.yml`` (``key=null`` removes a key, so the algorithm's default applies), and notes
the branch in its ``command.txt``. ``python train.py --resume NEW`` then trains it to the
run's budget; its logs are rewound to the checkpoint as any resume's are.

    python benchmarks/branch_run.py RUN --at 150000 --into logs/branch/NAME \\
        --hyperparams target_entropy_decay=null
"""

from __future__ import annotations

import shlex
import shutil
import sys
from pathlib import Path

from minitaur_env.training import OneLineErrorParser, UsageError
from minitaur_env.training.files import replaced_folder
from minitaur_env.training.hyperparams import RUN_KEYS, parse_overrides
from minitaur_env.training.run_folder import RunFolder, normalizer_json
from minitaur_env.training.safe_load import embedded_evaluation


def later_files(run: RunFolder, at: int) -> list[Path]:
    """What the run saved after env step ``at``: checkpoints, their statistics and replay
    buffers, and a best model from a later evaluation."""
    numbered = run.checkpoints() + run.replay_buffers()
    later = [path for steps, path in numbered if steps > at]
    for steps, _ in run.checkpoints():
        if steps > at and (statistics := run.vecnormalize(steps)).is_file():
            later += [statistics, normalizer_json(statistics)]
    recorded = embedded_evaluation(run.best_model) if run.best_model.is_file() else None
    if recorded is not None and recorded[0] > at:
        statistics = run.vecnormalize_beside(run.best_model)
        later += [run.best_model, statistics, normalizer_json(statistics)]
    return [path for path in later if path.is_file()]


def branch(run: RunFolder, at: int, into: Path, changes: dict, command: str) -> RunFolder:
    """A copy of ``run`` as it was at checkpoint ``at``, with ``changes`` to its
    hyperparameters (a value None removes the key); ``command`` made it. The copy is
    written aside and appears whole or not at all."""
    if not run.checkpoint(at).is_file():
        kept = ", ".join(str(steps) for steps, _ in sorted(run.checkpoints())) or "none"
        raise UsageError(f"{run} has no checkpoint at {at} steps (kept: {kept})")
    config = run.read_config()
    if config["algo"] in ("sac", "tqc", "crossq") and not run.replay_buffer(at).is_file():
        raise UsageError(f"{run} kept no replay buffer at {at} steps: a branch there cannot resume")
    fixed = sorted(set(changes) & set(RUN_KEYS))
    if fixed:
        kept = ", ".join(RUN_KEYS)
        raise UsageError(f"--hyperparams {fixed[0]}: a branch keeps the run's {kept}")
    if into.exists():
        raise UsageError(f"--into {into} already exists; name a new folder")
    finished = [run.zoo_model, run.learning_curve, run.provenance, run.failure_log]
    finished += list(run.path.glob("final_model_report*.json"))
    skipped = {path.resolve() for path in later_files(run, at) + finished}
    with replaced_folder(into) as staged:
        shutil.copytree(
            run.path,
            staged,
            dirs_exist_ok=True,
            ignore=lambda folder, names: [
                name
                for name in names
                if name in (run.lock_file.name, run.staging_dir.name)
                or (Path(folder) / name).resolve() in skipped
            ],
        )
        hyperparams = dict(config.get("hyperparams") or {})
        for key, value in changes.items():
            if value is None:
                hyperparams.pop(key, None)
            else:
                hyperparams[key] = value
        staged_run = RunFolder(staged)
        staged_run.write_config({**config, "hyperparams": hyperparams})
        staged_run.append_command(f"# branched at {at} steps from {run}: {command}")
    return RunFolder(into)


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a run folder with checkpoints")
    parser.add_argument("--at", type=int, required=True, help="the checkpoint's env steps")
    parser.add_argument("--into", type=Path, required=True, help="the new run folder")
    parser.add_argument("--hyperparams", nargs="+", metavar="KEY=VALUE", default=[])
    args = parser.parse_args(argv)
    try:
        if not RunFolder.is_run(args.run):
            raise UsageError(f"{args.run} is not a run folder (no config.yml)")
        changes = parse_overrides(args.hyperparams, "--hyperparams")
        given = sys.argv[1:] if argv is None else argv
        command = shlex.join(["python", "benchmarks/branch_run.py", *given])
        branched = branch(RunFolder(args.run), args.at, args.into, changes, command)
    except UsageError as error:
        parser.error(str(error))
    print(f"branched {args.run} at {args.at} steps into {branched}; continue it with:")
    print(f"python train.py --resume {branched}")


if __name__ == "__main__":
    main()
