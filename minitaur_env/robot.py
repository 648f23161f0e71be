"""The Minitaur robot: its URDF, joints, leg model, motors and sensors.

Joints and links are looked up by name in the URDF, never by hard-coded index.
Motor order, directions and the leg model follow the classic
``pybullet_envs.bullet.minitaur`` so observations and actions mean the same thing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np

from minitaur_env.motor import OBSERVED_TORQUE_LIMIT, SPEED_LIMIT, MotorModel
from minitaur_env.sim import DATA_PATH, BulletSim

MotorControl = Literal["accurate", "pd", "position"]
MOTOR_CONTROLS: tuple[str, ...] = ("accurate", "pd", "position")

NUM_MOTORS = 8
NUM_LEGS = 4
LEG_NAMES = ("front_left", "back_left", "front_right", "back_right")
# Motor i belongs to leg i // 2; each leg has an "L" and an "R" motor.
MOTOR_JOINT_NAMES = tuple(f"motor_{leg}{side}_joint" for leg in LEG_NAMES for side in "LR")
KNEE_JOINT_NAMES = tuple(f"knee_{leg}{side}_link" for leg in LEG_NAMES for side in "LR")
# The left legs' motors turn the other way round: observations and commands are
# expressed with the same sign on both sides.
MOTOR_DIRECTIONS = np.array([-1.0, -1.0, -1.0, -1.0, 1.0, 1.0, 1.0, 1.0])

INIT_POSITION = (0.0, 0.0, 0.2)
INIT_ORIENTATION = (0.0, 0.0, 0.0, 1.0)
INIT_MOTOR_ANGLE = math.pi / 2
INIT_KNEE_ANGLE = -2.1834
KNEE_PIVOT_RIGHT = (0.0, 0.005, 0.2)
KNEE_PIVOT_LEFT = (0.0, 0.01, 0.2)

OVERHEAT_SHUTDOWN_TORQUE = 2.45  # N m
OVERHEAT_SHUTDOWN_TIME = 1.0  # s
POSITION_SERVO_MAX_FORCE = 3.5  # N m, PyBullet's own servo in "position" control

# Gains per motor-control mode when the user does not give them (the classic values).
DEFAULT_GAINS: dict[str, tuple[float, float]] = {
    "accurate": (1.0, 0.02),
    "pd": (8.0, 0.3),
    "position": (1.0, 1.0),
}

# Observation layout: [angles | velocities | torques | base quaternion].
OBSERVATION_SIZE = 3 * NUM_MOTORS + 4
CLASSIC_OBSERVATION_BOUND = np.concatenate(
    [
        np.full(NUM_MOTORS, math.pi),
        np.full(NUM_MOTORS, SPEED_LIMIT),
        np.full(NUM_MOTORS, OBSERVED_TORQUE_LIMIT),
        np.ones(4),
    ]
)


_MOTOR_LEG = np.arange(NUM_MOTORS) // 2
# (-1)**m for the left legs' motors, negated for the right legs' (m >= 4).
_EXTENSION_SIGN = np.array([1.0, -1.0, 1.0, -1.0, -1.0, 1.0, -1.0, 1.0])


def leg_model_to_motor_angles(action: np.ndarray) -> np.ndarray:
    """Motor angle targets from leg-model actions (``ConvertFromLegModel``).

    ``action[0:4]`` extends leg ``i`` (its two motors move apart), ``action[4:8]``
    swings it (both motors move together). Zero maps to 5*pi/8 for every motor.
    """
    swing = -(math.pi / 4) * (action[NUM_LEGS + _MOTOR_LEG] + 1.5)
    extension = _EXTENSION_SIGN * (math.pi / 4) * action[_MOTOR_LEG]
    return math.pi + swing + extension


# Left-right mirror images. The legs swap sides (front-left with front-right, back-left
# with back-right) and, seen in the mirror, a leg's "L" motor is the other leg's "R"
# motor: motor m's mirror is _MIRROR_MOTOR[m]. Leg-model entries keep their sign (a
# mirrored leg extends and swings as the original), and the base's roll and yaw change
# sign, pitch does not. The robot is symmetric only up to its knee pivots (5 and 10 mm
# off its axis) and the classic randomization: over 50 steps of an action sequence and
# of its mirror from the same reset, the motor angles stay within 0.06 rad of each
# other's mirror while they move by 0.78 (tests/test_env.py).
_MIRROR_MOTOR = np.array([5, 4, 7, 6, 1, 0, 3, 2])
_MIRROR_LEG = np.array([2, 3, 0, 1])
_MIRROR_OBSERVATION = np.concatenate(
    [
        _MIRROR_MOTOR,
        NUM_MOTORS + _MIRROR_MOTOR,
        2 * NUM_MOTORS + _MIRROR_MOTOR,
        3 * NUM_MOTORS + np.arange(4),
    ]
)
_MIRROR_OBSERVATION_SIGN = np.concatenate([np.ones(24), [-1.0, 1.0, -1.0, 1.0]])


def mirror_observation(observation: np.ndarray) -> np.ndarray:
    """The classic observation (last axis of 28: angles, velocities, torques, quaternion
    x y z w) of the left-right mirror image of the robot."""
    return observation[..., _MIRROR_OBSERVATION] * _MIRROR_OBSERVATION_SIGN.astype(
        observation.dtype
    )


def mirror_leg_action(action: np.ndarray) -> np.ndarray:
    """The leg-model action (last axis of 8: extensions, then swings, of the four legs)
    that makes the mirror image of the robot do what ``action`` makes it do."""
    return action[..., np.concatenate([_MIRROR_LEG, NUM_LEGS + _MIRROR_LEG])]


class Minitaur:
    """One Minitaur in a `BulletSim`: loading, posing, actuation and sensing.

    Args:
        sim: the simulator the robot lives in.
        time_step: the physics step (s); the overheat timer counts in it.
        motor_control: "accurate" (DC motor model, the classic default), "pd"
            (ideal PD torques) or "position" (PyBullet's position servos).
        motor_kp, motor_kd: gains of the chosen control mode.
        overheat_protection: switch a motor off for the episode after it has
            exceeded 2.45 N m for more than 1 s ("accurate" control only).
        motor_velocity_limit: clip targets to this speed (rad/s) per step.
        self_collision: let the legs collide with each other and the body.
        on_rack: hold the base fixed in the air (for looking at a gait).
        urdf_root: folder holding ``quadruped/minitaur.urdf``.
    """

    def __init__(
        self,
        sim: BulletSim,
        time_step: float,
        motor_control: MotorControl = "accurate",
        motor_kp: float = 1.0,
        motor_kd: float = 0.02,
        overheat_protection: bool = True,
        motor_velocity_limit: float = math.inf,
        self_collision: bool = True,
        on_rack: bool = False,
        urdf_root: str = DATA_PATH,
    ) -> None:
        self._sim = sim
        self.time_step = time_step
        self.motor_control = motor_control
        self.kp = motor_kp
        self.kd = motor_kd
        self.overheat_protection = overheat_protection and motor_control == "accurate"
        self.motor_velocity_limit = motor_velocity_limit
        self.motor_model = MotorModel(kp=motor_kp, kd=motor_kd)

        self.body = sim.load_urdf(
            "quadruped/minitaur.urdf",
            INIT_POSITION,
            INIT_ORIENTATION,
            self_collision=self_collision,
            urdf_root=urdf_root,
        )
        joints = sim.joint_names(self.body)
        joint_index = {name: i for i, (name, _) in enumerate(joints)}
        self.motor_joints = [joint_index[name] for name in MOTOR_JOINT_NAMES]
        self.knee_joints = [joint_index[name] for name in KNEE_JOINT_NAMES]
        # Links by role, from the child link names of the URDF.
        self.leg_links = [
            i for i, (_, link) in enumerate(joints) if link.startswith(("upper_leg", "lower_leg"))
        ]
        self.motor_links = list(self.motor_joints)
        self.foot_links = [i for i, (_, link) in enumerate(joints) if link.startswith("lower_leg")]
        self.base_mass_urdf = sim.mass(self.body, -1)
        self.leg_mass_urdf = sim.mass(self.body, self.leg_links[0])
        self.motor_mass_urdf = sim.mass(self.body, self.motor_links[0])
        self._inertias_urdf = {
            link: sim.inertia(self.body, link) for link in [-1, *self.leg_links, *self.motor_links]
        }

        self._set_initial_pose()
        for right, left in zip(self.knee_joints[1::2], self.knee_joints[0::2], strict=True):
            sim.add_point_constraint(self.body, right, left, KNEE_PIVOT_RIGHT, KNEE_PIVOT_LEFT)
        if motor_control == "position":
            sim.free_joints(self.body, self.knee_joints)
            self._hold_initial_pose_with_servos()
        else:
            sim.free_joints(self.body, self.motor_joints + self.knee_joints)
        if on_rack:
            sim.fix_base_in_air(self.body, height=1.0)
        self.reset_motor_state()

    # -- resetting -----------------------------------------------------------
    def _set_initial_pose(self) -> None:
        for motor, knee, direction in zip(
            self.motor_joints, self.knee_joints, MOTOR_DIRECTIONS, strict=True
        ):
            self._sim.reset_joint(self.body, motor, direction * INIT_MOTOR_ANGLE)
            self._sim.reset_joint(self.body, knee, direction * INIT_KNEE_ANGLE)

    def _hold_initial_pose_with_servos(self) -> None:
        targets = MOTOR_DIRECTIONS * INIT_MOTOR_ANGLE
        self._sim.set_position_targets(
            self.body, self.motor_joints, targets, self.kp, self.kd, POSITION_SERVO_MAX_FORCE
        )

    def reset_motor_state(self) -> None:
        """Forget torques, overheat timers and shut-down motors (start of an episode)."""
        self.observed_torques = np.zeros(NUM_MOTORS)
        self.overheat_steps = np.zeros(NUM_MOTORS, dtype=np.int64)
        self.motors_enabled = np.ones(NUM_MOTORS, dtype=bool)
        self.motor_strength = np.ones(NUM_MOTORS)

    # -- actuation -------------------------------------------------------------
    def apply_motor_targets(
        self, targets: np.ndarray, pd_state: tuple[np.ndarray, np.ndarray] | None = None
    ) -> None:
        """Command motor angles (observation convention) for the next physics step.

        ``pd_state``: the (angles, velocities) the PD loop sees, when they lag the true
        state (``pd_latency``); the motor's back-EMF always uses the true velocity.
        """
        if self.motor_control == "position":
            self._apply_position_servo(targets)
            return
        angles, velocities = self.motor_angles_velocities()
        if self.motor_velocity_limit < math.inf:
            reach = self.time_step * self.motor_velocity_limit
            targets = np.minimum(np.maximum(targets, angles - reach), angles + reach)
        seen_angles, seen_velocities = pd_state if pd_state is not None else (angles, velocities)
        if self.motor_control == "accurate":
            torques, self.observed_torques = self.motor_model.torques(
                targets, seen_angles, seen_velocities, velocities
            )
            torques = torques * self.motor_strength
            if self.overheat_protection:
                self._update_overheat(torques)
                torques = np.where(self.motors_enabled, torques, 0.0)
        else:
            torques = -self.kp * (seen_angles - targets) - self.kd * seen_velocities
            self.observed_torques = torques
            torques = torques * self.motor_strength
        self._sim.set_torques(self.body, self.motor_joints, torques * MOTOR_DIRECTIONS)

    def _apply_position_servo(self, targets: np.ndarray) -> None:
        if self.motor_velocity_limit < math.inf:
            angles, _ = self.motor_angles_velocities()
            reach = self.time_step * self.motor_velocity_limit
            targets = np.clip(targets, angles - reach, angles + reach)
        self._sim.set_position_targets(
            self.body,
            self.motor_joints,
            targets * MOTOR_DIRECTIONS,
            self.kp,
            self.kd,
            POSITION_SERVO_MAX_FORCE,
        )

    def _update_overheat(self, torques: np.ndarray) -> None:
        hot = np.abs(torques) > OVERHEAT_SHUTDOWN_TORQUE
        self.overheat_steps = np.where(hot, self.overheat_steps + 1, 0)
        self.motors_enabled &= self.overheat_steps <= OVERHEAT_SHUTDOWN_TIME / self.time_step

    # -- sensing -------------------------------------------------------------
    def motor_angles_velocities(self) -> tuple[np.ndarray, np.ndarray]:
        angles, velocities = self._sim.joint_positions_velocities(self.body, self.motor_joints)
        return angles * MOTOR_DIRECTIONS, velocities * MOTOR_DIRECTIONS

    def motor_torques(self) -> np.ndarray:
        """Torques as the motor model observes them (the joint's in "position" control)."""
        if self.motor_control == "position":
            return self._sim.joint_torques(self.body, self.motor_joints) * MOTOR_DIRECTIONS
        return self.observed_torques

    def base_pose(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        return self._sim.base_pose(self.body)

    def observation(self) -> np.ndarray:
        """[motor angles, motor velocities, motor torques, base quaternion] (28, float64)."""
        angles, velocities = self.motor_angles_velocities()
        _, orientation = self.base_pose()
        return np.concatenate([angles, velocities, self.motor_torques(), orientation])

    def sensor_reading(self) -> np.ndarray:
        """:meth:`observation` plus the base's angular velocity in the base frame (31)."""
        reading = self.observation()
        rates = world_to_base(reading[-4:], self._sim.base_angular_velocity(self.body))
        return np.concatenate([reading, rates])

    # -- dynamics parameters -----------------------------------------------------
    def set_base_mass(self, mass: float) -> None:
        self._sim.set_mass(self.body, -1, mass)

    def set_leg_masses(self, leg_mass: float, motor_mass: float) -> None:
        """Every upper and lower leg link gets ``leg_mass``; every motor ``motor_mass``."""
        for link in self.leg_links:
            self._sim.set_mass(self.body, link, leg_mass)
        for link in self.motor_links:
            self._sim.set_mass(self.body, link, motor_mass)

    def set_foot_friction(self, friction: float) -> None:
        for link in self.foot_links:
            self._sim.set_lateral_friction(self.body, link, friction)

    def set_battery_voltage(self, voltage: float) -> None:
        self.motor_model.voltage = voltage

    def set_motor_viscous_damping(self, damping: float) -> None:
        self.motor_model.viscous_damping = damping

    def scale_inertias(self, base_scale: float, leg_scale: float) -> None:
        """The base's URDF inertia times ``base_scale``; every leg link's and motor's times
        ``leg_scale``."""
        for link, diagonal in self._inertias_urdf.items():
            scale = base_scale if link == -1 else leg_scale
            self._sim.set_inertia(self.body, link, [scale * value for value in diagonal])

    def set_motor_strength(self, ratios: Sequence[float]) -> None:
        """Factors on each motor's output torque (what the sensor reports is unchanged)."""
        self.motor_strength = np.asarray(ratios, dtype=float)

    def set_joint_friction(self, frictions: Sequence[float]) -> None:
        """Coulomb friction torque (N m) of each knee joint."""
        if self.motor_control == "position":
            return  # the knees are free there too, but only the motor model reads them
        self._sim.set_joint_friction(self.body, self.knee_joints, frictions)


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
