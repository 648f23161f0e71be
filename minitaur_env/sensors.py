"""What the robot's sensors report: delayed readings, and the IMU's angles and rates.

A :class:`SensorHistory` keeps the true sensor reading of every physics step, so the
controller (``control_latency``) and the motors' PD loop (``pd_latency``) can read the
state as it was some milliseconds ago, interpolated between physics steps as the
classic ``minitaur_reactive_env`` does.
"""

from __future__ import annotations

import collections
import math
from typing import Literal

import numpy as np

from minitaur_env.motor import OBSERVED_TORQUE_LIMIT, SPEED_LIMIT
from minitaur_env.robot import CLASSIC_OBSERVATION_BOUND, NUM_MOTORS, OBSERVATION_SIZE

# A reading: [angles (8) | velocities (8) | observed torques (8) | quaternion xyzw (4) |
# base angular velocity in the base frame (3)].
ANGLES = slice(0, NUM_MOTORS)
VELOCITIES = slice(NUM_MOTORS, 2 * NUM_MOTORS)
QUATERNION = slice(3 * NUM_MOTORS, 3 * NUM_MOTORS + 4)
BASE_RATES = slice(3 * NUM_MOTORS + 4, 3 * NUM_MOTORS + 7)

# Declared observation bounds. The classic bounds (pi, the nominal no-load speed, the
# torque sensor's limit, 1) plus 0.01 do not contain what the robot does: the motor
# angles of the recorded classic trajectories reach 3.94 rad, and with a 16.8 V
# battery or an impact the motor speed passes the nominal no-load speed. Angles get a
# full turn each way and speeds twice the nominal no-load speed; torques and the
# quaternion are clipped by construction.
OBSERVATION_BOUND = np.concatenate(
    [
        np.full(NUM_MOTORS, 2 * math.pi),
        np.full(NUM_MOTORS, 2 * SPEED_LIMIT),
        np.full(NUM_MOTORS, OBSERVED_TORQUE_LIMIT + 0.01),
        np.full(4, 1.01),
    ]
).astype(np.float32)

# observation="imu": motor angles, then roll, pitch and their rates from the IMU, as the
# real robot's SAC policy saw them (Haarnoja et al. 2018). The rates are clipped where a
# MEMS gyroscope saturates (2000 deg/s).
GYRO_LIMIT = math.radians(2000.0)  # rad/s
IMU_OBSERVATION_BOUND = np.concatenate(
    [np.full(NUM_MOTORS, 2 * math.pi), np.full(2, math.pi), np.full(2, GYRO_LIMIT)]
).astype(np.float32)
Observation = Literal["classic", "imu"]
OBSERVATIONS: tuple[str, ...] = ("classic", "imu")


class SensorHistory:
    """Readings of the last physics steps, newest first, for delays up to ``max_delay``."""

    def __init__(self, physics_time_step: float, max_delay: float) -> None:
        self.physics_time_step = physics_time_step
        self._readings: collections.deque[np.ndarray] = collections.deque(
            maxlen=int(max_delay / physics_time_step) + 2
        )

    def clear(self) -> None:
        self._readings.clear()

    def append(self, reading: np.ndarray) -> None:
        self._readings.appendleft(reading)

    def delayed(self, delay: float) -> np.ndarray:
        """The reading of ``delay`` seconds ago, linearly interpolated between physics steps
        (the oldest one while the episode is younger than the delay)."""
        readings = self._readings
        if delay <= 0 or len(readings) == 1:
            return readings[0]
        steps_ago = int(delay / self.physics_time_step + 1e-9)
        if steps_ago + 1 >= len(readings):
            return readings[-1]
        blend = delay / self.physics_time_step - steps_ago
        if blend < 1e-9:
            return readings[steps_ago]
        return (1.0 - blend) * readings[steps_ago] + blend * readings[steps_ago + 1]


def quaternion_to_euler(quaternion: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of an xyzw quaternion, in PyBullet's (extrinsic xyz) convention."""
    x, y, z, w = quaternion / np.linalg.norm(quaternion)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


def euler_to_quaternion(euler: np.ndarray) -> np.ndarray:
    """The xyzw quaternion of (roll, pitch, yaw); the inverse of :func:`quaternion_to_euler`."""
    cr, sr = math.cos(euler[0] / 2), math.sin(euler[0] / 2)
    cp, sp = math.cos(euler[1] / 2), math.sin(euler[1] / 2)
    cy, sy = math.cos(euler[2] / 2), math.sin(euler[2] / 2)
    return np.array(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


def observe(
    reading: np.ndarray,
    observation: Observation,
    rng: np.random.Generator,
    noise_stdev: float,
    imu_noise_stdev: float,
    imu_bias: np.ndarray,
) -> np.ndarray:
    """The observation of a sensor reading: IMU errors, then the relative noise.

    ``noise_stdev`` is relative to the classic bounds (to pi for the "imu" observation's
    motor angles); the draws come from ``rng`` in a fixed order, so a seed fixes them.
    A noisy reading saturates at the observation space's bounds, as a sensor's range does:
    the classic env let noise carry observations outside its own space (a torque at its
    limit plus noise), which a policy or a space check then sees as impossible input.
    """

    def imu_errors(euler: np.ndarray, rates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if imu_noise_stdev > 0:
            euler = euler + rng.normal(scale=imu_noise_stdev, size=3)
            rates = rates + rng.normal(scale=imu_noise_stdev, size=3)
        return euler + imu_bias, rates

    with_imu_errors = imu_noise_stdev > 0 or imu_bias.any()
    if observation == "imu":
        angles = reading[ANGLES]
        if noise_stdev > 0:
            angles = angles + rng.normal(scale=noise_stdev * math.pi, size=NUM_MOTORS)
        euler = quaternion_to_euler(reading[QUATERNION])
        rates = reading[BASE_RATES]
        if with_imu_errors:
            euler, rates = imu_errors(euler, rates)
        rates = np.clip(rates, -GYRO_LIMIT, GYRO_LIMIT)
        observed = np.concatenate([angles, euler[:2], rates[:2]])
        if noise_stdev > 0 or with_imu_errors:
            observed = np.clip(observed, -IMU_OBSERVATION_BOUND, IMU_OBSERVATION_BOUND)
        return observed.astype(np.float32)
    state = reading[:OBSERVATION_SIZE]
    if with_imu_errors:
        euler, _ = imu_errors(quaternion_to_euler(state[QUATERNION]), np.zeros(3))
        state = np.concatenate([state[: 3 * NUM_MOTORS], euler_to_quaternion(euler)])
    if noise_stdev > 0:
        state = state + (
            rng.normal(scale=noise_stdev, size=OBSERVATION_SIZE) * CLASSIC_OBSERVATION_BOUND
        )
    if noise_stdev > 0 or with_imu_errors:
        state = np.clip(state, -OBSERVATION_BOUND, OBSERVATION_BOUND)
    return state.astype(np.float32)
