"""The env's grouped settings: sim-to-real realism, reward weights and the camera.

Each is a frozen dataclass that checks itself when made, so an env holds only settings
that make physical sense, and each error names the setting, the value and the accepted
range.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from minitaur_env.checks import choice, integer, number, preset_or_fields
from minitaur_env.randomization import DynamicsRanges, Pushes

CLASSIC_CONTROL_STEP = 0.01  # s, one action at 100 Hz
MAX_CONTROL_STEP = 0.1  # s; a larger value is almost surely milliseconds
# s; shorter, "position" control (one physics step per control step) would get no solver
# iteration (the classic budget is 300 per 10 ms) and the motor models' 2 ms step no fit.
MIN_CONTROL_STEP = 0.001
MAX_LATENCY = 1.0  # s
MAX_IMU_ERROR = 1.0  # rad


@dataclasses.dataclass(frozen=True)
class Uniform:
    """A setting drawn anew at every reset, uniformly in ``[low, high]``."""

    low: float
    high: float

    def draw(self, rng: np.random.Generator, size: int | None = None) -> Any:
        return rng.uniform(self.low, self.high, size)


@dataclasses.dataclass(frozen=True)
class EpisodeRealism:
    """One episode's realism: every range of a :class:`Realism` drawn, the control step
    snapped to whole physics steps (``reset``'s ``info["realism"]`` when any is drawn)."""

    control_time_step: float
    control_latency: float
    pd_latency: float
    imu_noise_stdev: float
    imu_bias: tuple[float, float, float]


# The order of the draws: the first four as the classic randomizer drew them, so that a
# seed gives the episodes it gave when they lived in DynamicsRanges.
DRAW_ORDER = ("control_time_step", "control_latency", "imu_noise_stdev", "imu_bias", "pd_latency")


@dataclasses.dataclass(frozen=True)
class Realism:
    """What the classic env leaves ideal, after Tan et al. 2018; the defaults are classic.

    Each of the first five fields takes a value, or a range ``(low, high)`` drawn
    uniformly at every reset from the env's seeded generator:

    - ``control_time_step`` (0.01 s, 0.001 to 0.1): the control step, a multiple of the
      2 ms physics step (with "position" motor control, the physics step itself; a
      drawn step is snapped to whole physics steps). The return sums per-step rewards,
      so it grows with the time 1000 steps last.
    - ``control_latency`` (0 s, at most 1): observations are this old, interpolated
      between the physics steps' sensor readings as the classic reactive env did.
    - ``pd_latency`` (0 s, at most 1): the motors' PD loop sees angles and velocities
      this old (the motor's back-EMF still uses the true velocity); needs a motor model.
    - ``imu_noise_stdev`` (0 rad, at most 1): Gaussian noise on the IMU's roll, pitch and
      yaw (and rates).
    - ``imu_bias`` (0 rad, within +-1): added to the IMU's angles; a number (every
      axis), three numbers (one per axis) or ``(low, high)``, drawn per axis. In the
      classic observation noise and bias reach the quaternion through the Euler angles.
    - ``pushes`` (None): ``True`` for Tan et al.'s pushes (130-220 N, horizontal, in a
      random direction, for 0.06 s every 1.2 s), ``"sagittal"`` (:meth:`Pushes.sagittal`),
      ``"walking"`` (:meth:`Pushes.walking`), or a :class:`Pushes` or mapping of its
      fields; the force of each step is ``info["push_force"]``.

    :meth:`tan2018` gives Table I's timing and IMU ranges.
    """

    control_time_step: float | Uniform = CLASSIC_CONTROL_STEP
    control_latency: float | Uniform = 0.0
    pd_latency: float | Uniform = 0.0
    imu_noise_stdev: float | Uniform = 0.0
    imu_bias: float | Sequence[float] | Uniform = (0.0, 0.0, 0.0)
    pushes: Pushes | Mapping[str, Any] | bool | None = None

    def __post_init__(self) -> None:
        checked = {
            "control_time_step": _setting(
                "control_time_step",
                self.control_time_step,
                MIN_CONTROL_STEP,
                MAX_CONTROL_STEP,
                "s",
            ),
            "control_latency": _setting(
                "control_latency", self.control_latency, 0, MAX_LATENCY, "s"
            ),
            "pd_latency": _setting("pd_latency", self.pd_latency, 0, MAX_LATENCY, "s"),
            "imu_noise_stdev": _setting(
                "imu_noise_stdev", self.imu_noise_stdev, 0, MAX_IMU_ERROR, "rad"
            ),
            "imu_bias": _imu_bias(self.imu_bias),
            "pushes": Pushes.coerce(self.pushes),
        }
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    @classmethod
    def tan2018(cls) -> Realism:
        """Table I of Tan et al. 2018: control step 3-20 ms, latency 0-40 ms, IMU noise
        0-0.05 and bias +-0.05 rad (the classic ``minitaur_env_randomizer_config``)."""
        return cls(
            control_time_step=Uniform(0.003, 0.02),
            control_latency=Uniform(0.0, 0.04),
            imu_noise_stdev=Uniform(0.0, 0.05),
            imu_bias=Uniform(-0.05, 0.05),
        )

    @classmethod
    def coerce(
        cls, value: Realism | Mapping[str, Any] | str | None, base: Realism | None = None
    ) -> Realism:
        """From a Realism, ``"classic"``, ``"tan2018"``, or a mapping of fields set on
        top of ``base`` (classic by default); None is ``base``."""
        return preset_or_fields(cls, "realism", value, cls() if base is None else base)

    @property
    def drawn(self) -> bool:
        """Whether any field is a range, drawn at every reset."""
        return any(isinstance(getattr(self, name), Uniform) for name in DRAW_ORDER)

    def highest(self, name: str) -> float:
        """The largest value ``name`` can take (the range's top for a drawn one)."""
        value = getattr(self, name)
        return value.high if isinstance(value, Uniform) else float(np.max(value))

    def draw(self, rng: np.random.Generator) -> EpisodeRealism:
        """This episode's values: each range drawn from ``rng`` in ``DRAW_ORDER``,
        and nothing drawn for a fixed field, so the classic settings draw nothing."""
        values: dict[str, Any] = {}
        for name in DRAW_ORDER:
            value = getattr(self, name)
            if name == "imu_bias":
                drawn = value.draw(rng, 3) if isinstance(value, Uniform) else value
                values[name] = tuple(float(v) for v in drawn)
            else:
                values[name] = float(value.draw(rng) if isinstance(value, Uniform) else value)
        return EpisodeRealism(**values)


def _setting(name: str, value: Any, low: float, high: float, unit: str) -> float | Uniform:
    """A number in ``[low, high]``, or a range within it drawn per episode."""
    if isinstance(value, Uniform):
        value = (value.low, value.high)
    if isinstance(value, str) or np.ndim(value) == 0:
        return number(name, value, low, high, unit=unit)
    bounds = list(value) if np.ndim(value) == 1 else []
    if len(bounds) != 2:
        raise ValueError(f"{name} must be a number or (low, high) in {unit}, got {value!r}")
    first = number(f"{name} low", bounds[0], low, high, unit=unit)
    last = number(f"{name} high", bounds[1], low, high, unit=unit)
    if first > last:
        raise ValueError(f"{name} must be (low, high) with low <= high, got {value!r}")
    return Uniform(first, last)


def _same(a: Any, b: Any) -> bool:
    return bool(np.array_equal(a, b)) if isinstance(a, tuple) else a == b


def _imu_bias(value: Any) -> tuple[float, float, float] | Uniform:
    if isinstance(value, Uniform) or (np.ndim(value) == 1 and len(value) == 2):
        return _setting("imu_bias", value, -MAX_IMU_ERROR, MAX_IMU_ERROR, "rad")
    values = [value] if np.ndim(value) == 0 else list(value) if np.ndim(value) == 1 else None
    if values is None or len(values) not in (1, 3):
        raise ValueError(f"imu_bias must be a number, three or (low, high) (rad), got {value!r}")
    checked = [number("imu_bias", v, -MAX_IMU_ERROR, MAX_IMU_ERROR, unit="rad") for v in values]
    return tuple(checked * 3 if len(checked) == 1 else checked)  # type: ignore[return-value]


def merge_realism(
    realism: Realism | Mapping[str, Any] | str | None,
    flat: Mapping[str, Any],
    base: Realism,
) -> Realism:
    """``realism`` on top of ``base``, then the deprecated flat keywords given (those not
    None) on top. A field set both in ``realism`` and as a keyword, to different values,
    is refused rather than one silently winning."""
    given = {name: setting for name, setting in flat.items() if setting is not None}
    merged = Realism.coerce(realism, base)
    if not given:
        return merged
    shown = ", ".join(f"{name}={setting!r}" for name, setting in given.items())
    warnings.warn(
        f"the keyword{'s' if len(given) > 1 else ''} {shown} will be removed after 0.3; "
        f"give realism={{{', '.join(f'{name!r}: {s!r}' for name, s in given.items())}}}",
        FutureWarning,
        stacklevel=3,
    )
    flattened = dataclasses.replace(merged, **given)
    if realism is not None:
        mine, default = Realism.coerce(realism), Realism()
        for name in given:
            own = getattr(mine, name)
            if not _same(own, getattr(default, name)) and not _same(own, getattr(flattened, name)):
                raise ValueError(
                    f"{name} is given twice, as {name}={given[name]!r} and in realism "
                    f"({own!r}); give it once"
                )
    return flattened


@dataclasses.dataclass(frozen=True)
class RewardWeights:
    """The classic reward's weights: ``forward`` may have either sign; the penalties'
    weights are >= 0."""

    distance: float = 1.0
    energy: float = 0.005
    drift: float = 0.0
    shake: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "distance",
            number(
                "distance_weight", self.distance, -math.inf, math.inf, low_open=True, high_open=True
            ),
        )
        for name in ("energy", "drift", "shake"):
            weight = number(f"{name}_weight", getattr(self, name), 0, math.inf, high_open=True)
            object.__setattr__(self, name, weight)


@dataclasses.dataclass(frozen=True)
class Camera:
    """The rgb_array camera: image size (pixels) and a view following the robot."""

    width: int = 640
    height: int = 480
    distance: float = 1.0  # m
    yaw: float = 0.0  # deg
    pitch: float = -30.0  # deg

    def __post_init__(self) -> None:
        integer("width", self.width, 1, 4096)
        integer("height", self.height, 1, 4096)
        number("camera_distance", self.distance, 0, 100, low_open=True, unit="m")
        number("camera_yaw", self.yaw, -360, 360, unit="deg")
        number("camera_pitch", self.pitch, -90, 90, unit="deg")


# Named starting points for dynamics_ranges and realism; what the caller gives is set on
# top, field by field. "tan2018": Table I of Tan et al. 2018 and a 3 ms PD latency, the
# Randomized ids' setting.
PRESETS = ("tan2018",)


def preset_settings(name: str | None) -> tuple[DynamicsRanges, Realism]:
    """The dynamics ranges and realism a preset starts from (None: the classic env's)."""
    if choice("preset", name, (None, *PRESETS)) is None:
        return DynamicsRanges(), Realism()
    return DynamicsRanges.tan2018(), dataclasses.replace(Realism.tan2018(), pd_latency=0.003)
