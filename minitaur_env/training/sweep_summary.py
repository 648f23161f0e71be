"""A sweep's outcome: one row and one IQM curve per configuration, from its trial folders."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from minitaur_env.training import UsageError
from minitaur_env.training.files import read_yaml
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.trial import RUNS, TRIAL_FILE


def summarize(folder: str | Path, milestones: Sequence[float] | None = None) -> list[dict]:
    """One row per configuration of a sweep folder; writes summary.csv and curves.png.

    ``milestones``: the returns whose first crossing the rows report (steps, minutes);
    by default those of :func:`default_milestones` for the sweep's env.
    """
    import gymnasium as gym

    from minitaur_env.training.aggregate import (
        GroupSummary,
        RunCurve,
        default_milestones,
        plot_iqm_curves,
        write_csv,
    )

    folder = Path(folder)
    trials = sorted((folder / RUNS).glob(f"*/{TRIAL_FILE}"))
    if not trials:
        raise UsageError(f"{folder} holds no sweep trials ({RUNS}/*/{TRIAL_FILE})")
    # The trial's run is the one it trains or resumes: the highest-numbered.
    run_of = {path: _newest_run(path.parent) for path in trials}
    env_id = next((run.read_config()["env"] for run in run_of.values() if run is not None), None)
    if env_id is not None:
        import minitaur_env  # noqa: F401  (the Minitaur ids' specs)
    if milestones is None:
        milestones = default_milestones(env_id) if env_id is not None else ()
    groups: dict[str, GroupSummary] = {}
    for trial_file, run in run_of.items():
        trial = read_yaml(trial_file)
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
    write_csv(rows, folder / "summary.csv")
    threshold = gym.spec(env_id).reward_threshold if env_id is not None else None
    plot_iqm_curves(list(groups.values()), folder / "curves.png", threshold)
    return rows


def _newest_run(trial_folder: Path) -> RunFolder | None:
    runs = RunFolder.found_under(trial_folder)
    return max(runs, key=lambda run: (run.number, str(run.path)), default=None)
