"""The gymnasium environment: spaces, reset/step, reward, termination and rendering."""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.wrappers import FlattenObservation, FrameStackObservation

from minitaur_env.checks import boolean, checked_action, choice, integer, number
from minitaur_env.randomization import DynamicsRanges, Pushes, apply_dynamics, sample_dynamics
from minitaur_env.robot import (
    DEFAULT_GAINS,
    INIT_MOTOR_ANGLE,
    MOTOR_CONTROLS,
    NUM_MOTORS,
    Minitaur,
    MotorControl,
    leg_model_to_motor_angles,
)
from minitaur_env.sensors import (
    ANGLES,
    IMU_OBSERVATION_BOUND,
    OBSERVATION_BOUND,
    OBSERVATIONS,
    VELOCITIES,
    Observation,
    SensorHistory,
    observe,
    quaternion_to_euler,
)
from minitaur_env.settings import (
    CLASSIC_CONTROL_STEP,
    DRAW_ORDER,
    Camera,
    EpisodeRealism,
    Realism,
    RewardWeights,
    Uniform,
    merge_realism,
    preset_settings,
)
from minitaur_env.sim import DATA_PATH, BulletSim

SUBSTEPS = 5  # physics steps per control step with a simulated motor model
SOLVER_ITERATIONS = 300  # per control step; split over the substeps
GRAVITY = -10.0
MAX_HISTORY = 16  # observations a policy may see at once (the ``history`` argument)
SETTLE_STEPS = 100  # physics steps holding every motor at pi/2 before an episode
FALL_UP_Z = 0.85  # the base's up axis must keep this world-z component
FALL_HEIGHT = 0.13  # m, minimum base height


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
    classic bound (pi, 167.7, 5.7, 1) added, and saturates at the space's bounds (the
    classic env let noisy observations leave its own space).

    With ``observation="imu"``, ``Box((12,), float32)``: the motor angles (0-7, rad,
    +-2 pi), the base's roll and pitch (8-9, rad, +-pi) and its roll and pitch rates in
    the base frame (10-11, rad/s, clipped at a gyroscope's +-2000 deg/s): what the real
    robot senses (Haarnoja et al. 2018). ``observation_noise_stdev`` then applies to the
    motor angles (times pi) and ``imu_noise_stdev`` to the rest.

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
    ``reset`` returns ``base_position``, with randomization ``dynamics`` (the physical
    parameters drawn) and, when a realism field is a range, ``realism`` (the episode's
    control step, latencies and IMU errors).

    ## Arguments
    - ``render_mode``: None, "rgb_array" (frames from a camera following the
      robot, CPU renderer) or "human" (the PyBullet GUI, camera following).
    - ``preset`` (None): "tan2018" starts ``dynamics_ranges`` and ``realism`` from Tan et
      al. 2018's Table I with a 3 ms PD latency (the Randomized ids' setting); what is
      given for either is set on top of it, field by field.
    - ``randomize_dynamics`` (True): re-draw masses, battery voltage, motor
      damping and foot friction at every reset, within ``dynamics_ranges``.
    - ``dynamics_ranges``: a :class:`DynamicsRanges`, a mapping of its fields (set on
      top of the classic ranges or the preset's), "classic" or "tan2018".
      Bools must be bools, and every number is checked against a physical range; an
      error names the argument, the value and the range.
    - ``observation`` ("classic"): "classic" or "imu" (above).
    - ``distance_weight`` (1.0), ``energy_weight`` (0.005), ``drift_weight`` (0.0),
      ``shake_weight`` (0.0): reward weights; the last three must be >= 0.
    - ``distance_limit`` (inf): terminate beyond this xy distance (m).
    - ``observation_noise_stdev`` (0.0): relative Gaussian observation noise.
    - ``motor_control`` ("accurate"): "accurate" DC motor model with PD
      position control, "pd" ideal PD torques, or "position" PyBullet servos.
    - ``motor_kp``, ``motor_kd`` (None: 1.0/0.02, 8.0/0.3 or 1.0/1.0 by mode).
    - ``motor_overheat_protection`` (True), ``motor_velocity_limit`` (inf rad/s).
    - ``action_repeat`` (1): control steps each action is held for.
      The attribute ``commanded_action`` holds the last step's action as the leg model
      took it (behind a gait prior, the 8 motor actions; the realism probe reads it).
    - ``realism`` (None): a :class:`Realism`, a mapping of its fields (set on top of the
      classic values or the preset's), "classic" or "tan2018": control step, control and
      PD latency, IMU noise and bias (each a value or a range drawn per episode), pushes.
      Until 0.3 each field is also a keyword of its own (``control_latency=0.02``), with
      a warning, and ``dynamics_ranges`` takes ``control_step``, ``control_latency``,
      ``imu_noise_stdev`` and ``imu_bias`` ranges (moved to ``realism``), with a warning.
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

    ``MinitaurBulletRandomized-v0`` is this env with ``preset="tan2018"``: same reward,
    threshold and time limit (1000 steps, which last 4-20 s as the control step is drawn).

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
        preset: str | None = None,
        randomize_dynamics: bool = True,
        dynamics_ranges: DynamicsRanges | dict[str, Any] | str | None = None,
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
        realism: Realism | dict[str, Any] | str | None = None,
        control_time_step: float | None = None,
        control_latency: float | None = None,
        pd_latency: float | None = None,
        imu_noise_stdev: float | None = None,
        imu_bias: float | Sequence[float] | None = None,
        pushes: Pushes | dict[str, Any] | bool | None = None,
        observation: Observation = "classic",
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
        self.render_mode = choice(
            "render_mode", render_mode, (None, *self.metadata["render_modes"])
        )
        self.observation = choice("observation", observation, OBSERVATIONS)
        self.motor_control = choice("motor_control", motor_control, MOTOR_CONTROLS)
        self.randomize_dynamics = boolean("randomize_dynamics", randomize_dynamics)
        self.motor_overheat_protection = boolean(
            "motor_overheat_protection", motor_overheat_protection
        )
        self.self_collision = boolean("self_collision", self_collision)
        self.on_rack = boolean("on_rack", on_rack)
        self.hard_reset = boolean("hard_reset", hard_reset)
        if dynamics_ranges is not None and not self.randomize_dynamics:
            raise ValueError(
                "dynamics_ranges has no effect with randomize_dynamics=False (the dynamics "
                "stay classic); drop one of them"
            )
        self.preset = preset
        base_ranges, base_realism = preset_settings(preset)
        dynamics_ranges, moved = _moved_ranges(dynamics_ranges, realism)
        if moved:
            realism = {**moved} if realism is None else {**_as_mapping(realism), **moved}
        _warn_timing_moved(preset, dynamics_ranges, realism)
        self.dynamics_ranges = DynamicsRanges.coerce(dynamics_ranges, base_ranges)
        self.reward_weights = RewardWeights(
            distance_weight, energy_weight, drift_weight, shake_weight
        )
        flat = {
            "control_time_step": control_time_step,
            "control_latency": control_latency,
            "pd_latency": pd_latency,
            "imu_noise_stdev": imu_noise_stdev,
            "imu_bias": imu_bias,
            "pushes": pushes,
        }
        self.realism = merge_realism(realism, flat, base_realism)
        self.camera = Camera(width, height, camera_distance, camera_yaw, camera_pitch)
        self.distance_limit = number("distance_limit", distance_limit, 0, math.inf, low_open=True)
        self.observation_noise_stdev = number(
            "observation_noise_stdev", observation_noise_stdev, 0, 10
        )
        self.motor_velocity_limit = number(
            "motor_velocity_limit", motor_velocity_limit, 0, math.inf, low_open=True, unit="rad/s"
        )
        self.action_repeat = integer("action_repeat", action_repeat, 1, 1000)
        default_kp, default_kd = DEFAULT_GAINS[motor_control]
        self._kp = number("motor_kp", default_kp if motor_kp is None else motor_kp, 0, 1e4)
        self._kd = number("motor_kd", default_kd if motor_kd is None else motor_kd, 0, 1e4)
        self.urdf_root = urdf_root

        self._check_time_steps()
        # The classic solver budget: 300 iterations per 10 ms, whatever the control step.
        self._solver_iterations = round(
            SOLVER_ITERATIONS * self.physics_time_step / CLASSIC_CONTROL_STEP
        )
        self._use_episode(_typical(self.realism))
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.dt)}

        self.action_space = spaces.Box(-1.0, 1.0, (NUM_MOTORS,), np.float32)
        bound = OBSERVATION_BOUND if observation == "classic" else IMU_OBSERVATION_BOUND
        self.observation_space = spaces.Box(-bound, bound, dtype=np.float32)

        # Delays need the readings of past physics steps; without them none are kept.
        max_delay = max(self.realism.highest("control_latency"), self.realism.highest("pd_latency"))
        self._history = SensorHistory(self.physics_time_step, max_delay) if max_delay > 0 else None
        self._physics_step_count = 0
        self._push_force = np.zeros(3)
        self.commanded_action = np.zeros(NUM_MOTORS)
        self._push_scale = 1.0

        self._sim: BulletSim | None = BulletSim(gui=render_mode == "human")
        self._robot: Minitaur | None = None
        self._start_state: int | None = None
        self._settled_state: tuple[int, np.ndarray] | None = None
        self._last_base_position = np.zeros(3)
        self._previous_x = 0.0
        self._last_frame_time = 0.0

    def _check_time_steps(self) -> None:
        """Set the physics step, and check the control step is a whole number of them."""
        control_time_step = self.realism.control_time_step
        # A motor model needs small physics steps to stay stable; PyBullet's own
        # position servos run one physics step per control step.
        if self.motor_control == "position":
            if self.realism.highest("pd_latency") > 0 or isinstance(control_time_step, Uniform):
                raise ValueError(
                    "pd_latency and a drawn control_time_step need a motor model "
                    "(motor_control 'accurate' or 'pd')"
                )
            self.physics_time_step = control_time_step
        else:
            self.physics_time_step = CLASSIC_CONTROL_STEP / SUBSTEPS
        if isinstance(control_time_step, Uniform):
            return  # each draw is snapped to whole physics steps
        substeps = round(control_time_step / self.physics_time_step)
        if substeps < 1 or abs(substeps * self.physics_time_step - control_time_step) > 1e-9:
            raise ValueError(
                f"control_time_step must be a positive multiple of the {self.physics_time_step} s "
                f"physics step, got {control_time_step}"
            )

    def _use_episode(self, episode: EpisodeRealism) -> EpisodeRealism:
        """Take this episode's control step (snapped to whole physics steps), latencies
        and IMU errors; return them as used."""
        substeps = max(1, round(episode.control_time_step / self.physics_time_step))
        control_step = self.physics_time_step * substeps
        if abs(control_step - episode.control_time_step) < 1e-12:
            control_step = episode.control_time_step  # exactly the classic 0.01 by default
        self._physics_steps_per_action = substeps * self.action_repeat
        self.dt = control_step * self.action_repeat
        self._episode = dataclasses.replace(episode, control_time_step=control_step)
        return self._episode

    # -- scene -------------------------------------------------------------------
    def _build_scene(self, sim: BulletSim) -> None:
        """Load the world; subclasses add bodies here."""
        self._plane = sim.load_plane()

    def _build_world(self) -> None:
        sim = self._live_sim()
        with sim.rendering_paused():
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
    def ground(self) -> int:
        """The body id of the plane the robot walks on."""
        if self._robot is None:
            raise ResetNeeded("call reset() before using the ground")
        return self._plane

    @property
    def robot(self) -> Minitaur:
        """The robot of the current episode."""
        if self._robot is None:
            raise ResetNeeded("call reset() before using the robot")
        return self._robot

    @property
    def push_scale(self) -> float:
        """The factor on every push's force, 1 for the ``pushes`` setting as given."""
        return self._push_scale

    def set_push_scale(self, scale: float) -> None:
        """Scale the force of the pushes drawn from now on by ``scale`` in [0, 1]: a
        curriculum's lever. The same random numbers are drawn at every scale."""
        self._push_scale = number("push scale", scale, 0, 1)

    def narrow_realism(self, fields: dict[str, Any]) -> None:
        """Draw the given realism fields from these ranges from the next reset on, each
        inside the env's own: a curriculum's lever, training envs that meet the hard end
        of the randomization more often. Anything else is refused in one line."""
        if not isinstance(fields, dict) or not fields or not set(fields) <= set(DRAW_ORDER):
            drawn = ", ".join(DRAW_ORDER)
            raise ValueError(
                f"narrow_realism takes a mapping of drawn realism fields ({drawn}), got {fields!r}"
            )
        narrowed = Realism.coerce(fields, self.realism)
        for name in fields:
            own, new = getattr(self.realism, name), getattr(narrowed, name)
            if not _inside(new, own):
                raise ValueError(
                    f"narrow_realism: {name} {_span(new)} is not inside the env's own {_span(own)}"
                )
        self.realism = narrowed
        self._check_time_steps()  # a fixed control step must be whole physics steps

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

        # Drawn after the dynamics, as the classic randomizer drew them.
        episode = self._use_episode(self.realism.draw(self.np_random))
        if self.realism.drawn:
            info["realism"] = episode

        if sim.gui:
            sim.follow_with_gui_camera([0, 0, 0], *self._camera_view())
        position, _ = robot.base_pose()
        # The classic reward measures the first step's displacement from the origin.
        self._last_base_position = np.zeros(3)
        self._previous_x = position[0]
        self._physics_step_count = 0
        self._push_force = np.zeros(3)
        info["base_position"] = np.array(position)
        if self._history is not None:
            self._history.clear()
            self._history.append(robot.sensor_reading())
        return self._observation(self._sensed(robot)), info

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
        self._live_sim()  # a closed env says so, rather than asking for a reset
        robot = self._robot
        if robot is None:
            raise ResetNeeded("call reset() before step()")
        action = checked_action(action, NUM_MOTORS)
        self.commanded_action = action  # what the leg model took (the realism probe reads it)
        targets = leg_model_to_motor_angles(action)
        sim, history = self._sim, self._history
        pd_latency, pushes = self._episode.pd_latency, self.realism.pushes
        for _ in range(self._physics_steps_per_action):
            pd_state = None
            if pd_latency > 0 and history is not None:
                late = history.delayed(pd_latency)
                pd_state = (late[ANGLES], late[VELOCITIES])
            robot.apply_motor_targets(targets, pd_state)
            if pushes is not None:
                self._push(sim, robot, pushes)
            sim.step()
            self._physics_step_count += 1
            if history is not None:
                history.append(robot.sensor_reading())

        position, orientation = robot.base_pose()
        state = robot.observation()
        reward, info = self._reward(np.array(position), state)
        terminated = self._is_terminated(position, orientation)
        info["motors_enabled"] = robot.motors_enabled.copy()
        if pushes is not None:
            info["push_force"] = self._push_force.copy()
        if self.render_mode == "human":
            self._show_in_gui(position)
        sensed = state if history is None and self.observation == "classic" else None
        return self._observation(self._sensed(robot, sensed)), reward, terminated, False, info

    def _push(self, sim: BulletSim, robot: Minitaur, pushes: Pushes) -> None:
        """Tan et al.'s pushes: a new random force every interval, held for the duration."""
        interval = max(1, round(pushes.interval / self.physics_time_step))
        duration = max(1, round(pushes.duration / self.physics_time_step))
        step = self._physics_step_count
        if step >= interval and step % interval == 0:
            yaw = quaternion_to_euler(np.array(robot.base_pose()[1]))[2] if pushes.heading else 0.0
            self._push_force = pushes.draw(self.np_random, yaw) * self._push_scale
        elif step < interval or step % interval >= duration:
            self._push_force = np.zeros(3)
        if self._push_force.any():
            sim.apply_base_force(robot.body, self._push_force)

    def _sensed(self, robot: Minitaur, state: np.ndarray | None = None) -> np.ndarray:
        """The reading the controller gets now: ``control_latency`` old when there is one."""
        if self._history is not None:
            return self._history.delayed(self._episode.control_latency)
        if state is not None:
            return state
        return robot.sensor_reading() if self.observation == "imu" else robot.observation()

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn(
                "render() called without a render_mode; "
                'make the env with render_mode="rgb_array" or "human"'
            )
            return None
        if self.render_mode == "human":
            return None
        self._live_sim()
        if self._robot is None:
            raise ResetNeeded("call reset() before render()")
        position, _ = self._robot.base_pose()
        camera = self.camera
        return self._sim.render(position, camera.width, camera.height, *self._camera_view())

    def _camera_view(self) -> tuple[float, float, float]:
        return self.camera.distance, self.camera.yaw, self.camera.pitch

    def close(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None
        self._robot = None

    # -- internals -------------------------------------------------------------
    def _observation(self, reading: np.ndarray) -> np.ndarray:
        return observe(
            reading,
            self.observation,
            self.np_random,
            self.observation_noise_stdev,
            self._episode.imu_noise_stdev,
            np.array(self._episode.imu_bias),
        )

    def _reward(self, position: np.ndarray, state: np.ndarray) -> tuple[float, dict[str, Any]]:
        displacement = position - self._last_base_position
        self._last_base_position = position
        torques = state[2 * NUM_MOTORS : 3 * NUM_MOTORS]
        velocities = state[NUM_MOTORS : 2 * NUM_MOTORS]
        energy = abs(float(np.dot(torques, velocities))) * self.physics_time_step
        weights = self.reward_weights
        info: dict[str, Any] = {
            "reward_forward": weights.distance * float(displacement[0]),
            "reward_energy": -weights.energy * energy,
            "reward_drift": -weights.drift * abs(float(displacement[1])),
            "reward_shake": -weights.shake * abs(float(displacement[2])),
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
        sim.follow_with_gui_camera(position, *self._camera_view())
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


# dynamics_ranges fields that moved to realism in 0.3, and their realism names.


def with_history(env: gym.Env, history: int) -> gym.Env:
    """``env`` seeing its last ``history`` (1 to 16) observations, newest last, flattened
    into one vector (the first observation repeated at reset); ``env`` itself for 1."""
    history = integer("history", history, 1, MAX_HISTORY)
    if history == 1:
        return env
    return FlattenObservation(FrameStackObservation(env, history))


def make_minitaur_env(render_mode: str | None = None, history: int = 1, **kwargs: Any) -> gym.Env:
    """``MinitaurBulletEnv(render_mode, **kwargs)`` seeing its last ``history``
    observations (:func:`with_history`); with the default 1, the classic env itself.

    The classic observation has no base velocity: a stack of them says where the body
    is going as well as where it is (``history: 3`` in SAC's ``minitaur-history``
    entry). What the env simulates and rewards is unchanged.
    """
    integer("history", history, 1, MAX_HISTORY)  # before the simulator is built
    return with_history(MinitaurBulletEnv(render_mode, **kwargs), history)


MOVED_RANGES = {
    "control_step": "control_time_step",
    "control_latency": "control_latency",
    "imu_noise_stdev": "imu_noise_stdev",
    "imu_bias": "imu_bias",
}


def _span(value: Any) -> tuple[float, float]:
    """The lowest and highest value a realism field can take."""
    if isinstance(value, Uniform):
        return (value.low, value.high)
    return (float(np.min(value)), float(np.max(value)))


def _inside(new: Any, own: Any) -> bool:
    """Whether every value of ``new`` is one ``own`` can take."""
    if not isinstance(own, Uniform):
        return not isinstance(new, Uniform) and bool(np.allclose(new, own))
    low, high = _span(new)
    return own.low <= low and high <= own.high


def _as_mapping(realism: Realism | dict[str, Any] | str) -> dict[str, Any]:
    if isinstance(realism, Realism):
        return {field.name: getattr(realism, field.name) for field in dataclasses.fields(realism)}
    if isinstance(realism, str):
        return _as_mapping(Realism.coerce(realism))
    return dict(realism)


def _moved_ranges(dynamics_ranges: Any, realism: Any) -> tuple[Any, dict[str, Any]]:
    """Take the timing and IMU ranges out of a dynamics_ranges mapping (where they were
    before 0.3), with a warning; refuse one that realism sets too."""
    if not isinstance(dynamics_ranges, dict):
        return dynamics_ranges, {}
    old = {name: value for name, value in dynamics_ranges.items() if name in MOVED_RANGES}
    if not old:
        return dynamics_ranges, {}
    moved = {MOVED_RANGES[name]: value for name, value in old.items()}
    if realism is not None:
        own = Realism.coerce(realism)
        twice = [name for name in moved if getattr(own, name) != getattr(Realism(), name)]
        if twice:
            raise ValueError(
                f"{twice[0]} is given twice, in dynamics_ranges and in realism; give it once "
                "(in realism)"
            )
    warnings.warn(
        f"dynamics_ranges {', '.join(sorted(old))} will be removed after 0.3; give "
        f"realism={{{', '.join(f'{name!r}: {value!r}' for name, value in moved.items())}}}",
        FutureWarning,
        stacklevel=4,
    )
    rest = {name: value for name, value in dynamics_ranges.items() if name not in MOVED_RANGES}
    return rest, moved


def _warn_timing_moved(preset_name: str | None, dynamics_ranges: Any, realism: Any) -> None:
    """Until 0.3 a named dynamics_ranges also set the control step, latency and IMU
    ranges; say so where the old meaning and the new one differ."""
    if not isinstance(dynamics_ranges, str) or realism is not None:
        return
    if dynamics_ranges == "tan2018" and preset_name is None:
        warnings.warn(
            "dynamics_ranges='tan2018' draws Table I's physical parameters only since 0.3; "
            "add realism='tan2018' for its control step, latency and IMU ranges",
            FutureWarning,
            stacklevel=4,
        )
    elif preset_name is not None:
        warnings.warn(
            f"dynamics_ranges={dynamics_ranges!r} keeps preset {preset_name!r}'s drawn control "
            "step, latency and IMU errors since 0.3; add realism='classic' for the classic ones",
            FutureWarning,
            stacklevel=4,
        )


def _typical(realism: Realism) -> EpisodeRealism:
    """The values before the first reset: the fixed ones, and the middle of each range."""

    def middle(value: Any) -> Any:
        return (value.low + value.high) / 2 if isinstance(value, Uniform) else value

    bias = realism.imu_bias
    return EpisodeRealism(
        control_time_step=middle(realism.control_time_step),
        control_latency=middle(realism.control_latency),
        pd_latency=middle(realism.pd_latency),
        imu_noise_stdev=middle(realism.imu_noise_stdev),
        imu_bias=(middle(bias),) * 3 if isinstance(bias, Uniform) else tuple(bias),
    )
