"""A finished run's copy whose final model averages the end of its training, as a run with
``average_weights`` in its entry would have ended.

``average_weights`` changes nothing during training (it only keeps the policy's weights
at the steps it averages), so a run without it that kept checkpoints at those steps holds
everything the key's run holds: this copies the run folder into ``--into``, writes the
weights of its checkpoints at the key's steps where the key's run keeps them, makes the
final model their mean with the final weights (the same ``WeightAverage.average_into``
that ends a run with the key) and adds the key to the copy's ``config.yml``. The run
itself is left as it was.

    python benchmarks/average_run.py RUN --start 0.75 --every 50000 --into logs/averaged/NAME
"""

from __future__ import annotations

import shlex
import shutil
import sys
from pathlib import Path

import numpy as np

from minitaur_env.training import OneLineErrorParser, UsageError
from minitaur_env.training.algorithms import algorithm_class
from minitaur_env.training.callbacks import WeightAverage, keep_policy_weights
from minitaur_env.training.files import atomic_path, replaced_folder
from minitaur_env.training.hyperparams import AVERAGE_WEIGHTS_KEY, average_weights
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.safe_load import embed_statistics, embedded_statistics, load_sb3_model


def _same_weights(first, second) -> bool:
    ours, theirs = first.policy.state_dict(), second.policy.state_dict()
    return ours.keys() == theirs.keys() and all(
        np.array_equal(ours[name].cpu().numpy(), theirs[name].cpu().numpy()) for name in ours
    )


def average_run(run: RunFolder, start: float, every: int, into: Path, command: str) -> RunFolder:
    """The copy of ``run`` in ``into``, its final model averaged from ``start`` (a fraction
    of the run's steps) at every ``every`` steps."""
    config = run.read_config()
    hyperparams = dict(config.get("hyperparams") or {})
    if AVERAGE_WEIGHTS_KEY in hyperparams:
        raise UsageError(f"{run}: its final model is averaged already ({AVERAGE_WEIGHTS_KEY})")
    if config.get("backend", "sb3") != "sb3":
        raise UsageError(f"{run}: {AVERAGE_WEIGHTS_KEY} averages PyTorch policies only")
    if not run.final_model.is_file():
        raise UsageError(f"{run} has no final model ({run.final_model.name}): is it finished?")
    if into.exists():
        raise UsageError(f"--into {into} already exists; name a new folder")
    hyperparams[AVERAGE_WEIGHTS_KEY] = {"start": start, "every": every}
    steps = average_weights(hyperparams, int(config["n_timesteps"]))
    missing = [step for step in steps if not run.checkpoint(step).is_file()]
    if missing:
        raise UsageError(f"{run} kept no checkpoint at steps {missing}; nothing to average there")
    algorithm = algorithm_class(config["algo"], "sb3")
    final = load_sb3_model(algorithm, run.final_model, device="cpu")
    newest = load_sb3_model(algorithm, run.checkpoints()[0][1], device="cpu")
    if not _same_weights(final, newest):
        # The run's final weights must stay somewhere once its copy's model is averaged.
        raise UsageError(f"{run}: its final model's weights are in no checkpoint")
    with replaced_folder(into) as staged:
        shutil.copytree(
            run.path,
            staged,
            dirs_exist_ok=True,
            ignore=shutil.ignore_patterns(run.lock_file.name, run.staging_dir.name),
        )
        copy = RunFolder(staged)
        for step in steps:
            checkpoint = load_sb3_model(algorithm, run.checkpoint(step), device="cpu")
            keep_policy_weights(checkpoint.policy, copy.policy_weights(step))
        WeightAverage(copy, steps).average_into(final)
        statistics = embedded_statistics(run.final_model)
        with atomic_path(copy.final_model) as temp:
            final.save(temp)
            if statistics is not None:
                embed_statistics(temp, statistics)
        copy.write_config({**config, "hyperparams": hyperparams})
        copy.append_command(command)
    return RunFolder(into)


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished run folder with checkpoints")
    parser.add_argument("--start", type=float, required=True, help="a fraction of the run")
    parser.add_argument("--every", type=int, required=True, help="env steps between weights")
    parser.add_argument("--into", type=Path, required=True, help="the new run folder")
    args = parser.parse_args(argv)
    try:
        if not RunFolder.is_run(args.run):
            raise UsageError(f"{args.run} is not a run folder (no config.yml)")
        given = sys.argv[1:] if argv is None else argv
        command = shlex.join(["python", "benchmarks/average_run.py", *given])
        copy = average_run(RunFolder(args.run), args.start, args.every, args.into, command)
    except UsageError as error:
        parser.error(str(error))
    print(f"{copy.final_model}: the policy averaged every {args.every} steps from {args.start}")


if __name__ == "__main__":
    main()
