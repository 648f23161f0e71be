"""``StabilizedMlpPolicy`` on ``--backend sbx``: SBX's SAC policy with colored exploring noise.

Of the PyTorch policy's keys (:mod:`minitaur_env.training.policies`) only ``noise_color``
has an SBX counterpart here: SBX has its own LayerNorm critics (``layer_norm``) and held
noise (``use_sde``), and the other keys are PyTorch optimizer hooks. The exploring action
is ``tanh(mean + std * noise)`` with ``noise`` from the same colored-noise process, so an
entry such as ``minitaur-pink`` means the same exploration on either backend; updates,
evaluations and the deterministic action are SBX's own.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from sbx.sac.policies import SACPolicy

from minitaur_env.training.noise import checked_noise_color, colored_noise_process


@jax.jit
def _gaussian(actor_state: Any, observations: Any) -> tuple[Any, Any]:
    """Mean and standard deviation of the actor's Gaussian, before its tanh."""
    gaussian = actor_state.apply_fn(actor_state.params, observations).distribution
    return gaussian.loc, gaussian.stddev()


class ColoredNoiseSACPolicy(SACPolicy):
    """SBX's ``SACPolicy`` exploring with colored noise of exponent ``noise_color``."""

    def __init__(self, *args: Any, noise_color: float = 0.0, **kwargs: Any) -> None:
        self.noise_color = checked_noise_color(noise_color)
        if self.noise_color and kwargs.get("use_sde"):
            raise ValueError("noise_color colors SAC's own noise; it does not combine with use_sde")
        self._colored_noise: Any = None
        super().__init__(*args, **kwargs)

    def _predict(self, observation: np.ndarray, deterministic: bool = False) -> np.ndarray:  # type: ignore[override]
        if deterministic or not self.noise_color:
            return super()._predict(observation, deterministic)
        mean, std = (np.asarray(value) for value in _gaussian(self.actor_state, observation))
        process = self._colored_noise
        if process is None or tuple(process.size[:-1]) != mean.shape:
            # Seeded from the policy's key, which the run's seed sets.
            self.key, noise_key = jax.random.split(self.key)
            seed = int(jax.random.randint(noise_key, (), 0, np.iinfo(np.int32).max))
            process = colored_noise_process(self.noise_color, mean.shape, seed)
            self._colored_noise = process
        return np.tanh(mean + std * process.sample())
