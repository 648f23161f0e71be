"""The env's grouped settings: sim-to-real realism, reward weights and the camera.

Each is a frozen dataclass that checks itself when made, so an env holds only settings
that make physical sense, and each error names the setting, the value and the accepted
range.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from minitaur_env.checks import from_mapping, integer, number
from minitaur_env.randomization import Pushes

CLASSIC_CONTROL_STEP = 0.01  # s, one action at 100 Hz
MAX_CONTROL_STEP = 0.1  # s; a larger value is almost surely milliseconds
# s; shorter, "position" control (one physics step per control step) would get no solver
# iteration (the classic budget is 300 per 10 ms) and the motor models' 2 ms step no fit.
MIN_CONTROL_STEP = 0.001
MAX_LATENCY = 1.0  # s
MAX_IMU_ERROR = 1.0  # rad


@dataclasses.dataclass(frozen=True)
class Realism:
    """What the classic env leaves ideal, after Tan et al. 2018; the defaults are classic.

    - ``control_time_step`` (0.01 s, 0.001 to 0.1): the control step, a multiple of the
      2 ms physics step (with "position" motor control, the physics step itself). The
      return sums per-step rewards, so it grows with the time 1000 steps last.
    - ``control_latency`` (0 s, at most 1): observations are this old, interpolated
      between the physics steps' sensor readings as the classic reactive env did.
    - ``pd_latency`` (0 s, at most 1): the motors' PD loop sees angles and velocities
      this old (the motor's back-EMF still uses the true velocity); needs a motor model.
    - ``imu_noise_stdev`` (0 rad, at most 1): Gaussian noise on the IMU's roll, pitch and
      yaw (and rates).
    - ``imu_bias`` (0 rad, a number or one per axis, each within +-1): added to the IMU's
      angles. In the classic observation both reach the quaternion through the Euler
      angles.
    - ``pushes`` (None): ``True`` for Tan et al.'s pushes (130-220 N, horizontal, in a
      random direction, for 0.06 s every 1.2 s), or a :class:`Pushes` or mapping of its
      fields; the force of each step is ``info["push_force"]``.

    The env also takes each field as a keyword of its own (``control_latency=0.02``),
    as ``--env-kwargs`` and the zoo's ``env_kwargs.yml`` state them.
    """

    control_time_step: float = CLASSIC_CONTROL_STEP
    control_latency: float = 0.0
    pd_latency: float = 0.0
    imu_noise_stdev: float = 0.0
    imu_bias: float | Sequence[float] = (0.0, 0.0, 0.0)
    pushes: Pushes | Mapping[str, Any] | bool | None = None

    def __post_init__(self) -> None:
        checked = {
            "control_time_step": number(
                "control_time_step",
                self.control_time_step,
                MIN_CONTROL_STEP,
                MAX_CONTROL_STEP,
                unit="s",
            ),
            "control_latency": number(
                "control_latency", self.control_latency, 0, MAX_LATENCY, unit="s"
            ),
            "pd_latency": number("pd_latency", self.pd_latency, 0, MAX_LATENCY, unit="s"),
            "imu_noise_stdev": number(
                "imu_noise_stdev", self.imu_noise_stdev, 0, MAX_IMU_ERROR, unit="rad"
            ),
            "imu_bias": _imu_bias(self.imu_bias),
            "pushes": Pushes.coerce(self.pushes),
        }
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    @classmethod
    def coerce(cls, value: Realism | Mapping[str, Any] | None, **flat: Any) -> Realism:
        """From a Realism, a mapping of its fields or None, with the flat keywords the
        caller was given (None: not given) on top. A field set both ways to different
        values is refused rather than one silently winning."""
        if value is None:
            realism = cls()
        elif isinstance(value, cls):
            realism = value
        elif isinstance(value, Mapping):
            realism = from_mapping(cls, value)
        else:
            raise ValueError(f"realism must be a Realism or a mapping of its fields, got {value!r}")
        given = {name: setting for name, setting in flat.items() if setting is not None}
        if not given:
            return realism
        merged = dataclasses.replace(realism, **given)
        default = cls()
        for name in given:
            mine, theirs = getattr(realism, name), getattr(merged, name)
            if not _same(mine, getattr(default, name)) and not _same(mine, theirs):
                raise ValueError(
                    f"{name} is given twice, as {name}={flat[name]!r} and in realism "
                    f"({mine!r}); give it once"
                )
        return merged


def _same(a: Any, b: Any) -> bool:
    return bool(np.array_equal(a, b)) if isinstance(a, tuple) else a == b


def _imu_bias(value: Any) -> tuple[float, float, float]:
    values = [value] if np.ndim(value) == 0 else list(value) if np.ndim(value) == 1 else None
    if values is None or len(values) not in (1, 3):
        raise ValueError(f"imu_bias must be a number or three (rad), got {value!r}")
    checked = [number("imu_bias", v, -MAX_IMU_ERROR, MAX_IMU_ERROR, unit="rad") for v in values]
    return tuple(checked * 3 if len(checked) == 1 else checked)  # type: ignore[return-value]


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
