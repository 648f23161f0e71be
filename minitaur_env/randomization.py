"""Per-episode dynamics randomization and pushes, drawn from the env's own seeded generator."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from minitaur_env.checks import boolean, from_mapping, number, preset_or_fields
from minitaur_env.robot import NUM_MOTORS, Minitaur

Range = tuple[float, float]

# What each range accepts: (lowest, highest, unit). Generous, but physical.
RANGE_BOUNDS: dict[str, tuple[float, float, str]] = {
    "base_mass_scale": (0.0, 10.0, ""),
    "leg_mass_scale": (0.0, 10.0, ""),
    "battery_voltage": (0.0, 50.0, "V"),
    "motor_viscous_damping": (0.0, 1.0, "N m s/rad"),
    "foot_friction": (0.0, 10.0, ""),
    "inertia_scale": (0.0, 10.0, ""),
    "motor_strength": (0.0, 10.0, ""),
    "joint_friction": (0.0, 100.0, "N m"),
}
POSITIVE_RANGES = {"base_mass_scale", "leg_mass_scale", "inertia_scale", "battery_voltage"}
MAX_PUSH_FORCE = 10_000.0  # N
MIN_PUSH_INTERVAL = 0.01  # s, one classic control step
SAGITTAL_BOUND = (130.0, 60.0)  # N, along and across the body (docs/sim-to-real.md)
WALKING_BOUND = (40.0, 20.0)  # N, along and across the body (docs/sim-to-real.md)


@dataclasses.dataclass(frozen=True)
class DynamicsRanges:
    """Uniform ranges of the parameters re-drawn at every reset.

    The defaults are the classic ``MinitaurEnvRandomizer``'s; the fields that default to
    ``None`` are not randomized (the env's fixed value holds), so the classic draws and
    their order are unchanged. :meth:`tan2018` gives Tan et al. 2018's Table I (the control
    step, latency and IMU errors are drawn by :class:`Realism`).
    """

    base_mass_scale: Range = (0.8, 1.2)
    """Factor on the URDF mass of the base."""
    leg_mass_scale: Range = (0.8, 1.2)
    """Factor on the URDF masses of the leg links and, drawn separately, of the motors."""
    battery_voltage: Range = (14.8, 16.8)
    """Battery voltage feeding the motor model (V)."""
    motor_viscous_damping: Range = (0.0, 0.01)
    """Motor viscous damping, the paper's "motor friction" (N m s / rad)."""
    foot_friction: Range = (0.8, 1.5)
    """Lateral friction coefficient of the feet (contact friction)."""
    inertia_scale: Range | None = None
    """Factor on the URDF inertias of the base and, drawn separately, of the legs."""
    motor_strength: Range | None = None
    """Factor on each motor's output torque, one draw per motor."""
    joint_friction: Range | None = None
    """Coulomb friction torque of each knee joint (N m), one draw per knee."""

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if value is None and field.default is None:
                continue
            low, high, unit = RANGE_BOUNDS[field.name]
            name = f"DynamicsRanges.{field.name}"
            try:
                first, last = value
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be (low, high), got {value!r}") from None
            # Masses, inertias and the voltage must stay > 0: a zero mass makes a body static.
            low_open = field.name in POSITIVE_RANGES
            first = number(f"{name} low", first, low, high, low_open=low_open, unit=unit)
            last = number(f"{name} high", last, low, high, low_open=low_open, unit=unit)
            if first > last:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {value!r}")
            object.__setattr__(self, field.name, (first, last))

    @classmethod
    def tan2018(cls) -> DynamicsRanges:
        """The physical ranges of Table I of Tan et al. 2018, "Sim-to-Real: Learning Agile
        Locomotion For Quadruped Robots" (the classic ``minitaur_env_randomizer_config``;
        its timing and IMU ranges are :meth:`Realism.tan2018`)."""
        return cls(
            base_mass_scale=(0.8, 1.2),
            leg_mass_scale=(0.8, 1.2),
            battery_voltage=(14.0, 16.8),
            motor_viscous_damping=(0.0, 0.05),
            foot_friction=(0.5, 1.25),
            inertia_scale=(0.5, 1.5),
            motor_strength=(0.8, 1.2),
            joint_friction=(0.0, 0.05),
        )

    @classmethod
    def coerce(
        cls, value: DynamicsRanges | dict[str, Any] | str | None, base: DynamicsRanges | None = None
    ) -> DynamicsRanges:
        """From what ``--env-kwargs`` can carry: ``"classic"``, ``"tan2018"`` or a mapping of
        fields set on top of ``base`` (classic by default: ``{motor_strength: [0.8, 0.8]}``
        keeps the other ranges); None is ``base``."""
        return preset_or_fields(cls, "dynamics_ranges", value, cls() if base is None else base)


@dataclasses.dataclass(frozen=True)
class DynamicsSample:
    """One draw of the physical parameters, reported in the reset info.

    The optional entries are None where their range is None.
    """

    base_mass: float
    leg_mass: float
    motor_mass: float
    battery_voltage: float
    motor_viscous_damping: float
    foot_friction: float
    base_inertia_scale: float | None = None
    leg_inertia_scale: float | None = None
    motor_strength: tuple[float, ...] | None = None
    joint_friction: tuple[float, ...] | None = None


def sample_dynamics(
    robot: Minitaur, ranges: DynamicsRanges, rng: np.random.Generator
) -> DynamicsSample:
    """Draw every parameter from ``rng``, in a fixed order, so a seed fixes them all.

    The classic parameters come first, so the classic ranges draw what they always drew.
    """
    sample = DynamicsSample(
        base_mass=robot.base_mass_urdf * rng.uniform(*ranges.base_mass_scale),
        leg_mass=robot.leg_mass_urdf * rng.uniform(*ranges.leg_mass_scale),
        motor_mass=robot.motor_mass_urdf * rng.uniform(*ranges.leg_mass_scale),
        battery_voltage=rng.uniform(*ranges.battery_voltage),
        motor_viscous_damping=rng.uniform(*ranges.motor_viscous_damping),
        foot_friction=rng.uniform(*ranges.foot_friction),
    )
    extra: dict[str, Any] = {}
    if ranges.inertia_scale is not None:
        extra["base_inertia_scale"] = rng.uniform(*ranges.inertia_scale)
        extra["leg_inertia_scale"] = rng.uniform(*ranges.inertia_scale)
    if ranges.motor_strength is not None:
        extra["motor_strength"] = tuple(
            float(v) for v in rng.uniform(*ranges.motor_strength, size=NUM_MOTORS)
        )
    if ranges.joint_friction is not None:
        extra["joint_friction"] = tuple(
            float(v) for v in rng.uniform(*ranges.joint_friction, size=NUM_MOTORS)
        )
    return dataclasses.replace(sample, **extra)


def apply_dynamics(robot: Minitaur, sample: DynamicsSample) -> None:
    """Set the robot's physical parameters."""
    robot.set_base_mass(sample.base_mass)
    robot.set_leg_masses(sample.leg_mass, sample.motor_mass)
    robot.set_battery_voltage(sample.battery_voltage)
    robot.set_motor_viscous_damping(sample.motor_viscous_damping)
    robot.set_foot_friction(sample.foot_friction)
    if sample.base_inertia_scale is not None and sample.leg_inertia_scale is not None:
        robot.scale_inertias(sample.base_inertia_scale, sample.leg_inertia_scale)
    if sample.motor_strength is not None:
        robot.set_motor_strength(sample.motor_strength)
    if sample.joint_friction is not None:
        robot.set_joint_friction(sample.joint_friction)


@dataclasses.dataclass(frozen=True)
class Pushes:
    """Horizontal pushes on the base: a force of a random magnitude in ``force`` (N), in a
    random direction of the ground plane, for ``duration`` seconds every ``interval``
    seconds of an episode (the first at ``interval``). The defaults are Tan et al. 2018's.
    ``direction`` (degrees from the +x axis, counterclockwise seen from above) fixes the
    direction: 0 pushes forward, 90 to the left; the magnitudes drawn stay the same.
    ``heading`` measures directions from the robot's heading (its yaw when the push
    begins) instead of the world's +x axis. ``bound`` (N, along and across the heading,
    or +x without ``heading``) is an ellipse a push must stay inside: one outside is
    scaled down onto it, keeping its direction, so a bound of (130, 80) lets a push along
    the body reach 130 N and one from the side 80 N. :meth:`sagittal` is the setting a
    Minitaur, whose legs move only in its sagittal plane, can be asked to survive.
    """

    force: Range = (130.0, 220.0)
    interval: float = 1.2
    duration: float = 0.06
    direction: float | None = None
    heading: bool = False
    bound: Range | None = None

    def __post_init__(self) -> None:
        try:
            low, high = self.force
        except (TypeError, ValueError):
            raise ValueError(f"Pushes.force must be (low, high) in N, got {self.force!r}") from None
        low = number("Pushes.force low", low, 0, MAX_PUSH_FORCE, unit="N")
        high = number("Pushes.force high", high, 0, MAX_PUSH_FORCE, unit="N")
        if low > high:
            raise ValueError(f"Pushes.force must be (low, high) with low <= high, got {self.force}")
        # A push at most every classic control step: shorter intervals are a constant
        # force, not pushes (one at every physics step for 1e-9).
        interval = number("Pushes.interval", self.interval, MIN_PUSH_INTERVAL, 600, unit="s")
        duration = number("Pushes.duration", self.duration, 0, 600, low_open=True, unit="s")
        if duration > interval:
            raise ValueError(
                f"Pushes needs 0 < duration <= interval, got duration {duration}, "
                f"interval {interval}"
            )
        direction = self.direction
        if direction is not None:
            direction = number("Pushes.direction", direction, -360, 360, unit="degrees")
        bound = self.bound
        if bound is not None:
            try:
                along, across = bound
            except (TypeError, ValueError):
                raise ValueError(
                    f"Pushes.bound must be (along, across) in N, got {bound!r}"
                ) from None
            bound = (
                number("Pushes.bound along", along, 0, MAX_PUSH_FORCE, low_open=True, unit="N"),
                number("Pushes.bound across", across, 0, MAX_PUSH_FORCE, low_open=True, unit="N"),
            )
        checked = {
            "force": (low, high),
            "interval": interval,
            "duration": duration,
            "direction": direction,
            "heading": boolean("Pushes.heading", self.heading),
            "bound": bound,
        }
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    @classmethod
    def sagittal(cls) -> Pushes:
        """Tan et al.'s pushes (130-220 N for 0.06 s every 1.2 s, any direction around the
        robot's heading) brought inside the ellipse of 130 N along the body and 60 N across
        it: every push lands on that ellipse. A Minitaur standing still survives 99 % of
        them (1 fall in the 20 report episodes; at 80 N across, 8 falls; Tan et al.'s own
        pushes, 19): docs/sim-to-real.md, "Which pushes a Minitaur can survive"."""
        return cls(heading=True, bound=SAGITTAL_BOUND)

    @classmethod
    def walking(cls) -> Pushes:
        """Tan et al.'s pushes brought onto the ellipse of 40 N along the body and 20 N
        across it: the largest of the ellipses measured that the shipped robust PPO,
        trotting, survives in at most 2 of 20 report episodes. A walking trot stands on two
        diagonal feet and falls to a third of the side push a robot at rest takes:
        docs/sim-to-real.md, "Pushes a walking trot survives"."""
        return cls(heading=True, bound=WALKING_BOUND)

    @classmethod
    def coerce(cls, value: Pushes | dict[str, Any] | bool | str | None) -> Pushes | None:
        """``True`` or ``"tan2018"`` (Tan et al.'s pushes), ``"sagittal"``
        (:meth:`sagittal`), ``"walking"`` (:meth:`walking`), a mapping of fields, or
        None/False (no pushes)."""
        if value is None or value is False:
            return None
        if value is True or value == "tan2018":
            return cls()
        if value == "sagittal":
            return cls.sagittal()
        if value == "walking":
            return cls.walking()
        if isinstance(value, cls):
            return value
        if isinstance(value, dict):
            return from_mapping(cls, value)
        raise ValueError(
            "pushes must be True, 'tan2018', 'sagittal', 'walking', a Pushes or a mapping of its "
            f"fields, got {value!r}"
        )

    def draw(self, rng: np.random.Generator, yaw: float = 0.0) -> np.ndarray:
        """One push's world-frame force vector (N); ``yaw`` (rad) is the robot's heading,
        which directions are measured from when ``heading`` is set."""
        magnitude = rng.uniform(*self.force)
        angle = rng.uniform(0.0, 2.0 * math.pi)  # drawn either way: the same magnitudes follow
        if self.direction is not None:
            angle = math.radians(self.direction)
        if self.bound is not None:
            along, across = self.bound
            reach = math.hypot(math.cos(angle) / along, math.sin(angle) / across)
            magnitude = min(magnitude, 1.0 / reach)  # 1 / reach: the ellipse's radius there
        if self.heading:
            angle += yaw
        return np.array([magnitude * math.cos(angle), magnitude * math.sin(angle), 0.0])
