"""Learning statistics over run folders: per-run curves, milestones, IQM with bootstrap CIs.

Each run's own ``evaluations.npz`` (deterministic evaluations, raw return) and monitor
logs (wall-clock) are the source; nothing here depends on how the runs were launched
(train.py, the sweep, a notebook). The interquartile mean and its 95 % stratified
bootstrap confidence interval come from ``rliable`` (Agarwal et al. 2021), installed with
the ``ray`` extra.
"""

from __future__ import annotations

import csv
import dataclasses
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from minitaur_env.training.run_folder import RunFolder

# The unlogged end of a run is timed at its rate over about this many last logged steps:
# recent enough to be the final session's machine load, long enough to span evaluations.
RATE_WINDOW_STEPS = 10_000


@dataclasses.dataclass
class RunCurve:
    """One run's evaluations: env steps, mean eval return, wall-clock seconds."""

    run: RunFolder
    steps: np.ndarray
    returns: np.ndarray
    seconds: np.ndarray

    @classmethod
    def read(cls, run: RunFolder | str | Path) -> RunCurve:
        run = run if isinstance(run, RunFolder) else RunFolder(run)
        with np.load(run.evaluations) as data:
            steps, returns = data["timesteps"].astype(int), data["results"].mean(axis=1)
        return cls(run, steps, returns, wall_clock_at(run, steps))

    @property
    def final(self) -> float:
        return float(self.returns[-1]) if len(self.returns) else np.nan

    @property
    def best(self) -> tuple[float, int]:
        if not len(self.returns):
            return np.nan, 0
        index = int(np.argmax(self.returns))
        return float(self.returns[index]), int(self.steps[index])

    def at(self, step: int) -> float:
        """The last evaluation at or before ``step``; NaN if the run stopped before it."""
        earlier = np.nonzero(self.steps <= step)[0]
        if not len(earlier) or self.steps[-1] < step:
            return np.nan
        return float(self.returns[earlier[-1]])

    def reached(self, milestone: float) -> tuple[int, float] | None:
        """(env steps, seconds) of the first evaluation at or above ``milestone``."""
        hit = np.nonzero(self.returns >= milestone)[0]
        if not len(hit):
            return None
        return int(self.steps[hit[0]]), float(self.seconds[hit[0]])

    def after_reaching(self, milestone: float) -> tuple[float, float] | None:
        """(lowest evaluation, largest drop below an earlier peak) from the first evaluation
        at or above ``milestone`` on: how far a run falls back once it got there."""
        hit = np.nonzero(self.returns >= milestone)[0]
        if not len(hit):
            return None
        later = self.returns[hit[0] :]
        return float(later.min()), float((np.maximum.accumulate(later) - later).max())

    @property
    def steps_per_second(self) -> float:
        """Env steps per second of training wall-clock, evaluations included, up to the
        last evaluation that the monitor logs' clock covers."""
        timed = np.nonzero(np.isfinite(self.seconds) & (self.seconds > 0))[0]
        if not len(timed):
            return np.nan
        return float(self.steps[timed[-1]] / self.seconds[timed[-1]])


def wall_clock_at(run: RunFolder, steps: np.ndarray) -> np.ndarray:
    """Seconds of training when the run had made ``steps`` env steps (monitor logs).

    The monitors record every finished episode's end time; env steps between episode
    ends are interpolated. Each resumed session's monitor clock restarts from 0, so a
    session is counted from where the previous one's last logged episode ended: time
    spent stopped between sessions is not counted.

    Episodes cut by the end of a session are never logged, so the logs end up to one
    episode per env and session short of the steps trained: the final model's steps lie
    past the last logged episode. Steps within that shortfall are timed at the rate of
    the last logged steps; steps beyond it (a run that stopped earlier) are NaN.
    """
    episodes = run.monitor_episodes()
    if not episodes:
        return np.full(len(steps), np.nan)
    events = sorted((episode.training_time, episode.length) for episode in episodes)
    times = np.array([t for t, _ in events])
    done = np.cumsum([n for _, n in events])
    seconds = np.interp(steps, done, times, right=np.nan)
    sessions = 1 + max(episode.session for episode in episodes)
    envs = len({episode.monitor for episode in episodes})
    unlogged = sessions * envs * max(n for _, n in events)
    tail = (steps > done[-1]) & (steps <= done[-1] + unlogged)
    if tail.any() and len(done) > 1:
        since = max(0, int(np.searchsorted(done, done[-1] - RATE_WINDOW_STEPS)) - 1)
        rate = (times[-1] - times[since]) / (done[-1] - done[since])  # seconds per step
        seconds[tail] = times[-1] + (steps[tail] - done[-1]) * rate
    return seconds


def default_milestones(env_id: str) -> tuple[float, ...]:
    """5 and the reward threshold for the Minitaur ids; the env's threshold for others."""
    import gymnasium as gym

    spec = gym.spec(env_id)
    threshold = spec.reward_threshold
    if str(spec.entry_point).startswith("minitaur_env"):
        return tuple(sorted({5.0, float(threshold)}))
    return () if threshold is None else (float(threshold),)


def iqm_with_ci(
    values: Sequence[float], reps: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """(IQM, 95 % CI low, high) over runs, by rliable's stratified bootstrap."""
    from rliable import library as rly
    from rliable import metrics

    scores = np.asarray([v for v in values if np.isfinite(v)], dtype=float)
    if not len(scores):
        return np.nan, np.nan, np.nan
    if len(scores) == 1:
        return float(scores[0]), float(scores[0]), float(scores[0])
    # rliable (1.2) resamples with the global np.random and ignores its random_state, so
    # the same scores gave different intervals from one call to the next: seed the global
    # generator for the call and give the caller its state back.
    caller_state = np.random.get_state()
    np.random.seed(seed)
    try:
        with warnings.catch_warnings():
            # arch, under rliable, deprecates the RandomState that rliable hands it.
            warnings.simplefilter("ignore", FutureWarning)
            estimates, intervals = rly.get_interval_estimates(
                {"runs": scores.reshape(-1, 1)},
                lambda x: np.array([metrics.aggregate_iqm(x)]),
                reps=reps,
                random_state=np.random.RandomState(seed),
            )
    finally:
        np.random.set_state(caller_state)
    return (
        float(estimates["runs"][0]),
        float(intervals["runs"][0, 0]),
        float(intervals["runs"][1, 0]),
    )


@dataclasses.dataclass
class GroupSummary:
    """One configuration over its seeds."""

    name: str
    curves: list[RunCurve]
    failed: list[str]
    milestones: Sequence[float] = (5.0, 15.0)
    unfinished: int = 0

    def iqm_curve(self) -> tuple[np.ndarray, np.ndarray]:
        """(steps, [IQM, CI low, CI high] per step) on every step any run evaluated at."""
        grid = np.unique(np.concatenate([c.steps for c in self.curves]))
        stats = np.array([iqm_with_ci([c.at(int(s)) for c in self.curves], reps=500) for s in grid])
        return grid, stats

    def median_minutes(self, steps: np.ndarray) -> np.ndarray:
        """The runs' median wall-clock minutes at ``steps`` (NaN past every run's end)."""
        with warnings.catch_warnings():  # steps after every run's last logged episode
            warnings.simplefilter("ignore", RuntimeWarning)
            seconds = [np.interp(steps, c.steps, c.seconds) for c in self.curves]
            return np.nanmedian(seconds, axis=0) / 60

    def row(self) -> dict[str, object]:
        finals = [c.final for c in self.curves]
        bests = [c.best[0] for c in self.curves]
        iqm, low, high = iqm_with_ci(finals)
        row: dict[str, object] = {
            "config": self.name,
            "seeds_done": len(self.curves),
            "seeds_failed": len(self.failed),
            "seeds_unfinished": self.unfinished,
            "steps": int(min((c.steps[-1] for c in self.curves if len(c.steps)), default=0)),
            "final_per_seed": " ".join(f"{v:.2f}" for v in finals),
            "best_per_seed": " ".join(f"{v:.2f}" for v in bests),
            "median": float(np.median(finals)) if finals else np.nan,
            "iqm": iqm,
            "iqm_low": low,
            "iqm_high": high,
        }
        for milestone in self.milestones:
            hits = [c.reached(milestone) for c in self.curves]
            got = [h for h in hits if h is not None]
            label = f"{milestone:g}"
            row[f"reached_{label}"] = f"{len(got)}/{len(hits)}"
            row[f"steps_to_{label}_per_seed"] = " ".join(
                "-" if h is None else str(h[0]) for h in hits
            )
            row[f"median_steps_to_{label}"] = (
                float(np.median([h[0] for h in got])) if got else np.nan
            )
            row[f"median_minutes_to_{label}"] = (
                float(np.median([h[1] for h in got])) / 60 if got else np.nan
            )
        return row


def write_csv(rows: list[dict[str, object]], path: Path) -> None:
    from minitaur_env.training.files import atomic_path

    with atomic_path(path) as temp, temp.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def format_rows(rows: list[dict[str, object]]) -> str:
    """A fixed-width text table of the summary rows, for the terminal."""
    columns = list(rows[0])
    texts = [[_cell(row[c]) for c in columns] for row in rows]
    widths = [max(len(c), *(len(t[i]) for t in texts)) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True))]
    lines += ["  ".join(t.ljust(w) for t, w in zip(text, widths, strict=True)) for text in texts]
    return "\n".join(lines)


def _cell(value: object) -> str:
    if isinstance(value, float):
        return "-" if not np.isfinite(value) else f"{value:.2f}"
    return str(value)


def plot_iqm_curves(
    groups: list[GroupSummary], path: Path, threshold: float | None, by_minutes: bool = False
) -> None:
    """IQM of the eval return over seeds against env steps, with its 95 % CI band; with
    ``by_minutes`` a second panel against the median run's wall-clock minutes. The legend
    sits under the panels, so that no label hides a curve however many groups there are."""
    from minitaur_env.training.plotting import figure, save_figure

    drawn = [group for group in groups if group.curves]
    legend_rows = -(-(len(drawn) + (threshold is not None)) // 2)
    legend_height = 0.2 * legend_rows + 0.2  # inches: one 8-point line each, and a margin
    height = 4.5 + legend_height
    if by_minutes:
        fig, (by_steps, by_time) = figure(2, figsize=(12, height))
        panels = [(by_steps, "env steps"), (by_time, "wall-clock (min), median run")]
    else:
        fig, by_steps = figure(figsize=(8, height))
        panels = [(by_steps, "env steps")]
    for group in drawn:
        grid, stats = group.iqm_curve()
        label = f"{group.name} ({len(group.curves)} seeds)"
        for ax, xlabel in panels:
            x = grid if xlabel == "env steps" else group.median_minutes(grid)
            line = ax.plot(x, stats[:, 0], label=label)
            ax.fill_between(x, stats[:, 1], stats[:, 2], alpha=0.2, color=line[0].get_color())
    for ax, xlabel in panels:
        if threshold is not None:
            ax.axhline(threshold, color="grey", linestyle="--", label="reward threshold")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("eval return, IQM over seeds (95% CI)")
        ax.grid(alpha=0.3)
    handles, labels = by_steps.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8, frameon=False)
    save_figure(fig, path, bottom=legend_height / height if handles else 0.0)
