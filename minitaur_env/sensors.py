"""What the robot's sensors report: delayed readings, and the IMU's angles and rates.

A :class:`SensorHistory` keeps the true sensor reading of every physics step, so the
controller (``control_latency``) and the motors' PD loop (``pd_latency``) can read the
state as it was some milliseconds ago, interpolated between physics steps as the
classic ``minitaur_reactive_env`` does.
"""

from __future__ import annotations

import collections
import math

import numpy as np

from minitaur_env.robot import NUM_MOTORS

# A reading: [angles (8) | velocities (8) | observed torques (8) | quaternion xyzw (4) |
# base angular velocity in the base frame (3)].
ANGLES = slice(0, NUM_MOTORS)
VELOCITIES = slice(NUM_MOTORS, 2 * NUM_MOTORS)
QUATERNION = slice(3 * NUM_MOTORS, 3 * NUM_MOTORS + 4)
BASE_RATES = slice(3 * NUM_MOTORS + 4, 3 * NUM_MOTORS + 7)
READING_SIZE = 3 * NUM_MOTORS + 7


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


def world_to_base(quaternion: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """``vector`` (world frame) expressed in the frame of the body oriented by ``quaternion``:
    what a gyroscope on the base reads for the base's angular velocity."""
    x, y, z, w = quaternion / np.linalg.norm(quaternion)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    return rotation.T @ vector
