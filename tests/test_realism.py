"""The realism probe: motors at their limits and foot slip, each against a control."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import evaluate
from minitaur_env import MinitaurBulletEnv
from minitaur_env.realism import RealismProbe
from tests.scripts import REPO, error_lines, run_main


def probe_steps(env: gym.Env, actions, seed: int = 0) -> list[dict]:
    probe = RealismProbe(env)
    probe.reset(seed=seed)
    infos = []
    for action in actions:
        *_, terminated, _, info = probe.step(action)
        infos.append(info)
        if terminated:
            break
    probe.close()
    return infos


def test_a_standing_robot_neither_slips_nor_saturates_and_bang_bang_commands_saturate():
    standing = probe_steps(MinitaurBulletEnv(randomize_dynamics=False), [np.zeros(8)] * 100)
    assert all(info["motors_at_torque_limit"] == 0 for info in standing)
    assert max(info["foot_slip"] for info in standing[50:]) < 0.05  # settled: contact creep only
    # Full-range commands that flip every step ask for more current than the table gives.
    flipping = [np.full(8, (-1.0) ** step) for step in range(100)]
    infos = probe_steps(MinitaurBulletEnv(randomize_dynamics=False, on_rack=True), flipping)
    assert sum(info["motors_at_torque_limit"] > 0 for info in infos) > 20
    assert all(info["motors_at_velocity_limit"] == 0 for info in infos)  # far from 168 rad/s
    assert all(info["actions_at_limit"] == 1.0 for info in infos)
    assert all(info["actions_at_limit"] == 0.0 for info in standing)


def test_actions_at_a_limit_are_those_within_5_percent_of_the_ends():
    actions = [np.array([0.5, -0.5, 0.94, -0.94, 0.0, -0.95, 0.96, 1.0])] * 3
    infos = probe_steps(MinitaurBulletEnv(randomize_dynamics=False), actions)
    assert [info["actions_at_limit"] for info in infos] == [3 / 8] * 3  # -0.95, 0.96, 1.0


def test_behind_a_gait_prior_the_motor_actions_are_counted_not_the_policys():
    env = RealismProbe(gym.make("MinitaurBulletTrot-v0", randomize_dynamics=False))
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    differs = 0
    for _ in range(30):
        action = rng.uniform(-1, 1, env.action_space.shape)  # 11: modulation and residuals
        info = env.step(action)[-1]
        motors = env.unwrapped.commanded_action  # the 8 the leg model took
        assert info["actions_at_limit"] == np.mean(np.abs(motors) >= 0.95)
        differs += info["actions_at_limit"] != np.mean(np.abs(action) >= 0.95)
    env.close()
    assert differs > 0  # control: counting the policy's own action would read otherwise


def test_the_velocity_limit_follows_the_battery_voltage():
    env = MinitaurBulletEnv(randomize_dynamics=False, on_rack=True)
    flipping = [np.full(8, (-1.0) ** (step // 10)) for step in range(60)]
    plain = probe_steps(env, flipping)
    assert all(info["motors_at_velocity_limit"] == 0 for info in plain)
    # A 1 V battery: its no-load speed (10.5 rad/s) is within the legs' swing.
    env = MinitaurBulletEnv(randomize_dynamics=False, on_rack=True)
    env.reset(seed=0)
    env.robot.set_battery_voltage(1.0)
    probe = RealismProbe(env)
    speeds = []
    for action in flipping:
        *_, info = probe.step(action)
        speeds.append(info["motors_at_velocity_limit"])
    assert max(speeds) > 0
    probe.close()


def test_feet_slip_more_on_ice_than_on_the_classic_ground():
    trot = np.zeros(11)

    def slip(friction: float) -> float:
        ground = {"foot_friction": [friction, friction]}
        probe = RealismProbe(gym.make("MinitaurBulletTrot-v0", dynamics_ranges=ground))
        probe.reset(seed=0)
        slips = []
        for _ in range(200):
            *_, terminated, _, info = probe.step(trot)
            if not math.isnan(info["foot_slip"]):
                slips.append(info["foot_slip"])
            if terminated:
                break
        probe.close()
        return float(np.mean(slips))

    assert slip(0.05) > 2 * slip(1.0)


def test_evaluate_reports_the_realism_rows_and_refuses_a_model_without_a_motor_model(tmp_path):
    model = REPO / "pretrained/ppo/MinitaurBulletEnv-v0_1/MinitaurBulletEnv-v0.zip"
    # In this process (evaluate.main): three plays without three interpreter starts.
    result = run_main(
        evaluate.main, "--model", str(model), "--episodes", "1", "--realism", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    for label in ("steps at a torque limit", "steps at a velocity limit", "foot slip"):
        assert label in result.stdout
    plain = run_main(evaluate.main, "--model", str(model), "--episodes", "1", cwd=tmp_path)
    assert "foot slip" not in plain.stdout
    refused = run_main(
        evaluate.main,
        "--model",
        str(model),
        "--episodes",
        "1",
        "--realism",
        "--env-kwargs",
        "motor_control=pd",
        cwd=tmp_path,
    )
    assert refused.returncode == 2
    assert error_lines(refused) == [
        "evaluate.py: error: --realism on MinitaurBulletEnv-v0: the realism probe needs the "
        "DC motor model (motor_control='accurate'), got 'pd'"
    ]


@pytest.mark.parametrize("control", ["pd", "position"])
def test_the_probe_refuses_an_env_without_the_motor_model(control):
    env = MinitaurBulletEnv(motor_control=control)
    with pytest.raises(ValueError, match="needs the DC motor model"):
        RealismProbe(env)
    env.close()


def test_the_probe_only_watches_the_same_episode_unfolds_with_and_without_it():
    rng = np.random.default_rng(2)
    actions = rng.uniform(-1, 1, (60, 8))
    plain, probed = MinitaurBulletEnv(), RealismProbe(MinitaurBulletEnv())
    np.testing.assert_array_equal(plain.reset(seed=7)[0], probed.reset(seed=7)[0])
    for action in actions:
        expected, got = plain.step(action), probed.step(action)
        np.testing.assert_array_equal(got[0], expected[0])
        assert got[1] == expected[1]
    plain.close()
    probed.close()


def test_speed_uses_each_episodes_own_control_step():
    # Under the preset every episode draws its control step: 1000 steps last 3-20 s.
    from minitaur_env.training.evaluation import run_episodes

    class Still:
        def check_spaces(self, observation_space, action_space) -> None:
            pass

        def act(self, observation, deterministic=True):
            return np.zeros(11)

    env = gym.make("MinitaurBulletTrotRandomized-v0", max_episode_steps=30)
    steps = {}
    for seed in (0, 1, 2):
        env.reset(seed=seed)
        steps[seed] = env.unwrapped.dt
    assert len(set(steps.values())) > 1  # the seeds draw different control steps
    records = run_episodes(Still(), env, episodes=3, seed=0)
    for seed, record in zip(steps, records, strict=True):
        assert record["speed"] == pytest.approx(record["distance"] / (30 * steps[seed]))
    env.close()
