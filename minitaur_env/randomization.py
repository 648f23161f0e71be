"""Per-episode dynamics randomization, drawn from the env's own seeded generator."""

from __future__ import annotations

import dataclasses

import numpy as np

from minitaur_env.robot import Minitaur


@dataclasses.dataclass(frozen=True)
class DynamicsRanges:
    """Uniform ranges of the physical parameters re-drawn at every reset.

    The defaults are the classic ``MinitaurEnvRandomizer``'s.
    """

    base_mass_scale: tuple[float, float] = (0.8, 1.2)
    """Factor on the URDF mass of the base."""
    leg_mass_scale: tuple[float, float] = (0.8, 1.2)
    """Factor on the URDF masses of the leg links and, drawn separately, of the motors."""
    battery_voltage: tuple[float, float] = (14.8, 16.8)
    """Battery voltage feeding the motor model (V)."""
    motor_viscous_damping: tuple[float, float] = (0.0, 0.01)
    """Motor viscous damping (N m s / rad)."""
    foot_friction: tuple[float, float] = (0.8, 1.5)
    """Lateral friction coefficient of the feet."""

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            low, high = getattr(self, field.name)
            if not (np.isfinite(low) and np.isfinite(high) and 0.0 <= low <= high):
                raise ValueError(
                    f"DynamicsRanges.{field.name} must be (low, high) with 0 <= low <= high, "
                    f"got {(low, high)}"
                )


@dataclasses.dataclass(frozen=True)
class DynamicsSample:
    """One draw of the physical parameters, reported in the reset info."""

    base_mass: float
    leg_mass: float
    motor_mass: float
    battery_voltage: float
    motor_viscous_damping: float
    foot_friction: float


def sample_dynamics(
    robot: Minitaur, ranges: DynamicsRanges, rng: np.random.Generator
) -> DynamicsSample:
    """Draw every parameter from ``rng``, in a fixed order, so a seed fixes them all."""
    return DynamicsSample(
        base_mass=robot.base_mass_urdf * rng.uniform(*ranges.base_mass_scale),
        leg_mass=robot.leg_mass_urdf * rng.uniform(*ranges.leg_mass_scale),
        motor_mass=robot.motor_mass_urdf * rng.uniform(*ranges.leg_mass_scale),
        battery_voltage=rng.uniform(*ranges.battery_voltage),
        motor_viscous_damping=rng.uniform(*ranges.motor_viscous_damping),
        foot_friction=rng.uniform(*ranges.foot_friction),
    )


def apply_dynamics(robot: Minitaur, sample: DynamicsSample) -> None:
    robot.set_base_mass(sample.base_mass)
    robot.set_leg_masses(sample.leg_mass, sample.motor_mass)
    robot.set_battery_voltage(sample.battery_voltage)
    robot.set_motor_viscous_damping(sample.motor_viscous_damping)
    robot.set_foot_friction(sample.foot_friction)
