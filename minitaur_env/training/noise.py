"""Colored exploring noise for SAC (Eberhard et al. 2023, "Pink noise is all you need"):
``pink-noise-rl``'s process, shared by the PyTorch and the SBX policy, no torch or JAX."""

from __future__ import annotations

from typing import Any

import numpy as np
from pink import ColoredNoiseProcess

# Steps per colored-noise sequence: the classic 1000-step time limit, as Eberhard et al.
# set it to the episode length (a longer one adds periods no episode can use).
COLORED_NOISE_STEPS = 1000


def checked_noise_color(value: Any) -> float:
    """``noise_color`` as a float, or a one-line ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 2:
        raise ValueError(f"noise_color must be a number in [0, 2], got {value!r}")
    return float(value)


def colored_noise_process(beta: float, shape: tuple[int, ...], seed: int) -> ColoredNoiseProcess:
    """Unit-variance noise of spectrum ``1 / f ** beta``, one sequence per entry of ``shape``
    (envs by action dimensions); ``sample()`` gives the next step's ``shape`` array."""
    size = (*shape, COLORED_NOISE_STEPS)
    return ColoredNoiseProcess(beta=beta, size=size, rng=np.random.default_rng(seed))
