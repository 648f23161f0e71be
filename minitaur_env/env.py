"""The gymnasium environment: spaces, reset/step, reward, termination and rendering."""

from __future__ import annotations

import math
import time
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from minitaur_env.motor import OBSERVED_TORQUE_LIMIT, SPEED_LIMIT
from minitaur_env.randomization import DynamicsRanges, apply_dynamics, sample_dynamics
from minitaur_env.robot import (
    CLASSIC_OBSERVATION_BOUND,
    DEFAULT_GAINS,
    INIT_MOTOR_ANGLE,
    MOTOR_CONTROLS,
    NUM_MOTORS,
    OBSERVATION_SIZE,
    Minitaur,
    MotorControl,
    leg_model_to_motor_angles,
)
from minitaur_env.sim import DATA_PATH, BulletSim

CONTROL_TIME_STEP = 0.01  # s, one action at 100 Hz
SUBSTEPS = 5  # physics steps per control step with a simulated motor model
SOLVER_ITERATIONS = 300  # per control step; split over the substeps
GRAVITY = -10.0
SETTLE_STEPS = 100  # physics steps holding every motor at pi/2 before an episode
ACTION_TOLERANCE = 0.01  # the classic env accepts actions up to 1.01 in magnitude
FALL_UP_Z = 0.85  # the base's up axis must keep this world-z component
FALL_HEIGHT = 0.13  # m, minimum base height

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


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


class MinitaurBulletEnv(gym.Env[np.ndarray, np.ndarray]):
    """The Minitaur quadruped learning to run forward, as in PyBullet's classic env.

    A Ghost Robotics Minitaur (eight motors, two per leg, each leg a closed
    five-bar linkage) stands on a plane. The agent commands the legs at 100 Hz
    and is rewarded for the distance it makes along +x, minus the energy it
    spends. With the default arguments this is the classic
    ``pybullet_envs`` ``MinitaurBulletEnv-v0`` (same simulation, motor model,
    observation, reward and termination), made a seeded, float32 gymnasium env.

    ## Action space
    ``Box(-1, 1, (8,), float32)``, the leg model: ``a[i]`` (i < 4) extends leg i
    (front-left, back-left, front-right, back-right); ``a[4 + i]`` swings it.
    Motor ``m`` of leg ``i = m // 2`` is commanded to
    ``pi - pi/4 * (a[4+i] + 1.5) + s_m * pi/4 * a[i]`` with ``s_m = (-1)**m``, negated
    for the right legs. Entries up to 1.01 in magnitude are accepted (the classic
    tolerance); NaN, inf, a wrong shape or a larger entry raise ``ValueError``.

    ## Observation space
    ``Box((28,), float32)``; angles and velocities use the classic motor directions.

    | index | observation | unit | declared bound |
    |-------|-------------|------|----------------|
    | 0-7   | motor angles | rad | +-2 pi |
    | 8-15  | motor velocities | rad/s | +-2 x 167.7 |
    | 16-23 | motor torques as the motor model observes them | N m | +-5.71 |
    | 24-27 | base orientation quaternion (x, y, z, w) | | +-1.01 |

    With ``observation_noise_stdev > 0`` each entry gets ``N(0, stdev)`` times its
    classic bound (pi, 167.7, 5.7, 1) added.

    ## Reward
    Per step, ``reward = reward_forward + reward_energy + reward_drift + reward_shake``:

    - ``reward_forward = distance_weight * dx``, dx the base's x displacement (m);
    - ``reward_energy = -energy_weight * |torque . velocity| * dt_physics``;
    - ``reward_drift = -drift_weight * |dy|``; ``reward_shake = -shake_weight * |dz|``.

    As in the classic env the displacement of the first step is measured from
    the origin, not from the settled start pose. Each term is in ``info``.

    ## Starting state
    The robot is loaded at (0, 0, 0.2) with every motor at pi/2, the dynamics
    are re-drawn (``randomize_dynamics``), and every motor is held at pi/2 for 100
    physics steps before the first observation.

    ## Episode end
    ``terminated`` when the robot falls (the base's up axis has a world-z
    component below 0.85, or the base is lower than 0.13 m) or is farther than
    ``distance_limit`` from the origin in the xy plane. The registered ids
    truncate at 1000 steps (10 s).

    ## Info
    ``reward_forward``, ``reward_energy``, ``reward_drift``, ``reward_shake``,
    ``base_position`` (x, y, z in m), ``x_velocity`` (m/s, over the last step),
    ``motors_enabled`` (False where overheat protection switched a motor off).
    ``reset`` returns ``base_position`` and, with randomization, ``dynamics``.

    ## Arguments
    - ``render_mode``: None, "rgb_array" (frames from a camera following the
      robot, CPU renderer) or "human" (the PyBullet GUI, camera following).
    - ``randomize_dynamics`` (True): re-draw masses, battery voltage, motor
      damping and foot friction at every reset, within ``dynamics_ranges``.
    - ``dynamics_ranges``: a :class:`DynamicsRanges` (classic ranges by default).
    - ``distance_weight`` (1.0), ``energy_weight`` (0.005), ``drift_weight`` (0.0),
      ``shake_weight`` (0.0): reward weights; the last three must be >= 0.
    - ``distance_limit`` (inf): terminate beyond this xy distance (m).
    - ``observation_noise_stdev`` (0.0): relative Gaussian observation noise.
    - ``motor_control`` ("accurate"): "accurate" DC motor model with PD
      position control, "pd" ideal PD torques, or "position" PyBullet servos.
    - ``motor_kp``, ``motor_kd`` (None: 1.0/0.02, 8.0/0.3 or 1.0/1.0 by mode).
    - ``motor_overheat_protection`` (True), ``motor_velocity_limit`` (inf rad/s).
    - ``action_repeat`` (1): control steps of 0.01 s each action is held for.
    - ``self_collision`` (True), ``on_rack`` (False: True holds the base in the air).
    - ``hard_reset`` (True): rebuild the world at every reset (about 40 ms), as
      the classic env does. False builds it once and restores a saved state
      (under 0.1 ms with fixed dynamics; with randomized dynamics the robot must
      still settle on its new masses). Both are reproducible from the seed, and
      with fixed dynamics both give the same first observation; a fast reset then
      solves contacts in a sorted order, so its steps are not bit-identical to the
      classic env's (the parity tests use hard resets).
    - ``width``, ``height`` (640, 480), ``camera_distance`` (1.0 m),
      ``camera_yaw`` (0 deg), ``camera_pitch`` (-30 deg): the rgb_array camera.
    - ``urdf_root``: folder with ``plane.urdf`` and ``quadruped/minitaur.urdf``
      (``pybullet_data`` by default).

    ## Version history
    - v0: gymnasium port of pybullet_envs' MinitaurBulletEnv-v0 (pybullet 3.2.7):
      float32 observations inside declared bounds, seeded randomization and
      noise, terminated/truncated, rgb_array and human rendering.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 100}

    def __init__(
        self,
        render_mode: str | None = None,
        *,
        randomize_dynamics: bool = True,
        dynamics_ranges: DynamicsRanges | None = None,
        distance_weight: float = 1.0,
        energy_weight: float = 0.005,
        drift_weight: float = 0.0,
        shake_weight: float = 0.0,
        distance_limit: float = math.inf,
        observation_noise_stdev: float = 0.0,
        motor_control: MotorControl = "accurate",
        motor_kp: float | None = None,
        motor_kd: float | None = None,
        motor_overheat_protection: bool = True,
        motor_velocity_limit: float = math.inf,
        action_repeat: int = 1,
        self_collision: bool = True,
        on_rack: bool = False,
        hard_reset: bool = True,
        width: int = 640,
        height: int = 480,
        camera_distance: float = 1.0,
        camera_yaw: float = 0.0,
        camera_pitch: float = -30.0,
        urdf_root: str = DATA_PATH,
    ) -> None:
        _require(
            render_mode is None or render_mode in self.metadata["render_modes"],
            f"render_mode must be None or one of {self.metadata['render_modes']}, "
            f"got {render_mode!r}",
        )
        _require(
            motor_control in MOTOR_CONTROLS,
            f"motor_control must be one of {MOTOR_CONTROLS}, got {motor_control!r}",
        )
        _require(math.isfinite(distance_weight), "distance_weight must be finite")
        for name, weight in (
            ("energy_weight", energy_weight),
            ("drift_weight", drift_weight),
            ("shake_weight", shake_weight),
            ("observation_noise_stdev", observation_noise_stdev),
        ):
            _require(
                math.isfinite(weight) and weight >= 0,
                f"{name} must be finite and >= 0, got {weight}",
            )
        _require(distance_limit > 0, f"distance_limit must be > 0, got {distance_limit}")
        _require(
            motor_velocity_limit > 0,
            f"motor_velocity_limit must be > 0, got {motor_velocity_limit}",
        )
        _require(
            isinstance(action_repeat, int) and action_repeat >= 1,
            f"action_repeat must be an int >= 1, got {action_repeat!r}",
        )
        for name, size in (("width", width), ("height", height)):
            _require(
                isinstance(size, int) and 0 < size <= 4096,
                f"{name} must be an int in 1..4096, got {size!r}",
            )
        _require(camera_distance > 0, f"camera_distance must be > 0, got {camera_distance}")
        default_kp, default_kd = DEFAULT_GAINS[motor_control]
        self._kp = default_kp if motor_kp is None else motor_kp
        self._kd = default_kd if motor_kd is None else motor_kd
        _require(self._kp >= 0 and self._kd >= 0, "motor_kp and motor_kd must be >= 0")

        self.render_mode = render_mode
        self.randomize_dynamics = randomize_dynamics
        self.dynamics_ranges = dynamics_ranges or DynamicsRanges()
        self.distance_weight = distance_weight
        self.energy_weight = energy_weight
        self.drift_weight = drift_weight
        self.shake_weight = shake_weight
        self.distance_limit = distance_limit
        self.observation_noise_stdev = observation_noise_stdev
        self.motor_control = motor_control
        self.motor_overheat_protection = motor_overheat_protection
        self.motor_velocity_limit = motor_velocity_limit
        self.action_repeat = action_repeat
        self.self_collision = self_collision
        self.on_rack = on_rack
        self.hard_reset = hard_reset
        self.width = width
        self.height = height
        self.camera_distance = camera_distance
        self.camera_yaw = camera_yaw
        self.camera_pitch = camera_pitch
        self.urdf_root = urdf_root

        # A motor model needs small physics steps to stay stable; PyBullet's own
        # position servos run one physics step per control step.
        substeps = 1 if motor_control == "position" else SUBSTEPS
        self.physics_time_step = CONTROL_TIME_STEP / substeps
        self._solver_iterations = SOLVER_ITERATIONS // substeps
        self._physics_steps_per_action = substeps * action_repeat
        self.dt = CONTROL_TIME_STEP * action_repeat
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.dt)}

        self.action_space = spaces.Box(-1.0, 1.0, (NUM_MOTORS,), np.float32)
        self.observation_space = spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, dtype=np.float32)

        self._sim: BulletSim | None = BulletSim(gui=render_mode == "human")
        self._robot: Minitaur | None = None
        self._start_state: int | None = None
        self._settled_state: tuple[int, np.ndarray] | None = None
        self._last_base_position = np.zeros(3)
        self._previous_x = 0.0
        self._last_frame_time = 0.0

    # -- scene -------------------------------------------------------------------
    def _build_scene(self, sim: BulletSim) -> None:
        """Load the world; subclasses add bodies here."""
        self._plane = sim.load_plane()

    def _build_world(self) -> None:
        sim = self._live_sim()
        sim.reset_world(self.physics_time_step, self._solver_iterations, GRAVITY)
        self._build_scene(sim)
        self._robot = Minitaur(
            sim,
            self.physics_time_step,
            motor_control=self.motor_control,
            motor_kp=self._kp,
            motor_kd=self._kd,
            overheat_protection=self.motor_overheat_protection,
            motor_velocity_limit=self.motor_velocity_limit,
            self_collision=self.self_collision,
            on_rack=self.on_rack,
            urdf_root=self.urdf_root,
        )
        self._start_state = None
        self._settled_state = None
        if not self.hard_reset and self.randomize_dynamics:
            # Every episode restores this unsettled state and settles from it.
            sim.sort_contact_pairs()
            self._start_state = sim.save_state()

    @property
    def sim(self) -> BulletSim:
        """The physics client (for tools and tests that need to reach the world)."""
        return self._live_sim()

    @property
    def robot(self) -> Minitaur:
        """The robot of the current episode."""
        if self._robot is None:
            raise ResetNeeded("call reset() before using the robot")
        return self._robot

    def _live_sim(self) -> BulletSim:
        if self._sim is None:
            raise RuntimeError("the env is closed; make a new one")
        return self._sim

    # -- gymnasium API -----------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        sim = self._live_sim()
        if self._robot is None or self.hard_reset:
            self._build_world()
        elif self._start_state is not None:
            sim.restore_state(self._start_state)
        robot = self._robot
        assert robot is not None
        robot.reset_motor_state()

        info: dict[str, Any] = {}
        if self.randomize_dynamics:
            dynamics = sample_dynamics(robot, self.dynamics_ranges, self.np_random)
            apply_dynamics(robot, dynamics)
            info["dynamics"] = dynamics
            self._settle(robot)
        elif self.hard_reset:
            self._settle(robot)
        else:
            if self._settled_state is None:
                # Settle exactly as a hard reset does, so the first observation is
                # the classic one; sort contacts only for what follows.
                self._settle(robot)
                self._settled_state = (sim.save_state(), robot.observed_torques.copy())
                sim.sort_contact_pairs()
            state, torques = self._settled_state
            sim.restore_state(state)
            robot.observed_torques = torques.copy()

        if sim.gui:
            sim.follow_with_gui_camera(
                [0, 0, 0], self.camera_distance, self.camera_yaw, self.camera_pitch
            )
        position, _ = robot.base_pose()
        # The classic reward measures the first step's displacement from the origin.
        self._last_base_position = np.zeros(3)
        self._previous_x = position[0]
        info["base_position"] = np.array(position)
        return self._observation(robot.observation()), info

    def _settle(self, robot: Minitaur) -> None:
        sim = self._live_sim()
        hold = np.full(NUM_MOTORS, INIT_MOTOR_ANGLE)
        for _ in range(SETTLE_STEPS):
            if robot.motor_control != "position":
                robot.apply_motor_targets(hold)
            sim.step()

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        robot = self._robot
        if robot is None or self._sim is None:
            raise ResetNeeded("call reset() before step()")
        targets = leg_model_to_motor_angles(self._checked_action(action))
        sim = self._sim
        for _ in range(self._physics_steps_per_action):
            robot.apply_motor_targets(targets)
            sim.step()

        position, orientation = robot.base_pose()
        state = robot.observation()
        reward, info = self._reward(np.array(position), state)
        terminated = self._is_terminated(position, orientation)
        info["motors_enabled"] = robot.motors_enabled.copy()
        if self.render_mode == "human":
            self._show_in_gui(position)
        return self._observation(state), reward, terminated, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn(
                "render() called without a render_mode; "
                'make the env with render_mode="rgb_array" or "human"'
            )
            return None
        if self.render_mode == "human":
            return None
        if self._robot is None or self._sim is None:
            raise ResetNeeded("call reset() before render()")
        position, _ = self._robot.base_pose()
        return self._sim.render(
            position,
            self.width,
            self.height,
            self.camera_distance,
            self.camera_yaw,
            self.camera_pitch,
        )

    def close(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None
        self._robot = None

    # -- internals -------------------------------------------------------------
    def _checked_action(self, action: Any) -> np.ndarray:
        try:
            action = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise ValueError(f"action must be numeric, got {action!r}") from error
        if action.shape != (NUM_MOTORS,):
            raise ValueError(f"action must have shape ({NUM_MOTORS},), got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action must be finite, got {action.tolist()}")
        limit = 1.0 + ACTION_TOLERANCE
        if np.any(np.abs(action) > limit):
            worst = int(np.argmax(np.abs(action)))
            raise ValueError(
                f"action[{worst}] = {action[worst]} is outside [-1, 1] "
                f"(tolerance {ACTION_TOLERANCE})"
            )
        return action

    def _observation(self, state: np.ndarray) -> np.ndarray:
        if self.observation_noise_stdev > 0:
            state = state + (
                self.np_random.normal(scale=self.observation_noise_stdev, size=OBSERVATION_SIZE)
                * CLASSIC_OBSERVATION_BOUND
            )
        return state.astype(np.float32)

    def _reward(self, position: np.ndarray, state: np.ndarray) -> tuple[float, dict[str, Any]]:
        displacement = position - self._last_base_position
        self._last_base_position = position
        torques = state[2 * NUM_MOTORS : 3 * NUM_MOTORS]
        velocities = state[NUM_MOTORS : 2 * NUM_MOTORS]
        energy = abs(float(np.dot(torques, velocities))) * self.physics_time_step
        info: dict[str, Any] = {
            "reward_forward": self.distance_weight * float(displacement[0]),
            "reward_energy": -self.energy_weight * energy,
            "reward_drift": -self.drift_weight * abs(float(displacement[1])),
            "reward_shake": -self.shake_weight * abs(float(displacement[2])),
        }
        reward = (
            info["reward_forward"]
            + info["reward_energy"]
            + info["reward_drift"]
            + info["reward_shake"]
        )
        info["base_position"] = position
        info["x_velocity"] = (float(position[0]) - self._previous_x) / self.dt
        self._previous_x = float(position[0])
        return reward, info

    def has_fallen(self) -> bool:
        """True when the base tilts past the fall angle or sinks below the fall height."""
        if self._robot is None:
            raise ResetNeeded("call reset() before has_fallen()")
        position, orientation = self._robot.base_pose()
        return self._fallen(position, orientation)

    @staticmethod
    def _fallen(position: tuple[float, ...], orientation: tuple[float, ...]) -> bool:
        return BulletSim.up_axis_z(orientation) < FALL_UP_Z or position[2] < FALL_HEIGHT

    def _is_terminated(self, position: tuple[float, ...], orientation: tuple[float, ...]) -> bool:
        return self._fallen(position, orientation) or math.hypot(position[0], position[1]) > (
            self.distance_limit
        )

    def _show_in_gui(self, position: tuple[float, ...]) -> None:
        sim = self._live_sim()
        sim.follow_with_gui_camera(
            position, self.camera_distance, self.camera_yaw, self.camera_pitch
        )
        # Pace the GUI at real time; a faster loop would look like fast-forward.
        delay = self.dt - (time.perf_counter() - self._last_frame_time)
        if delay > 0:
            time.sleep(delay)
        self._last_frame_time = time.perf_counter()


class MinitaurBulletDuckEnv(MinitaurBulletEnv):
    """`MinitaurBulletEnv` with a rubber duck riding on the robot's back.

    The episode also terminates when the duck touches the ground. All arguments
    are those of `MinitaurBulletEnv`.
    """

    DUCK_POSITION = (0.0, 0.0, 0.25)
    DUCK_ORIENTATION = (0.5, 0.5, 0.5, 0.5)

    def _build_scene(self, sim: BulletSim) -> None:
        super()._build_scene(sim)
        self._duck = sim.load_urdf(
            "duck_vhacd.urdf", self.DUCK_POSITION, self.DUCK_ORIENTATION, urdf_root=self.urdf_root
        )

    def lost_duck(self) -> bool:
        return self._live_sim().has_contact(self._duck, self._plane)

    def _is_terminated(self, position: tuple[float, ...], orientation: tuple[float, ...]) -> bool:
        return self.lost_duck() or super()._is_terminated(position, orientation)
