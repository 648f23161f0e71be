"""Behaviour of the gymnasium env: API, seeding, reward, termination, rendering, errors."""

from __future__ import annotations

import gc
import time
import warnings

import gymnasium as gym
import numpy as np
import pybullet
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import check_env as gym_check_env
from gymnasium.utils.passive_env_checker import env_render_passive_checker
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import minitaur_env
from minitaur_env import DynamicsRanges, MinitaurBulletEnv


def rollout(env: gym.Env, seed: int, steps: int, action_seed: int = 0):
    rng = np.random.default_rng(action_seed)
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 8).astype(np.float32))
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            break
    return np.array(observations), np.array(rewards)


@pytest.fixture
def env():
    env = MinitaurBulletEnv()
    yield env
    env.close()


# -- registration and checkers ------------------------------------------------------


@pytest.mark.parametrize("env_id", minitaur_env.ENV_IDS)
def test_registered_with_classic_spec(env_id):
    spec = gym.spec(env_id)
    assert spec.max_episode_steps == 1000
    assert spec.reward_threshold == (5.0 if "Duck" in env_id else 15.0)


def test_make_by_module_prefixed_id_and_classic_id_are_the_same_env():
    a = gym.make("minitaur_env:MinitaurBullet-v0")
    b = gym.make("MinitaurBulletEnv-v0")
    assert type(a.unwrapped) is type(b.unwrapped) is MinitaurBulletEnv
    a.close()
    b.close()


@pytest.mark.parametrize("env_id", minitaur_env.ENV_IDS)
def test_gymnasium_and_sb3_checkers_pass_without_warnings_headless(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=True, skip_render_check=True)
    env.close()
    frames = gym.make(env_id, render_mode="rgb_array", width=64, height=48)
    frames.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env_render_passive_checker(frames.unwrapped)
    frames.close()


def test_gymnasium_checker_passes_in_every_render_mode_with_a_display(display):
    # gymnasium's full check also makes the env in "human" mode: the GUI.
    env = gym.make("MinitaurBulletEnv-v0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped)
    env.close()


def test_spaces_and_metadata(env):
    assert env.action_space == gym.spaces.Box(-1, 1, (8,), np.float32)
    assert env.observation_space.shape == (28,)
    assert env.observation_space.dtype == np.float32
    assert env.metadata["render_fps"] == 100
    slow = MinitaurBulletEnv(action_repeat=2)
    assert slow.metadata["render_fps"] == 50 and env.metadata["render_fps"] == 100
    slow.close()


def test_observations_are_float32_and_inside_the_space_under_violent_actions(env):
    rng = np.random.default_rng(1)
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        assert obs.dtype == np.float32 and env.observation_space.contains(obs)
        action = np.zeros(8)
        for step in range(300):
            if step % 10 == 0:
                action = np.sign(rng.uniform(-1, 1, 8))
            obs, _, terminated, _, _ = env.step(action.astype(np.float32))
            assert obs.dtype == np.float32
            assert env.observation_space.contains(obs), obs
            if terminated:
                break


@pytest.mark.parametrize(
    "kwargs",
    [
        {"observation_noise_stdev": 0.01},
        {
            "observation_noise_stdev": 0.01,
            "observation": "imu",
            "imu_noise_stdev": 0.05,
            "imu_bias": 0.05,
        },
        {"observation_noise_stdev": 0.3},
    ],
    ids=["classic-noise", "imu-noise-and-bias", "heavy-noise"],
)
def test_noisy_observations_saturate_at_the_space_bounds(kwargs):
    # The classic env added noise after its bounds: a torque at its limit plus noise left
    # the space (165 of 300 observations at 0.01). A noisy reading now saturates there.
    env = MinitaurBulletEnv(**kwargs)
    rng = np.random.default_rng(1)
    obs, _ = env.reset(seed=0)
    observations, action = [obs], np.zeros(8)
    for step in range(300):
        if step % 10 == 0:
            action = np.sign(rng.uniform(-1, 1, 8))
        obs, _, terminated, _, _ = env.step(action.astype(np.float32))
        observations.append(obs)
        if terminated:
            obs, _ = env.reset()
    env.close()
    outside = [o for o in observations if not env.observation_space.contains(o)]
    assert not outside, outside[0]
    at_bound = np.isclose(np.abs(observations), env.observation_space.high).any(axis=1)
    if kwargs["observation_noise_stdev"] == 0.3:  # control: noise that reaches the bounds
        assert at_bound.mean() > 0.5


# -- seeding ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"randomize_dynamics": False}, {"observation_noise_stdev": 0.01}],
    ids=["randomized", "fixed", "noisy"],
)
def test_same_seed_gives_identical_trajectories(kwargs):
    first, second = MinitaurBulletEnv(**kwargs), MinitaurBulletEnv(**kwargs)
    # Interleave the two envs in one process: they must not share any state.
    obs_a, rew_a = rollout(first, seed=7, steps=150)
    rollout(second, seed=99, steps=50)
    obs_b, rew_b = rollout(second, seed=7, steps=150)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    first.close()
    second.close()


def test_different_seeds_draw_different_dynamics(env):
    _, info_a = env.reset(seed=1)
    _, info_b = env.reset(seed=2)
    assert info_a["dynamics"] != info_b["dynamics"]
    ranges = DynamicsRanges()
    for info in (info_a, info_b):
        assert ranges.battery_voltage[0] <= info["dynamics"].battery_voltage
        assert info["dynamics"].battery_voltage <= ranges.battery_voltage[1]
        assert ranges.foot_friction[0] <= info["dynamics"].foot_friction
        assert info["dynamics"].foot_friction <= ranges.foot_friction[1]


def test_randomization_changes_the_dynamics_and_can_be_switched_off():
    fixed = MinitaurBulletEnv(randomize_dynamics=False)
    obs_fixed_1, _ = rollout(fixed, seed=1, steps=30)
    obs_fixed_2, _ = rollout(fixed, seed=2, steps=30)
    np.testing.assert_array_equal(obs_fixed_1, obs_fixed_2)
    randomized = MinitaurBulletEnv()
    obs_random, _ = rollout(randomized, seed=1, steps=30)
    assert not np.array_equal(obs_random, obs_fixed_1)
    fixed.close()
    randomized.close()


# -- reward, info, termination ---------------------------------------------------------


def test_reward_terms_sum_to_the_reward_and_info_reports_motion():
    env = MinitaurBulletEnv(drift_weight=0.3, shake_weight=0.2)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    previous_x = env.robot.base_pose()[0][0]
    for _ in range(50):
        _, reward, _, _, info = env.step(rng.uniform(-1, 1, 8).astype(np.float32))
        terms = [info[k] for k in ("reward_forward", "reward_energy", "reward_drift")]
        terms.append(info["reward_shake"])
        assert reward == pytest.approx(sum(terms), abs=1e-12)
        assert info["reward_energy"] <= 0 and info["reward_drift"] <= 0
        assert info["reward_shake"] <= 0
        x = info["base_position"][0]
        assert info["x_velocity"] == pytest.approx((x - previous_x) / 0.01, abs=1e-6)
        previous_x = x
    assert info["motors_enabled"].shape == (8,)
    env.close()


def test_upside_down_robot_terminates(env):
    env.reset(seed=0)
    upside_down = (1.0, 0.0, 0.0, 0.0)  # 180 degrees about x
    env.sim.reset_base(env.robot.body, (0.0, 0.0, 0.4), upside_down)
    assert env.has_fallen()
    _, _, terminated, truncated, _ = env.step(np.zeros(8, np.float32))
    assert terminated and not truncated


def test_standing_robot_does_not_terminate_and_time_limit_truncates():
    env = gym.make("MinitaurBulletEnv-v0", max_episode_steps=20)
    env.reset(seed=0)
    for step in range(20):
        _, _, terminated, truncated, _ = env.step(np.zeros(8, np.float32))
        assert not terminated
        assert truncated == (step == 19)
    env.close()


@pytest.mark.parametrize("limit", [0.05, float("inf")])
def test_distance_limit_terminates_only_beyond_the_limit(limit):
    env = MinitaurBulletEnv(distance_limit=limit)
    env.reset(seed=0)
    env.sim.reset_base(env.robot.body, (0.1, 0.0, 0.2), (0, 0, 0, 1))
    _, _, terminated, _, _ = env.step(np.zeros(8, np.float32))
    assert terminated == (limit < 0.1)
    env.close()


def test_duck_env_terminates_when_the_duck_touches_the_ground():
    env = gym.make("MinitaurBulletDuckEnv-v0").unwrapped
    env.reset(seed=0)
    _, _, terminated, _, _ = env.step(np.zeros(8, np.float32))
    assert not terminated and not env.lost_duck()
    env.sim.reset_base(env._duck, (0.6, 0.0, 0.02), (0, 0, 0, 1))
    _, _, terminated, _, _ = env.step(np.zeros(8, np.float32))
    assert env.lost_duck() and terminated
    env.close()


@pytest.mark.parametrize("protection", [True, False])
def test_overheat_protection_switches_a_stalled_motor_off(protection):
    env = MinitaurBulletEnv(
        on_rack=True, randomize_dynamics=False, motor_overheat_protection=protection
    )
    env.reset(seed=0)
    body, joint, client = env.robot.body, env.robot.motor_joints[0], env.sim._id
    # Pin motor 0's link to the world: commanded away from its angle, it stalls at full torque.
    position, orientation = pybullet.getLinkState(body, joint, physicsClientId=client)[:2]
    pin = pybullet.createConstraint(
        body,
        joint,
        -1,
        -1,
        pybullet.JOINT_FIXED,
        [0, 0, 0],
        [0, 0, 0],
        position,
        childFrameOrientation=orientation,
        physicsClientId=client,
    )
    action = np.zeros(8, np.float32)
    action[[0, 4]] = 1.0
    enabled = []
    for _ in range(110):
        obs, _, _, _, info = env.step(action)
        enabled.append(info["motors_enabled"].copy())
    enabled = np.array(enabled)
    assert abs(obs[16]) > 2.45  # the stall torque the protection watches for
    assert enabled[:, 1:].all()
    if protection:  # more than 1 s (100 steps) above 2.45 N m: off
        assert enabled[:100, 0].all() and not enabled[100:, 0].any()
    else:
        assert enabled[:, 0].all()
    # Released, a live motor holds its target; a switched-off one applies no torque.
    pybullet.removeConstraint(pin, physicsClientId=client)
    for _ in range(20):
        obs, *_ = env.step(action)
    target = 1.9728  # motor 0's angle for this action, as the live motor reaches it
    assert (abs(obs[0] - target) > 0.3) == protection
    env.reset(seed=0)
    assert env.robot.motors_enabled.all()
    env.close()


# -- rendering --------------------------------------------------------------------------


def test_rgb_array_frames_follow_the_robot_and_are_not_blank():
    env = MinitaurBulletEnv(render_mode="rgb_array", width=160, height=120)
    with pytest.raises(ResetNeeded):
        env.render()
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    assert frame.std() > 10  # a blank (EGL-style) frame is uniform
    # The camera follows the base: moving the robot far away keeps it in view.
    start = env.robot.base_pose()[0]
    env.sim.reset_base(env.robot.body, (5.0, 3.0, 0.2), (0, 0, 0, 1))
    centre = (slice(40, 80), slice(50, 110))  # where the robot is in the first frame
    moved = env.render()
    followed = np.abs(moved.astype(int) - frame.astype(int))[centre].mean()
    # Negative control: a camera left where it was sees the robot gone from the centre.
    fixed = env.sim.render(start, 160, 120, env.camera.distance, 0.0, -30.0)
    left_behind = np.abs(fixed.astype(int) - frame.astype(int))[centre].mean()
    assert followed < 20 < left_behind
    env.close()


def test_default_frame_size_is_640x480():
    env = MinitaurBulletEnv(render_mode="rgb_array")
    env.reset(seed=0)
    assert env.render().shape == (480, 640, 3)
    env.close()


def test_human_mode_opens_the_gui_and_follows_the_robot(display):
    env = MinitaurBulletEnv(render_mode="human")
    env.reset(seed=0)
    assert env.sim.gui
    start = time.perf_counter()
    for _ in range(10):
        env.step(np.zeros(8, np.float32))
    assert time.perf_counter() - start >= 0.09  # paced at real time, 10 x 0.01 s
    assert env.render() is None
    env.close()


def _urdf_loads_while_drawing(monkeypatch, render_mode: str | None) -> tuple[int, int, bool]:
    """(URDFs loaded, of those loaded while the window drew, drawing at the end) over two
    resets, from the PyBullet calls themselves."""
    import pybullet

    drawing, loads, drawn = True, 0, 0
    configure, load_urdf = pybullet.configureDebugVisualizer, pybullet.loadURDF

    def configure_spy(flag, enable, **kwargs):
        nonlocal drawing
        if flag == pybullet.COV_ENABLE_RENDERING:
            drawing = bool(enable)
        return configure(flag, enable, **kwargs)

    def load_spy(*args, **kwargs):
        nonlocal loads, drawn
        loads, drawn = loads + 1, drawn + drawing
        return load_urdf(*args, **kwargs)

    monkeypatch.setattr(pybullet, "configureDebugVisualizer", configure_spy)
    monkeypatch.setattr(pybullet, "loadURDF", load_spy)
    env = MinitaurBulletEnv(render_mode=render_mode)
    env.reset(seed=0)
    env.reset(seed=1)
    env.close()
    return loads, drawn, drawing


def test_the_gui_draws_nothing_while_the_world_is_built(display, monkeypatch):
    # As the classic env: a window that redraws at each URDF loaded took seconds a body
    # under Xvfb's software OpenGL (an evaluate.py --gui of two 10-step episodes: 31 s,
    # 14 s with the pause).
    loads, drawn, drawing = _urdf_loads_while_drawing(monkeypatch, "human")
    assert loads >= 2 and drawn == 0 and drawing
    # control: headless, nothing is paused (nothing draws), and the spy sees the loads
    loads, drawn, _ = _urdf_loads_while_drawing(monkeypatch, None)
    assert loads >= 2 and drawn == loads


def test_human_mode_without_display_fails_clearly(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="DISPLAY"):
        MinitaurBulletEnv(render_mode="human")


def test_render_without_mode_warns_and_returns_none(env):
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


# -- bad input ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("action", "message"),
    [
        (np.full(8, np.nan), "finite"),
        (np.array([0, 0, np.inf, 0, 0, 0, 0, 0]), "finite"),
        (np.zeros(7), "shape"),
        (np.zeros((2, 8)), "shape"),
        (np.array([0, 0, 0, 1.02, 0, 0, 0, 0]), r"action\[3\]"),
        (["a"] * 8, "real numbers"),
        ([True] * 8, "real numbers"),
        (np.zeros(8) + 0.5j, "real numbers"),
    ],
)
def test_bad_actions_raise_value_error(env, action, message):
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(action)


def test_classic_action_tolerance_is_accepted_and_no_more(env):
    env.reset(seed=0)
    obs, *_ = env.step(np.full(8, 1.01, np.float32))
    assert obs.shape == (28,) and np.isfinite(obs).all()
    with pytest.raises(ValueError, match=r"action\[0\] = 1\.0199.* outside \[-1, 1\]"):
        env.step(np.full(8, 1.02, np.float32))


def test_step_before_reset_raises(env):
    with pytest.raises(ResetNeeded, match="reset"):
        env.step(np.zeros(8, np.float32))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"energy_weight": -1.0}, "energy_weight"),
        ({"drift_weight": float("nan")}, "drift_weight"),
        ({"width": 0}, "width"),
        ({"height": 100.5}, "height"),
        ({"render_mode": "window"}, "render_mode"),
        ({"motor_control": "magic"}, "motor_control"),
        ({"action_repeat": 0}, "action_repeat"),
        ({"distance_limit": -1.0}, "distance_limit"),
        ({"observation_noise_stdev": -0.1}, "observation_noise_stdev"),
        # accepted before without a word: 0 solver iterations, a push at every physics step,
        # ranges that nothing draws from
        ({"realism": {"control_time_step": 1e-300}}, r"control_time_step must be .*\[0.001, 0.1\]"),
        ({"realism": {"pushes": {"interval": 1e-9, "duration": 1e-9}}}, r"Pushes.interval must be"),
        ({"preset": "tan2018", "dynamics_ranges": {}, "randomize_dynamics": False}, "no effect"),
    ],
)
def test_invalid_arguments_fail_at_construction(kwargs, message):
    with pytest.raises(ValueError, match=message):
        MinitaurBulletEnv(**kwargs)


def test_the_smallest_accepted_settings_build(env):  # control of the three cases above
    MinitaurBulletEnv(realism={"control_time_step": 0.001}, motor_control="position").close()
    MinitaurBulletEnv(realism={"pushes": {"interval": 0.01, "duration": 0.002}}).close()
    MinitaurBulletEnv(preset="tan2018", dynamics_ranges={}).close()


def test_unknown_argument_fails_at_construction():
    with pytest.raises(TypeError, match="not_an_option"):
        gym.make("MinitaurBulletEnv-v0", not_an_option=1)


def test_invalid_dynamics_ranges_are_rejected():
    with pytest.raises(ValueError, match="foot_friction"):
        DynamicsRanges(foot_friction=(1.5, 0.8))


# -- lifetime ------------------------------------------------------------------------------


def _rss_mib() -> float:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def test_close_is_idempotent_and_frees_the_client():
    env = MinitaurBulletEnv()
    env.reset(seed=0)
    client = env.sim._id
    env.close()
    env.close()
    assert not pybullet.isConnected(physicsClientId=client)
    for call in (env.reset, lambda: env.step(np.zeros(8))):  # not "call reset()"
        with pytest.raises(RuntimeError, match="the env is closed; make a new one"):
            call()


def test_200_envs_leave_no_client_connected_and_memory_flat():
    clients = []
    rss = []
    for i in range(200):
        env = MinitaurBulletEnv()
        env.reset(seed=i)
        env.step(np.zeros(8, np.float32))
        clients.append(env.sim._id)
        env.close()
        if i in (49, 199):
            gc.collect()
            rss.append(_rss_mib())
    assert not any(pybullet.isConnected(physicsClientId=c) for c in clients)
    assert rss[1] - rss[0] < 20, f"memory grew {rss[1] - rss[0]:.1f} MiB over 150 envs"


def test_works_in_subproc_vec_env_built_from_the_id():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = make_vec_env(
        "minitaur_env:MinitaurBulletEnv-v0", n_envs=2, seed=3, vec_env_cls=SubprocVecEnv
    )
    obs = vec.reset()
    assert obs.shape == (2, 28) and obs.dtype == np.float32
    for _ in range(5):
        obs, rewards, _, infos = vec.step(np.zeros((2, 8), np.float32))
    assert rewards.shape == (2,) and "x_velocity" in infos[0]
    vec.close()


def test_fast_reset_starts_from_the_hard_reset_observation():
    hard = MinitaurBulletEnv(randomize_dynamics=False)
    fast = MinitaurBulletEnv(randomize_dynamics=False, hard_reset=False)
    expected, _ = hard.reset(seed=0)
    for seed in range(3):
        obs, _ = fast.reset(seed=seed)
        np.testing.assert_array_equal(obs, expected)
        for _ in range(20):
            fast.step(np.ones(8, np.float32))
    hard.close()
    fast.close()


def _rollout(env: MinitaurBulletEnv, seed: int, actions: np.ndarray) -> np.ndarray:
    observations = [env.reset(seed=seed)[0]]
    for action in actions:
        obs, _, terminated, _, _ = env.step(action)
        observations.append(obs)
        if terminated:
            break
    return np.array(observations)


@pytest.mark.parametrize("randomize", [False, True])
def test_fast_reset_is_reproducible_whatever_came_before(randomize):
    actions = np.random.default_rng(0).uniform(-1, 1, (150, 8)).astype(np.float32)
    other = np.random.default_rng(1).uniform(-1, 1, (150, 8)).astype(np.float32)
    fresh = MinitaurBulletEnv(randomize_dynamics=randomize, hard_reset=False)
    expected = _rollout(fresh, 7, actions)
    fresh.close()

    env = MinitaurBulletEnv(randomize_dynamics=randomize, hard_reset=False)
    for history_seed in (1, 2):
        _rollout(env, history_seed, other[: 50 * history_seed])
        np.testing.assert_array_equal(_rollout(env, 7, actions), expected)
    env.close()


@pytest.mark.parametrize("motor_control", ["accurate", "pd", "position"])
def test_every_motor_control_mode_stands_and_moves(motor_control):
    env = MinitaurBulletEnv(motor_control=motor_control, randomize_dynamics=False)
    obs, _ = env.reset(seed=0)
    for _ in range(50):
        obs, _, terminated, _, _ = env.step(np.zeros(8, np.float32))
        assert not terminated and env.observation_space.contains(obs)
    # Zero action means 5*pi/8 on every motor: each mode must get there from pi/2.
    np.testing.assert_allclose(obs[:8], 5 * np.pi / 8, atol=0.15)
    env.close()


def test_action_repeat_holds_each_action_longer():
    env = MinitaurBulletEnv(action_repeat=3, randomize_dynamics=False)
    env.reset(seed=0)
    assert env.dt == pytest.approx(0.03)
    _, _, _, _, info = env.step(np.full(8, 0.5, np.float32))
    single = MinitaurBulletEnv(randomize_dynamics=False)
    single.reset(seed=0)
    for _ in range(3):
        _, _, _, _, single_info = single.step(np.full(8, 0.5, np.float32))
    np.testing.assert_allclose(info["base_position"], single_info["base_position"], atol=1e-9)
    env.close()
    single.close()


def test_on_rack_holds_the_base_in_the_air():
    env = MinitaurBulletEnv(on_rack=True, randomize_dynamics=False)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(100):
        _, _, terminated, _, info = env.step(rng.uniform(-1, 1, 8).astype(np.float32))
        assert not terminated
    assert info["base_position"][2] > 0.5
    env.close()


TRAINING_MODULES = (
    "stable_baselines3",
    "sb3_contrib",
    "torch",
    "yaml",
    "matplotlib",
    "imageio",
    "tqdm",
    "rich",
)
WITHOUT_TRAINING = (
    "import sys\n"
    f"for name in {TRAINING_MODULES!r}:\n"
    "    sys.modules[name] = None  # as if not installed\n"
)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_the_env_alone_needs_neither_sb3_nor_torch_and_the_scripts_say_what_is_missing():
    import subprocess
    import sys

    from tests.scripts import REPO, error_lines

    play = "import gymnasium as gym, minitaur_env\nenv = gym.make('MinitaurBulletEnv-v0')\n"
    play += "obs, _ = env.reset(seed=0)\nprint(obs.shape, env.step(env.action_space.sample())[1])"
    result = subprocess.run(
        [sys.executable, "-c", WITHOUT_TRAINING + play], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("(28,) ")
    for script in ("train.py", "evaluate.py"):
        run = f"import runpy\nsys.argv = ['{script}']\nrunpy.run_path('{REPO / script}', "
        run += "run_name='__main__')"
        result = subprocess.run(
            [sys.executable, "-c", WITHOUT_TRAINING + run],
            capture_output=True,
            text=True,
            timeout=120,
        )
        (line,) = error_lines(result)
        assert line.startswith(f"{script}: error: ") and "'minitaur-env[train]'" in line
        assert result.returncode == 1


def test_a_mirrored_action_sequence_moves_the_robot_into_the_mirrored_observations():
    from minitaur_env.robot import mirror_leg_action, mirror_observation

    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (50, 8)).astype(np.float32)
    for t in range(1, len(actions)):  # smooth commands, as a policy's: less chaos to amplify
        actions[t] = 0.8 * actions[t - 1] + 0.2 * actions[t]

    def observations(sequence: np.ndarray) -> np.ndarray:
        env = MinitaurBulletEnv()
        seen = [env.reset(seed=1)[0]]
        seen += [env.step(action)[0] for action in sequence]
        env.close()
        return np.array(seen)

    played = observations(actions)
    mirrored = observations(mirror_leg_action(actions))
    angles = np.s_[:, :8]
    moved = np.abs(played[angles] - played[0, :8]).max()
    error = np.abs(mirror_observation(played)[angles] - mirrored[angles]).max()
    # 0.06 of 0.78 rad measured: the robot is symmetric up to its knee pivots
    assert moved > 0.4 and error < 0.15 * moved
    # The control: without swapping each leg's two motors the mirror image is wrong.
    legs_only = played[:, np.r_[4:8, 0:4]]
    assert np.abs(legs_only[angles] - mirrored[angles]).max() > 3 * error
    twice = mirror_observation(mirror_observation(played))
    assert np.array_equal(twice, played)
    assert np.array_equal(mirror_leg_action(mirror_leg_action(actions)), actions)
