"""What a run shows while it trains: a progress bar on a terminal, one line per evaluation
elsewhere (CI, ``nohup``, a sweep's trial logs), so that either way a user sees steps/s,
the time left and the latest evaluation without SB3's logger tables (``-v 1``)."""

from __future__ import annotations

import sys
import time
from typing import IO

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

from minitaur_env.training import PROGRESS_MODES


def resolve_progress(mode: str, stream: IO[str] | None = None) -> str:
    """``auto`` becomes ``bar`` on an interactive terminal and ``lines`` otherwise."""
    if mode not in PROGRESS_MODES:
        raise ValueError(f"progress must be one of {', '.join(PROGRESS_MODES)}, not {mode!r}")
    if mode != "auto":
        return mode
    stream = stream or sys.stderr
    return "bar" if stream.isatty() else "lines"


def format_duration(seconds: float) -> str:
    hours, rest = divmod(round(seconds), 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"


class TrainingProgress(BaseCallback):
    """Progress of one ``learn`` call, with the evaluation results of ``evaluation``.

    Runs after the EvalCallback in the same CallbackList, so that an evaluation that
    ends on a step is reported on that step. Without evaluations, ``lines`` mode prints
    a line at every tenth of the run instead.
    """

    def __init__(
        self,
        mode: str,
        total_steps: int,
        label: str,
        evaluation: EvalCallback | None = None,
        stream: IO[str] | None = None,
    ) -> None:
        super().__init__()
        self.mode = resolve_progress(mode, stream)
        self.total_steps = total_steps
        self.label = label
        self.evaluation = evaluation
        self.stream = stream or sys.stderr
        self.bar = None
        self.reported_evaluations = 0
        self.next_line_at = 0

    def _on_training_start(self) -> None:
        self.start_steps = self.shown_steps = self.num_timesteps
        self.started = time.perf_counter()
        if self.evaluation is not None:
            self.reported_evaluations = len(self.evaluation.evaluations_timesteps)
        self.next_line_at = self.start_steps + self.total_steps // 10
        if self.mode == "bar":
            from tqdm import tqdm

            self.bar = tqdm(
                total=self.total_steps,
                initial=self.start_steps,
                desc=self.label,
                unit="step",
                dynamic_ncols=True,
                file=self.stream,
            )

    def _on_step(self) -> bool:
        if self.mode == "none":
            return True
        latest = self._new_evaluation()
        if self.bar is not None:
            self.bar.update(self.num_timesteps - self.shown_steps)
            self.shown_steps = self.num_timesteps
            if latest:
                self.bar.set_postfix_str(latest, refresh=True)
        elif latest or (self.evaluation is None and self.num_timesteps >= self.next_line_at):
            self.next_line_at += max(self.total_steps // 10, 1)
            print(self._line(latest), file=self.stream, flush=True)
        return True

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def _new_evaluation(self) -> str:
        evaluation = self.evaluation
        if evaluation is None or len(evaluation.evaluations_results) <= self.reported_evaluations:
            return ""
        self.reported_evaluations = len(evaluation.evaluations_results)
        results = evaluation.evaluations_results[-1]
        mean, std = np.mean(results), np.std(results)
        return f"eval {mean:.2f} ± {std:.2f} (best {evaluation.best_mean_reward:.2f})"

    def _line(self, latest: str) -> str:
        elapsed = time.perf_counter() - self.started
        done = self.num_timesteps - self.start_steps
        rate = done / elapsed if elapsed > 0 else 0.0
        left = (self.total_steps - self.num_timesteps) / rate if rate > 0 else float("nan")
        parts = [
            f"{self.label}",
            f"step {self.num_timesteps:,}/{self.total_steps:,}",
            latest,
            f"{rate:.0f} steps/s",
            f"elapsed {format_duration(elapsed)}",
            f"ETA {format_duration(left)}" if left == left else "",
        ]
        return "  ".join(part for part in parts if part)
