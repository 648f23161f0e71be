"""The learning curve of a run: mean evaluation return +- std against env steps."""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from minitaur_env.training.video import atomic_path


def plot_learning_curve(
    evaluations: str | os.PathLike[str],
    path: str | os.PathLike[str],
    title: str = "",
    reward_threshold: float | None = None,
) -> None:
    """Plot SB3's ``evaluations.npz`` (timesteps, results[n_evals, n_episodes]) to a PNG."""
    with np.load(evaluations) as data:
        steps = data["timesteps"]
        results = data["results"]
    mean, std = results.mean(axis=1), results.std(axis=1)
    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    ax.plot(steps, mean, marker="o", markersize=3, label="mean eval return")
    ax.fill_between(steps, mean - std, mean + std, alpha=0.25, label="+- std")
    if reward_threshold is not None:
        ax.axhline(reward_threshold, color="grey", linestyle="--", label="reward threshold")
    ax.set_xlabel("env steps")
    ax.set_ylabel(f"return ({results.shape[1]} episodes)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    fig.tight_layout()
    with atomic_path(path) as temp:
        fig.savefig(temp, format="png")
    plt.close(fig)
