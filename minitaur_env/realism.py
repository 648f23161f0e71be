"""Could the real robot do it? Motor limits and foot slip of a gait, step by step.

A simulated gait can lean on what the hardware cannot give: motors held at their torque
ceiling, run near their no-load speed, or feet that skid instead of pushing. The
:class:`RealismProbe` wrapper reports, after every step:

- ``motors_at_torque_limit``: motors whose winding current is at or beyond the motor
  model's last table entry (60 A), where the torque stops growing (3.5 N m times the
  motor's strength);
- ``motors_at_velocity_limit``: motors turning at 90 % or more of their no-load speed
  at this episode's battery voltage (voltage / torque constant), where back-EMF leaves
  almost no torque;
- ``foot_slip``: the mean horizontal speed (m/s) of the lower legs' points in contact
  with the ground, NaN when none touches it;
- ``actions_at_limit``: the share of the step's 8 actions, as the leg model takes them
  (behind a gait prior, the motor actions, not the policy's), within 5 % of the range's
  ends: bang-bang use of the swing and extension ranges.

Motor figures are sampled at the last physics step of each control step. The probe
costs a contact query and a few link states per step, so it is opt-in
(``evaluate.py --realism``); the env itself never computes them.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from minitaur_env.motor import SATURATION_CURRENT, TORQUE_CONSTANT

VELOCITY_LIMIT_SHARE = 0.9  # of the no-load speed
ACTION_LIMIT_SHARE = 0.95  # of the action range's half-width


class RealismProbe(gym.Wrapper):
    """Adds motor-limit counts and foot slip to ``info`` at every step (see the module)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        if getattr(env.unwrapped, "motor_control", None) != "accurate":
            raise ValueError(
                "the realism probe needs the DC motor model (motor_control='accurate'), "
                f"got {getattr(env.unwrapped, 'motor_control', None)!r}"
            )

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        info.update(measure(self.env.unwrapped))
        return observation, reward, terminated, truncated, info


def measure(env: Any) -> dict[str, float]:
    """The motor-limit counts and the foot slip of ``env`` (a ``MinitaurBulletEnv``) now."""
    robot, sim = env.robot, env.sim
    model = robot.motor_model
    _, velocities = robot.motor_angles_velocities()
    no_load_speed = model.voltage / TORQUE_CONSTANT
    slips = [
        float(np.hypot(*sim.point_velocity(robot.body, link, point)[:2]))
        for link, point in sim.contact_points(robot.body, env.ground)
        if link in robot.foot_links
    ]
    return {
        "motors_at_torque_limit": float(np.sum(np.abs(model.last_current) >= SATURATION_CURRENT)),
        "motors_at_velocity_limit": float(
            np.sum(np.abs(velocities) >= VELOCITY_LIMIT_SHARE * no_load_speed)
        ),
        "foot_slip": float(np.mean(slips)) if slips else float("nan"),
        # The motor-level action the leg model took: behind a gait prior, not the policy's.
        "actions_at_limit": float(np.mean(np.abs(env.commanded_action) >= ACTION_LIMIT_SHARE)),
    }
