"""How a run ended, and the summary train.py prints."""

from __future__ import annotations

import dataclasses
import signal
from pathlib import Path

import numpy as np

from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.safe_load import embedded_evaluation


@dataclasses.dataclass
class RunResult:
    """How a run ended: ``completed``, ``interrupted`` (Ctrl-C/SIGTERM), ``diverged`` or
    ``failed`` (an env raised)."""

    status: str
    run: RunFolder
    num_timesteps: int
    trained_steps: int
    elapsed_s: float
    checkpoint: Path | None = None
    signal: int | None = None
    message: str = ""
    last_eval: tuple[int, float, float] | None = None  # (steps, mean, std)
    best_eval: tuple[int, float] | None = None  # (steps, mean)
    usage_error: bool = False  # failed on a setting, not on the env or the disk

    @property
    def exit_code(self) -> int:
        """The status a script should exit with. 0; 2 (failed on a setting); 1 (diverged, or
        failed on the env or the disk); 130 (Ctrl-C), 143 (SIGTERM)."""
        if self.status == "completed":
            return 0
        if self.status == "interrupted":
            return 128 + (self.signal or signal.SIGINT)
        return 2 if self.usage_error else 1

    def summary(self) -> str:
        lines = [f"run folder: {self.run}"]
        rate = self.trained_steps / max(self.elapsed_s, 1e-9)
        lines.append(
            f"env steps: {self.num_timesteps} ({self.trained_steps} this session, "
            f"{self.elapsed_s / 60:.1f} min, {rate:.0f} steps/s)"
        )
        if self.last_eval is not None and self.best_eval is not None:
            steps, mean, std = self.last_eval
            lines.append(
                f"last eval: {mean:.2f} +- {std:.2f} at {steps} steps; "
                f"best: {self.best_eval[1]:.2f} at {self.best_eval[0]} steps"
            )
        if self.run.learning_curve.is_file():
            lines.append(f"learning curve: {self.run.learning_curve}")
        return "\n".join(lines)

    def read_evaluations(self, env_id: str) -> None:
        """Fill ``last_eval`` and ``best_eval`` from evaluations.npz (the best model's own
        record where its zip holds one) and draw the curve."""
        import gymnasium as gym

        from minitaur_env.training.plotting import plot_learning_curve

        run = self.run
        if not run.evaluations.exists():
            return
        with np.load(run.evaluations) as data:
            results, steps = data["results"], data["timesteps"]
        if not len(steps):
            return
        means = results.mean(axis=1)
        best = int(np.argmax(means))
        self.last_eval = (int(steps[-1]), float(means[-1]), float(results[-1].std()))
        self.best_eval = (int(steps[best]), float(means[best]))
        if run.best_model.is_file():
            self.best_eval = embedded_evaluation(run.best_model) or self.best_eval
        plot_learning_curve(
            run.evaluations,
            run.learning_curve,
            title=f"{run.path.parent.name} on {env_id}",
            reward_threshold=gym.spec(env_id).reward_threshold,
        )
