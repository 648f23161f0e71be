"""Figures: a run's learning curve (mean evaluation return +- std against env steps)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from minitaur_env.training.files import atomic_path


def figure(ncols: int = 1, figsize: tuple[float, float] = (8, 4.5)) -> tuple[Figure, Any]:
    """A figure and its axes, without pyplot: the user's matplotlib backend is left alone
    (a notebook keeps its own), and nothing stays open in pyplot's registry."""
    fig = Figure(figsize=figsize, dpi=100)
    return fig, fig.subplots(1, ncols)


def save_figure(fig: Figure, path: str | os.PathLike[str], bottom: float = 0.0) -> None:
    """Write ``fig`` as a PNG, its axes laid out above ``bottom`` (a fraction of the
    figure's height kept free, e.g. for a legend under the axes)."""
    fig.tight_layout(rect=(0, bottom, 1, 1))
    with atomic_path(path) as temp:
        fig.savefig(temp, format="png")


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
    fig, ax = figure(figsize=(7, 4))
    ax.plot(steps, mean, marker="o", markersize=3, label="mean eval return")
    ax.fill_between(steps, mean - std, mean + std, alpha=0.25, label="+- std")
    if reward_threshold is not None:
        ax.axhline(reward_threshold, color="grey", linestyle="--", label="reward threshold")
    ax.set_xlabel("env steps")
    ax.set_ylabel(f"return ({results.shape[1]} episodes)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    save_figure(fig, path)
