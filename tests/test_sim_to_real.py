"""Sim-to-real knobs: each changes behaviour the way it should, is seeded, and is off by default."""

from __future__ import annotations

import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pybullet
import pytest

import minitaur_env  # noqa: F401
from minitaur_env import DynamicsRanges, MinitaurBulletEnv, Pushes, Realism
from minitaur_env.robot import MOTOR_DIRECTIONS, leg_model_to_motor_angles
from minitaur_env.sensors import SensorHistory, euler_to_quaternion, quaternion_to_euler

# Every classic range pinned to one value, so that only the knob under test differs.
PINNED = {
    "base_mass_scale": (1.0, 1.0),
    "leg_mass_scale": (1.0, 1.0),
    "battery_voltage": (16.0, 16.0),
    "motor_viscous_damping": (0.0, 0.0),
    "foot_friction": (1.0, 1.0),
}


def observations(steps: int = 30, seed: int = 0, action: np.ndarray | None = None, **kwargs):
    """Observations and infos of ``steps`` steps of random (or fixed) actions."""
    env = MinitaurBulletEnv(**{"randomize_dynamics": False, **kwargs})
    rng = np.random.default_rng(1)
    obs, info = env.reset(seed=seed)
    seen, infos = [obs], [info]
    for _ in range(steps):
        step = rng.uniform(-1, 1, 8) if action is None else action
        obs, _, terminated, _, info = env.step(step)
        seen.append(obs)
        infos.append(info)
        if terminated:
            break
    env.close()
    return np.array(seen), infos


# -- defaults ---------------------------------------------------------------------------
def test_defaults_draw_only_the_classic_parameters():
    env = MinitaurBulletEnv()
    _, info = env.reset(seed=0)
    sample = info["dynamics"]
    extra = [f.name for f in dataclasses.fields(sample)][6:]
    assert extra and all(getattr(sample, name) is None for name in extra)
    assert env.dt == 0.01 and env.observation_space.shape == (28,)
    env.close()


# -- latency ----------------------------------------------------------------------------
@pytest.mark.parametrize("steps", [1, 2, 3])
def test_control_latency_delays_observations_by_whole_steps(steps):
    plain, _ = observations()
    late, _ = observations(realism={"control_latency": 0.01 * steps})
    np.testing.assert_array_equal(late[steps:], plain[:-steps])
    assert np.abs(late[steps:] - plain[steps:]).max() > 0.1  # control: not the same series
    np.testing.assert_array_equal(late[:steps], np.repeat(plain[:1], steps, axis=0))


def test_sensor_history_interpolates_between_physics_steps():
    history = SensorHistory(physics_time_step=0.002, max_delay=0.01)
    for value in range(10):
        history.append(np.full(3, float(value)))  # newest: 9
    assert history.delayed(0.0)[0] == 9.0
    assert history.delayed(0.004)[0] == pytest.approx(7.0)
    assert history.delayed(0.005)[0] == pytest.approx(6.5)
    assert history.delayed(1.0)[0] == 3.0  # older than kept: the oldest reading (maxlen 7)


def test_pd_latency_makes_the_position_loop_overshoot():
    swing = np.array([0, 0, 0, 0, 1, 1, 1, 1], dtype=float)
    settle = {}
    for latency in (0.0, 0.012):
        angles, _ = observations(40, action=swing, on_rack=True, realism={"pd_latency": latency})
        settle[latency] = angles[:, 0]
    # Without latency the motor moves to its target without passing it.
    assert settle[0.0].min() == pytest.approx(settle[0.0][-1], abs=1e-3)
    assert settle[0.012].min() < settle[0.0][-1] - 0.1


# -- physical parameters ----------------------------------------------------------------
def test_motor_strength_scales_the_applied_torque(monkeypatch):
    action = np.full(8, 0.5)
    for strength in (1.0, 0.8):
        env = MinitaurBulletEnv(
            dynamics_ranges={**PINNED, "motor_strength": (strength, strength)}, on_rack=True
        )
        env.reset(seed=0)
        robot = env.robot
        angles, velocities = robot.motor_angles_velocities()
        unscaled, _ = robot.motor_model.torques(
            leg_model_to_motor_angles(action), angles, velocities
        )
        applied: list = []
        monkeypatch.setattr(env.sim, "set_torques", lambda b, j, t, seen=applied: seen.append(t))
        env.step(action)
        env.close()
        assert np.abs(unscaled).max() > 0.1
        np.testing.assert_allclose(applied[0], strength * unscaled * MOTOR_DIRECTIONS)


def test_inertia_scale_sets_the_link_inertias():
    env = MinitaurBulletEnv(dynamics_ranges={"inertia_scale": (1.5, 1.5)})
    env.reset(seed=0)
    robot = env.robot
    urdf = robot._inertias_urdf
    np.testing.assert_allclose(env.sim.inertia(robot.body, -1), 1.5 * np.array(urdf[-1]))
    leg = robot.leg_links[0]
    np.testing.assert_allclose(env.sim.inertia(robot.body, leg), 1.5 * np.array(urdf[leg]))
    env.close()


def test_joint_friction_slows_the_legs():
    extend = np.array([1, 1, 1, 1, 0.5, 0.5, 0.5, 0.5])
    travel = {}
    for friction in (0.0, 20.0):
        ranges = {**PINNED, "joint_friction": (friction, friction)}
        angles, _ = observations(
            2, action=extend, on_rack=True, randomize_dynamics=True, dynamics_ranges=ranges
        )
        travel[friction] = np.abs(angles[-1, :8] - angles[0, :8]).mean()
    assert travel[20.0] < 0.8 * travel[0.0]


def test_contact_friction_range_is_applied():
    env = MinitaurBulletEnv(dynamics_ranges={"foot_friction": (0.5, 0.5)})
    _, info = env.reset(seed=0)
    assert info["dynamics"].foot_friction == 0.5
    foot = env.robot.foot_links[0]
    assert pybullet.getDynamicsInfo(env.robot.body, foot, physicsClientId=env.sim._id)[1] == 0.5
    env.close()


# -- control step ---------------------------------------------------------------------
def test_control_step_sets_the_time_per_action():
    slow = MinitaurBulletEnv(
        realism={"control_time_step": 0.02, "pushes": True}, randomize_dynamics=False
    )
    assert slow.dt == 0.02 and slow.metadata["render_fps"] == 50
    slow.reset(seed=0)
    pushed = []
    for step in range(70):
        info = slow.step(np.zeros(8))[-1]
        if info["push_force"].any():
            pushed.append(step)
    slow.close()
    assert pushed[0] == 60  # the first push, at 1.2 s, comes at 60 steps of 20 ms, not 120
    with pytest.raises(ValueError, match="control_time_step must be a positive multiple"):
        MinitaurBulletEnv(realism={"control_time_step": 0.003})


def test_a_drawn_control_step_snaps_to_physics_steps():
    env = MinitaurBulletEnv(realism={"control_time_step": (0.003, 0.02)})
    steps = set()
    for seed in range(8):
        _, info = env.reset(seed=seed)
        drawn = info["realism"].control_time_step
        assert 0.003 <= drawn <= 0.02 and env.dt == drawn
        assert drawn / 0.002 == pytest.approx(round(drawn / 0.002), abs=1e-9)
        steps.add(round(env.dt, 3))
    assert len(steps) > 3
    env.close()


# -- pushes -----------------------------------------------------------------------------
def test_pushes_move_the_base_and_follow_the_seed():
    standing = np.zeros(8)
    runs = {}
    for name, kwargs in (
        ("still", {}),
        ("pushed", {"realism": {"pushes": {"force": (200.0, 200.0)}}}),
    ):
        _, infos = observations(135, action=standing, **kwargs)
        runs[name] = infos
    forces = [i for i, info in enumerate(runs["pushed"][1:]) if info["push_force"].any()]
    assert forces == list(range(120, 126))  # at 1.2 s, for 0.06 s (6 steps of 10 ms)
    assert np.linalg.norm(runs["pushed"][121]["push_force"]) == pytest.approx(200.0)
    moved = {
        name: np.linalg.norm(infos[-1]["base_position"][:2] - infos[118]["base_position"][:2])
        for name, infos in runs.items()
    }
    assert moved["pushed"] > 0.05 > moved["still"] * 5
    first, again, other = (
        observations(135, action=standing, seed=seed, realism={"pushes": True})[0]
        for seed in (0, 0, 1)
    )
    np.testing.assert_array_equal(again, first)  # same seed, same pushes
    assert not np.array_equal(other, first)


def test_a_push_direction_fixes_where_the_base_goes_and_keeps_the_magnitudes():
    standing = np.zeros(8)
    moved, magnitudes = {}, {}
    for direction in (None, 0.0, 90.0):
        pushes = {"force": (100.0, 150.0), "direction": direction}
        _, infos = observations(135, action=standing, realism={"pushes": pushes})
        force = infos[121]["push_force"]
        magnitudes[direction] = np.linalg.norm(force)
        moved[direction] = infos[-1]["base_position"][:2] - infos[118]["base_position"][:2]
        if direction is not None:
            angle = np.radians(direction)
            np.testing.assert_allclose(
                force[:2] / magnitudes[direction], [np.cos(angle), np.sin(angle)], atol=1e-12
            )
    assert magnitudes[None] == magnitudes[0.0] == magnitudes[90.0]  # the same draws
    assert moved[0.0][0] > 0.02 > abs(moved[0.0][1])  # forward
    assert moved[90.0][1] > 0.02 > abs(moved[90.0][0])  # to the left
    with pytest.raises(
        ValueError, match=r"Pushes\.direction must be a number in \[-360, 360\] degrees"
    ):
        Pushes(direction="left")


def test_a_push_scale_scales_the_same_draws_and_a_bad_one_is_refused():
    def pushed(scale: float | None) -> tuple[np.ndarray, float]:
        env = MinitaurBulletEnv(randomize_dynamics=False, realism={"pushes": True})
        if scale is not None:
            env.set_push_scale(scale)
        env.reset(seed=3)
        infos = [env.step(np.zeros(8))[4] for _ in range(135)]
        after = infos[-1]["base_position"][:2] - infos[118]["base_position"][:2]
        env.close()
        return infos[121]["push_force"], float(np.linalg.norm(after))

    (full, moved_full), (half, moved_half), (none, moved_none) = map(pushed, (None, 0.5, 0.0))
    assert np.linalg.norm(full) >= 130
    np.testing.assert_allclose(half, 0.5 * full, rtol=1e-12)  # the same direction and draw
    assert not none.any()
    assert moved_full > moved_half > moved_none  # and the base feels the difference
    env = MinitaurBulletEnv(realism={"pushes": True})
    assert env.push_scale == 1.0
    with pytest.raises(ValueError, match=r"push scale must be in \[0, 1\], got 1\.5"):
        env.set_push_scale(1.5)
    assert env.push_scale == 1.0
    env.close()


def test_narrowed_realism_draws_inside_the_new_ranges_and_a_range_outside_is_refused():
    def draws(narrow: dict | None) -> list[tuple[float, float]]:
        env = MinitaurBulletEnv(preset="tan2018")
        if narrow is not None:
            env.narrow_realism(narrow)
        drawn = []
        for seed in range(12):
            realism = env.reset(seed=seed)[1]["realism"]
            drawn.append((realism.control_time_step, realism.control_latency))
        env.close()
        return drawn

    hard = {"control_time_step": [0.012, 0.02], "control_latency": [0.02, 0.04]}
    narrowed, own = draws(hard), draws(None)
    assert all(0.012 - 1e-9 <= step <= 0.02 and 0.02 <= late <= 0.04 for step, late in narrowed)
    # The control: the preset's own ranges draw below both lower ends.
    assert any(step < 0.012 for step, _ in own) and any(late < 0.02 for _, late in own)
    env = MinitaurBulletEnv(preset="tan2018")
    before = env.realism
    for bad, message in (
        (
            {"control_latency": [0.0, 0.06]},
            r"control_latency \(0.0, 0.06\) is not inside the env's own \(0.0, 0.04\)",
        ),
        ({"pushes": True}, "takes a mapping of drawn realism fields"),
        ({}, "takes a mapping of drawn realism fields"),
    ):
        with pytest.raises(ValueError, match=message):
            env.narrow_realism(bad)
    assert env.realism == before  # a refusal changes nothing
    classic = MinitaurBulletEnv()
    with pytest.raises(ValueError, match=r"control_time_step \(0.012, 0.02\) is not inside"):
        classic.narrow_realism({"control_time_step": [0.012, 0.02]})  # the classic 10 ms is fixed
    env.close()
    classic.close()


# -- IMU --------------------------------------------------------------------------------
def test_euler_conversions_match_pybullet():
    rng = np.random.default_rng(0)
    for _ in range(20):
        quaternion = rng.normal(size=4)
        quaternion /= np.linalg.norm(quaternion)
        euler = quaternion_to_euler(quaternion)
        np.testing.assert_allclose(euler, pybullet.getEulerFromQuaternion(quaternion), atol=1e-9)
        np.testing.assert_allclose(
            euler_to_quaternion(euler), pybullet.getQuaternionFromEuler(euler), atol=1e-9
        )


def test_imu_observation_holds_motor_angles_roll_pitch_and_rates():
    classic, _ = observations(20)
    imu, _ = observations(20, observation="imu")
    env = MinitaurBulletEnv(observation="imu")
    assert env.observation_space.shape == (12,)
    assert all(env.observation_space.contains(obs) for obs in imu)
    env.close()
    np.testing.assert_array_equal(imu[:, :8], classic[:, :8])
    for row, quaternion in zip(imu, classic[:, 24:], strict=True):
        np.testing.assert_allclose(row[8:10], quaternion_to_euler(quaternion)[:2], atol=1e-5)
    assert np.abs(imu[1:, 10:]).max() > 0.05  # the base rocks: rates are read


def test_imu_bias_shifts_and_imu_noise_spreads_roll_and_pitch():
    still = np.zeros(8)
    true, _ = observations(50, action=still, on_rack=True, observation="imu")
    biased, _ = observations(
        50, action=still, on_rack=True, observation="imu", realism={"imu_bias": 0.05}
    )
    np.testing.assert_allclose(biased[:, 8:10], true[:, 8:10] + 0.05, atol=1e-6)
    np.testing.assert_array_equal(biased[:, :8], true[:, :8])
    noisy, _ = observations(
        50, action=still, on_rack=True, observation="imu", realism={"imu_noise_stdev": 0.05}
    )
    error = noisy[:, 8:10] - true[:, 8:10]
    assert 0.035 < error.std() < 0.065 and abs(error.mean()) < 0.02
    classic_biased, _ = observations(
        5, action=still, on_rack=True, realism={"imu_bias": [0.05, 0.0, 0.0]}
    )
    classic, _ = observations(5, action=still, on_rack=True)
    rolls = [quaternion_to_euler(q)[0] for q in (classic_biased[-1, 24:], classic[-1, 24:])]
    assert rolls[0] - rolls[1] == pytest.approx(0.05, abs=1e-5)


# -- the preset -------------------------------------------------------------------------
def test_the_randomized_id_uses_tan2018_and_is_reproducible():
    spec = gym.spec("MinitaurBulletRandomized-v0")
    assert spec.reward_threshold == 15.0 and spec.kwargs == {"preset": "tan2018"}
    runs = []
    for seed in (3, 3, 4):
        env = gym.make("MinitaurBulletRandomized-v0")
        obs, info = env.reset(seed=seed)
        env.action_space.seed(0)
        series = [obs]
        for _ in range(20):
            series.append(env.step(env.action_space.sample())[0])
        runs.append((np.array(series), (info["dynamics"], info["realism"])))
        env.close()
    dynamics, realism = runs[0][1]
    assert 0 <= realism.control_latency <= 0.04 and realism.pd_latency == 0.003
    assert 0.003 <= realism.control_time_step <= 0.02
    assert all(0.8 <= s <= 1.2 for s in dynamics.motor_strength)
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    assert runs[0][1] == runs[1][1] and runs[0][1] != runs[2][1]
    assert not np.array_equal(runs[0][0], runs[2][0])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"observation": "lidar"}, "observation must be one of"),
        ({"realism": {"control_latency": -0.01}}, "control_latency must be in [0, 1] s, got -0.01"),
        ({"realism": {"imu_bias": float("nan")}}, "imu_bias must be in [-1, 1] rad, got nan"),
        ({"realism": {"imu_bias": [0.1, 0.2, 0.3, 0.4]}}, "imu_bias must be a number, three or"),
        ({"realism": {"control_latency": [0.04, 0.0]}}, "control_latency must be (low, high) with"),
        ({"realism": {"pd_latency": [0.0, 0.01, 0.02]}}, "pd_latency must be a number or (low,"),
        (
            {"realism": {"control_time_step": [0.0, 0.02]}},
            "control_time_step low must be in [0.001",
        ),
        ({"realism": "tan2019"}, "realism must be a Realism, a mapping of its fields, 'classic'"),
        ({"preset": "tan2019"}, "preset must be one of (None, 'tan2018'), got 'tan2019'"),
        # What the issue found accepted silently: each now names the value and the range.
        ({"randomize_dynamics": "no"}, "randomize_dynamics must be True or False, got 'no'"),
        ({"hard_reset": 0}, "hard_reset must be True or False, got 0"),
        (
            {"realism": {"control_latency": 1e9}},
            "control_latency must be in [0, 1] s, got 1000000000.0",
        ),
        (
            {"realism": {"pushes": {"force": [1e12, 1e12]}}},
            "Pushes.force low must be in [0, 10000] N",
        ),
        (
            {"dynamics_ranges": {"base_mass_scale": [0, 0]}},
            "base_mass_scale low must be in (0, 10]",
        ),
        (
            {"dynamics_ranges": {"control_step": [3, 20]}},
            "control_time_step low must be in [0.001, 0.1] s",
        ),
        (
            {"realism": {"control_time_step": 10}},
            "control_time_step must be in [0.001, 0.1] s, got 10",
        ),
        (
            {"realism": {"control_time_step": "fast"}},
            "control_time_step must be a number in [0.001, 0.1] s",
        ),
        (
            {"realism": {"control_time_step": float("nan")}},
            "control_time_step must be in [0.001, 0.1] s, got nan",
        ),
        ({"energy_weight": "0.1"}, "energy_weight must be a number in [0, inf)"),
        ({"distance_limit": float("nan")}, "distance_limit must be in (0, inf]"),
        ({"width": True}, "width must be an int in [1, 4096], got True"),
        ({"realism": {"latency": 0.02}}, "Realism has no field 'latency'"),
        ({"realism": 0.02}, "realism must be a Realism, a mapping of its fields"),
        (
            {"realism": {"control_latency": 0.02}, "control_latency": 0.01},
            "control_latency is given twice",
        ),
        ({"dynamics_ranges": {"stiffness": (0, 1)}}, "DynamicsRanges has no field 'stiffness'"),
        ({"dynamics_ranges": "tan2019"}, "dynamics_ranges must be a DynamicsRanges"),
        ({"dynamics_ranges": {"motor_strength": 0.8}}, "motor_strength must be (low, high)"),
        ({"realism": {"pushes": {"interval": 0.05}}}, "Pushes needs 0 < duration <= interval"),
        ({"motor_control": "position", "realism": {"pd_latency": 0.003}}, "need a motor model"),
        ({"motor_control": "position", "realism": {"control_time_step": (0.01, 0.02)}}, "need a"),
        (
            {
                "dynamics_ranges": {"control_latency": [0, 0.04]},
                "realism": {"control_latency": 0.02},
            },
            "control_latency is given twice, in dynamics_ranges and in realism",
        ),
    ],
)
def test_bad_knobs_are_one_clear_error(kwargs, message):
    with pytest.raises(ValueError) as error:
        MinitaurBulletEnv(**kwargs)
    assert message in str(error.value) and "\n" not in str(error.value)


def test_pushes_default_to_tan2018():
    assert Pushes.coerce(True) == Pushes(force=(130.0, 220.0), interval=1.2, duration=0.06)


def test_the_deprecated_flat_keywords_warn_in_one_line_and_make_the_same_env():
    flat = {"control_latency": 0.02, "pd_latency": 0.004, "imu_bias": 0.01, "pushes": True}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the realism mapping warns about nothing
        grouped, _ = observations(steps=40, realism=flat)
    with pytest.warns(FutureWarning) as caught:
        aliased, _ = observations(steps=40, **flat)
    (warning,) = caught
    assert "will be removed after 0.3; give realism={'control_latency': 0.02" in str(
        warning.message
    )
    assert "\n" not in str(warning.message)
    with pytest.warns(FutureWarning):
        both, _ = observations(steps=40, realism=Realism(**flat), control_latency=0.02)
    nominal, _ = observations(steps=40)
    np.testing.assert_array_equal(grouped, aliased)
    np.testing.assert_array_equal(grouped, both)  # the same value given twice is no conflict
    assert not np.array_equal(grouped[1:], nominal[1:])  # the knobs are applied
    env = MinitaurBulletEnv(realism=flat)
    assert env.realism == Realism(**flat) and env.realism.imu_bias == (0.01, 0.01, 0.01)
    assert env.realism.pushes == Pushes()
    env.close()


def test_ranges_moved_out_of_dynamics_ranges_warn_and_draw_the_same_episodes():
    ranges = {
        "control_step": [0.003, 0.02],
        "control_latency": [0.0, 0.04],
        "imu_bias": [-0.05, 0.05],
    }
    with pytest.warns(FutureWarning, match="dynamics_ranges control_latency, control_step, imu_b"):
        old = MinitaurBulletEnv(dynamics_ranges={**ranges, "motor_strength": [0.8, 1.2]})
    new = MinitaurBulletEnv(
        dynamics_ranges={"motor_strength": [0.8, 1.2]},
        realism={
            "control_time_step": [0.003, 0.02],
            "control_latency": [0.0, 0.04],
            "imu_bias": [-0.05, 0.05],
        },
    )
    assert old.realism == new.realism and old.dynamics_ranges == new.dynamics_ranges
    for env in (old, new):
        env.action_space.seed(0)
    runs = [
        [env.reset(seed=5)[1]["realism"]] + [env.step(np.zeros(8))[0] for _ in range(5)]
        for env in (old, new)
    ]
    assert runs[0][0] == runs[1][0]
    np.testing.assert_array_equal(np.array(runs[0][1:]), np.array(runs[1][1:]))
    old.close()
    new.close()


def test_a_realism_range_is_drawn_per_episode_and_a_value_is_not():
    env = MinitaurBulletEnv(randomize_dynamics=False, realism={"control_latency": (0.0, 0.04)})
    drawn = [env.reset(seed=seed)[1]["realism"].control_latency for seed in (0, 0, 1, 2)]
    assert drawn[0] == drawn[1] and len(set(drawn)) == 3
    assert all(0.0 <= latency <= 0.04 for latency in drawn)
    env.close()
    fixed = MinitaurBulletEnv(randomize_dynamics=False, realism={"control_latency": 0.02})
    assert "realism" not in fixed.reset(seed=0)[1]  # control: nothing drawn, nothing reported
    fixed.close()


@pytest.mark.parametrize(
    ("kwargs", "warned"),
    [
        ({"dynamics_ranges": "tan2018"}, "draws Table I's physical parameters only since 0.3"),
        ({"preset": "tan2018", "dynamics_ranges": "classic"}, "add realism='classic'"),
        ({"dynamics_ranges": "tan2018", "realism": "tan2018"}, None),
        ({"preset": "tan2018", "dynamics_ranges": "classic", "realism": "classic"}, None),
    ],
)
def test_a_named_dynamics_ranges_says_where_its_old_meaning_changed(kwargs, warned):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        MinitaurBulletEnv(**kwargs).close()
    messages = [str(warning.message) for warning in caught if warning.category is FutureWarning]
    assert len(messages) == (0 if warned is None else 1)
    assert warned is None or warned in messages[0]


def test_the_preset_is_a_base_that_what_is_given_sets_fields_of():
    plain = MinitaurBulletEnv(preset="tan2018")
    assert plain.realism == dataclasses.replace(Realism.tan2018(), pd_latency=0.003)
    assert plain.dynamics_ranges == DynamicsRanges.tan2018()
    mixed = MinitaurBulletEnv(
        preset="tan2018",
        dynamics_ranges={"motor_strength": [0.8, 0.8]},
        realism={"control_latency": 0.02},
    )
    assert mixed.dynamics_ranges.motor_strength == (0.8, 0.8)
    assert mixed.dynamics_ranges.inertia_scale == DynamicsRanges.tan2018().inertia_scale
    assert mixed.realism.control_latency == 0.02
    assert mixed.realism.control_time_step == Realism.tan2018().control_time_step
    classic = MinitaurBulletEnv(preset="tan2018", dynamics_ranges="classic", realism="classic")
    assert classic.dynamics_ranges == DynamicsRanges() and classic.realism == Realism()
    for env in (plain, mixed, classic):
        env.close()


def test_the_randomized_id_keeps_its_latency_under_a_realism_mapping():
    env = gym.make("MinitaurBulletRandomized-v0", realism={"control_latency": 0.02})
    realism = env.unwrapped.realism
    assert realism.pd_latency == 0.003 and realism.control_latency == 0.02
    env.close()


def test_heading_pushes_turn_with_the_robot_and_the_bound_spares_the_axis():
    rng = np.random.default_rng
    forward = Pushes(force=(150.0, 150.0), direction=0.0, heading=True)
    np.testing.assert_allclose(forward.draw(rng(0), yaw=np.pi / 2)[:2], [0.0, 150.0], atol=1e-9)
    world = Pushes(force=(150.0, 150.0), direction=0.0)  # control: world +x whatever the yaw
    np.testing.assert_allclose(world.draw(rng(0), yaw=np.pi / 2)[:2], [150.0, 0.0], atol=1e-9)
    capped = Pushes(force=(100.0, 150.0), heading=True, bound=(200.0, 80.0))
    free = Pushes(force=(100.0, 150.0), heading=True)
    yaw = 0.7
    axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    reach, uncapped_sides = [], []
    for seed in range(400):
        force, uncapped = capped.draw(rng(seed), yaw), free.draw(rng(seed), yaw)
        along = force @ axis
        across = np.linalg.norm(force - along * axis)
        reach.append(np.hypot(along / 200.0, across / 80.0))
        uncapped_sides.append(np.linalg.norm(uncapped - (uncapped @ axis) * axis))
        np.testing.assert_allclose(
            force / np.linalg.norm(force), uncapped / np.linalg.norm(uncapped)
        )
        if abs(along) > 0.99 * np.linalg.norm(force):  # along the body: the force as drawn
            assert np.linalg.norm(force) == pytest.approx(np.linalg.norm(uncapped))
    assert max(reach) <= 1 + 1e-9 and max(reach) > 0.99  # inside the ellipse, up to its edge
    assert max(uncapped_sides) > 140.0  # control: without the bound the sides get it all
    assert Pushes.coerce("sagittal") == Pushes(heading=True, bound=(130.0, 60.0))
    assert Pushes.coerce("walking") == Pushes(heading=True, bound=(40.0, 20.0))
    with pytest.raises(ValueError, match="pushes must be True, 'tan2018', 'sagittal', 'walking'"):
        Pushes.coerce("trotting")
    assert Pushes.coerce("tan2018") == Pushes.coerce(True) == Pushes()
    with pytest.raises(ValueError, match=r"Pushes\.bound across must be in \(0, 10000\] N"):
        Pushes(bound=(130.0, 0.0))
    with pytest.raises(ValueError, match=r"Pushes\.bound must be \(along, across\)"):
        Pushes(bound=80.0)
    with pytest.raises(ValueError, match=r"Pushes\.heading must be True or False"):
        Pushes(heading="yes")


def test_the_env_pushes_along_the_robots_heading(monkeypatch):
    env = MinitaurBulletEnv(
        randomize_dynamics=False,
        realism={"pushes": {"force": [100, 100], "direction": 0, "heading": True}},
    )
    env.reset(seed=0)
    turned = tuple(euler_to_quaternion(np.array([0.0, 0.0, np.pi / 2])))
    position, _ = env.robot.base_pose()
    monkeypatch.setattr(env.robot, "base_pose", lambda: (position, turned))
    forces = [env.step(np.zeros(8))[4]["push_force"] for _ in range(122)]
    pushed = next(force for force in forces if force.any())
    np.testing.assert_allclose(pushed[:2], [0.0, 100.0], atol=1e-6)  # the robot's forward: +y
    env.close()
