"""The Minitaur's DC motor model: PD position command -> PWM -> current -> torque.

A plain-numpy model of the classic ``pybullet_envs.bullet.motor`` behaviour: a PD law
produces a PWM duty cycle, the battery voltage minus back-EMF drives a current through
the winding, and an empirical current-to-torque table saturates the output.
"""

from __future__ import annotations

import numpy as np

NOMINAL_VOLTAGE = 16.0  # V
RESISTANCE = 0.186  # Ohm
TORQUE_CONSTANT = 0.0954  # N m / A, also V s / rad of back-EMF
VOLTAGE_CLIPPING = 50.0  # V; diodes on the motor controller clip the net voltage
OBSERVED_TORQUE_LIMIT = 5.7  # N m, what the torque sensor can report
SPEED_LIMIT = NOMINAL_VOLTAGE / TORQUE_CONSTANT  # rad/s, no-load speed at nominal voltage

_CURRENT_TABLE = np.array([0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0])  # A
_TORQUE_TABLE = np.array([0.0, 1.0, 1.9, 2.45, 3.0, 3.25, 3.5])  # N m
SATURATION_CURRENT = float(_CURRENT_TABLE[-1])  # A: the torque is at its limit from here


class MotorModel:
    """Torques of all motors from position commands and the measured joint state.

    Args:
        kp: proportional gain from angle error (rad) to PWM.
        kd: derivative gain from joint velocity (rad/s) to PWM.
        voltage: battery voltage (V); randomized per episode by the env.
        viscous_damping: extra back-EMF-like damping (N m s / rad).
    """

    def __init__(
        self,
        kp: float = 1.0,
        kd: float = 0.02,
        voltage: float = NOMINAL_VOLTAGE,
        viscous_damping: float = 0.0,
    ) -> None:
        self.kp = kp
        self.kd = kd
        self.voltage = voltage
        self.viscous_damping = viscous_damping
        # The winding current of the last call (A): beyond the table's last entry the
        # torque stops growing (benchmarks/realism.py counts the steps it spends there).
        self.last_current = np.zeros(0)

    def torques(
        self,
        targets: np.ndarray,
        angles: np.ndarray,
        velocities: np.ndarray,
        true_velocities: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(actual torque applied to the joints, torque the sensor observes).

        ``angles`` and ``velocities`` are what the PD loop sees (late under PD latency);
        the back-EMF and damping use ``true_velocities`` (by default ``velocities``).
        """
        if true_velocities is None:
            true_velocities = velocities
        # np.minimum/np.maximum: the same values as np.clip at a fraction of its cost on
        # eight entries, and this runs five times per env step.
        pwm = -self.kp * (angles - targets) - self.kd * velocities
        pwm = np.minimum(np.maximum(pwm, -1.0), 1.0)
        observed = np.minimum(
            np.maximum(TORQUE_CONSTANT * (pwm * self.voltage / RESISTANCE), -OBSERVED_TORQUE_LIMIT),
            OBSERVED_TORQUE_LIMIT,
        )
        net_voltage = np.minimum(
            np.maximum(
                pwm * self.voltage - (TORQUE_CONSTANT + self.viscous_damping) * true_velocities,
                -VOLTAGE_CLIPPING,
            ),
            VOLTAGE_CLIPPING,
        )
        current = self.last_current = net_voltage / RESISTANCE
        actual = np.sign(current) * np.interp(np.abs(current), _CURRENT_TABLE, _TORQUE_TABLE)
        return actual, observed
