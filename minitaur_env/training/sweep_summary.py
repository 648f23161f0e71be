"""A sweep's outcome: one row and one IQM curve per configuration, from its trial folders."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from minitaur_env.training import UsageError
from minitaur_env.training.files import read_yaml
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.trial import RUNS, TRIAL_FILE


def summarize(
    folder: str | Path | Sequence[str | Path], milestones: Sequence[float] | None = None
) -> list[dict]:
    """One row per configuration of a sweep folder; writes summary.csv and curves.png.

    Several folders (say, more seeds of one configuration run as a later sweep) make one
    table, written into the first; a configuration's runs must then train the same
    config but for the seed. ``milestones``: the returns whose first crossing the rows
    report (steps, minutes); by default those of :func:`default_milestones` for the
    sweep's env.
    """
    import gymnasium as gym

    from minitaur_env.training.aggregate import (
        GroupSummary,
        RunCurve,
        default_milestones,
        plot_iqm_curves,
        write_csv,
    )

    folders = [Path(folder)] if isinstance(folder, (str, Path)) else [Path(f) for f in folder]
    trials = []
    for each in folders:
        found = sorted((each / RUNS).glob(f"*/{TRIAL_FILE}"))
        if not found:
            raise UsageError(f"{each} holds no sweep trials ({RUNS}/*/{TRIAL_FILE})")
        trials += found
    # The trial's run is the one it trains or resumes: the highest-numbered.
    run_of = {path: _newest_run(path.parent) for path in trials}
    env_id = next((run.read_config()["env"] for run in run_of.values() if run is not None), None)
    if env_id is not None:
        import minitaur_env  # noqa: F401  (the Minitaur ids' specs)
    if milestones is None:
        milestones = default_milestones(env_id) if env_id is not None else ()
    groups: dict[str, GroupSummary] = {}
    trained: dict[str, tuple[dict, RunFolder]] = {}  # group: a run's config but its seed
    for trial_file, run in run_of.items():
        trial = read_yaml(trial_file)
        if run is not None:
            config = {k: v for k, v in run.read_config().items() if k != "seed"}
            first = trained.setdefault(trial["group"], (config, run))
            if config != first[0]:
                differ = sorted(
                    k for k in config.keys() | first[0].keys() if config.get(k) != first[0].get(k)
                )
                raise UsageError(
                    f"{first[1].path} and {run.path} are both {trial['group']!r} but train "
                    f"different configs ({', '.join(differ)}): summarize them apart"
                )
        group = groups.setdefault(
            trial["group"], GroupSummary(trial["group"], [], [], tuple(milestones))
        )
        if trial["status"] == "completed" and run is not None:
            group.curves.append(RunCurve.read(run.path))
        elif trial["status"] == "failed":
            group.failed.append(trial.get("error", ""))
        else:  # interrupted: --resume finishes it
            group.unfinished += 1
    rows = [group.row() for group in groups.values()]
    write_csv(rows, folders[0] / "summary.csv")
    threshold = gym.spec(env_id).reward_threshold if env_id is not None else None
    plot_iqm_curves(list(groups.values()), folders[0] / "curves.png", threshold)
    return rows


def _newest_run(trial_folder: Path) -> RunFolder | None:
    runs = RunFolder.found_under(trial_folder)
    return max(runs, key=lambda run: (run.number, str(run.path)), default=None)
