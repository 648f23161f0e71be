"""An episode's drawn conditions as numbers, for a critic that sees them and an actor that does not.

Under randomization the return of an episode depends on what was drawn as much as on the
policy: the same gait covers twice the distance in a 1000-step episode at a 20 ms control
step as at 10 ms, and a weak motor or a long latency decide whether it falls. A value
function that sees only the observations has to guess the draws from a few frames, and
its errors are the advantages' noise. An asymmetric actor-critic (Pinto et al. 2018)
gives the critic the simulator's own values, which exist only in simulation, and keeps
the actor on what a robot senses (``PrivilegedCriticPolicy`` in
``minitaur_env.training.policies``).

``privileged=True`` on the trotting envs appends the values of ``CONDITION_NAMES`` to every
observation, each scaled so that Tan et al. 2018's range (Table I) spans [-1, 1]; a value
the env does not draw enters as the value in effect (the URDF's masses and inertias,
full motor strength, frictionless knees).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from minitaur_env.randomization import DynamicsSample
from minitaur_env.robot import NUM_MOTORS
from minitaur_env.settings import EpisodeRealism

# (name, low, high): the range mapped onto [-1, 1]; Tan et al.'s, and for the PD latency,
# which they do not draw, 0 to twice the preset's 3 ms.
_SCALED = (
    ("base_mass_scale", 0.8, 1.2),
    ("leg_mass_scale", 0.8, 1.2),
    ("motor_mass_scale", 0.8, 1.2),
    ("battery_voltage", 14.0, 16.8),
    ("motor_viscous_damping", 0.0, 0.05),
    ("foot_friction", 0.5, 1.25),
    ("base_inertia_scale", 0.5, 1.5),
    ("leg_inertia_scale", 0.5, 1.5),
    *((f"motor_strength_{i}", 0.8, 1.2) for i in range(NUM_MOTORS)),
    *((f"joint_friction_{i}", 0.0, 0.05) for i in range(NUM_MOTORS)),
    ("control_time_step", 0.003, 0.02),
    ("control_latency", 0.0, 0.04),
    ("pd_latency", 0.0, 0.006),
    ("imu_noise_stdev", 0.0, 0.05),
    *((f"imu_bias_{axis}", -0.05, 0.05) for axis in "xyz"),
)
CONDITION_NAMES = tuple(name for name, _, _ in _SCALED)
CONDITION_RANGES = {name: (low, high) for name, low, high in _SCALED}
# The PPO policy whose actor does not see these entries (minitaur_env.training.policies).
PRIVILEGED_POLICY_NAME = "PrivilegedCriticPolicy"
_LOW = np.array([low for _, low, _ in _SCALED])
_HALF_WIDTH = np.array([(high - low) / 2 for _, low, high in _SCALED])


def condition_values(
    dynamics: DynamicsSample, realism: EpisodeRealism, urdf_masses: tuple[float, float, float]
) -> dict[str, float]:
    """The episode's conditions by name, unscaled; ``urdf_masses`` are the base's, a leg
    link's and a motor's URDF masses, which the drawn masses are relative to."""
    base_mass, leg_mass, motor_mass = urdf_masses
    strength = dynamics.motor_strength or (1.0,) * NUM_MOTORS
    knee_friction = dynamics.joint_friction or (0.0,) * NUM_MOTORS
    values = {
        "base_mass_scale": dynamics.base_mass / base_mass,
        "leg_mass_scale": dynamics.leg_mass / leg_mass,
        "motor_mass_scale": dynamics.motor_mass / motor_mass,
        "battery_voltage": dynamics.battery_voltage,
        "motor_viscous_damping": dynamics.motor_viscous_damping,
        "foot_friction": dynamics.foot_friction,
        "base_inertia_scale": _in_effect(dynamics.base_inertia_scale, 1.0),
        "leg_inertia_scale": _in_effect(dynamics.leg_inertia_scale, 1.0),
        **{f"motor_strength_{i}": float(v) for i, v in enumerate(strength)},
        **{f"joint_friction_{i}": float(v) for i, v in enumerate(knee_friction)},
        "control_time_step": realism.control_time_step,
        "control_latency": realism.control_latency,
        "pd_latency": realism.pd_latency,
        "imu_noise_stdev": realism.imu_noise_stdev,
        **{f"imu_bias_{axis}": float(v) for axis, v in zip("xyz", realism.imu_bias, strict=True)},
    }
    return {name: values[name] for name in CONDITION_NAMES}


def _in_effect(drawn: float | None, urdf: float) -> float:
    return urdf if drawn is None else drawn


def scaled_conditions(values: dict[str, float]) -> np.ndarray:
    """The values in the order of ``CONDITION_NAMES``, Tan et al.'s range mapped onto [-1, 1]."""
    raw = np.array([values[name] for name in CONDITION_NAMES])
    return ((raw - _LOW) / _HALF_WIDTH - 1.0).astype(np.float32)


class EpisodeConditions(gym.ObservationWrapper):
    """Appends the episode's scaled conditions (``CONDITION_NAMES``) to every observation.

    Needs an env that draws its dynamics at every reset (``info["dynamics"]``): without a
    draw there is nothing for a critic to learn from, and a constant would hide a
    misconfigured run.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        inner = env.observation_space
        if not isinstance(inner, spaces.Box) or len(inner.shape) != 1:
            raise ValueError(f"privileged needs a flat Box observation, got {inner}")
        size = len(CONDITION_NAMES)
        self.observation_space = spaces.Box(
            np.concatenate([inner.low, np.full(size, -np.inf, np.float32)]),
            np.concatenate([inner.high, np.full(size, np.inf, np.float32)]),
            dtype=np.float32,
        )
        self._conditions = np.zeros(size, np.float32)

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        if "dynamics" not in info:
            raise ValueError(
                "privileged needs dynamics drawn at every reset; this env keeps them fixed "
                "(randomize_dynamics=False)"
            )
        base = self.env.unwrapped
        robot = base.robot
        masses = (robot.base_mass_urdf, robot.leg_mass_urdf, robot.motor_mass_urdf)
        values = condition_values(info["dynamics"], base.episode_realism, masses)
        self._conditions = scaled_conditions(values)
        return self.observation(observation), info

    def observation(self, observation: Any) -> np.ndarray:
        return np.concatenate([observation, self._conditions]).astype(np.float32)
