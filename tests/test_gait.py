"""The gait prior: a trotting generator the policy modulates, with residuals (PMTG)."""

from __future__ import annotations

import math
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import evaluate
import train
from minitaur_env import MinitaurBulletEnv, Trot, TrottingGait
from minitaur_env.package import main as package_main
from tests.scripts import needs, run_main

STILL = np.zeros(11)


def walk(env: gym.Env, steps: int, action: np.ndarray = STILL) -> tuple[int, dict]:
    """Play ``action`` for up to ``steps`` steps; the steps played and the last info."""
    env.reset(seed=0)
    played, terminated, truncated, info = 0, False, False, {}
    while played < steps and not (terminated or truncated):
        _, _, terminated, truncated, info = env.step(action)
        played += 1
    return played, info


@pytest.mark.parametrize("env_id", ["MinitaurBulletTrot-v0", "MinitaurBulletTrotRandomized-v0"])
def test_the_trotting_ids_pass_the_gymnasium_and_sb3_checkers(env_id):
    env = gym.make(env_id)
    assert isinstance(env.unwrapped, MinitaurBulletEnv)
    assert env.action_space.shape == (11,) and env.observation_space.shape == (30,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # Both checkers advise checking the unwrapped env; this one is the wrapper.
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version")
        gym_check_env(env.env.env, skip_render_check=True)  # below TimeLimit and the checker
        sb3_check_env(env.env.env, warn=True, skip_render_check=True)
    env.close()


def test_the_generator_alone_trots_forward_and_no_generator_stands_still():
    trotting = gym.make("MinitaurBulletTrot-v0", randomize_dynamics=False)
    steps, info = walk(trotting, 300)
    assert steps == 300 and info["base_position"][0] > 0.5  # 3 s at about 0.9 m/s
    # Negative control: with both amplitudes 0 the same zero action holds the legs still.
    still = gym.make(
        "MinitaurBulletTrot-v0", randomize_dynamics=False, gait={"extension": 0, "swing": 0}
    )
    steps, info = walk(still, 300)
    assert steps == 300 and abs(info["base_position"][0]) < 0.05
    trotting.close()
    still.close()


def test_with_no_generator_the_residuals_are_the_classic_action():
    # Amplitudes 0 and a residual range of 1: the policy's first 8 entries are the
    # classic env's action, so both envs follow the same trajectory bit for bit.
    classic = MinitaurBulletEnv(randomize_dynamics=False)
    gait = TrottingGait(
        MinitaurBulletEnv(randomize_dynamics=False), {"extension": 0, "swing": 0, "residual": 1}
    )
    rng = np.random.default_rng(0)
    first, _ = classic.reset(seed=3)
    wrapped, _ = gait.reset(seed=3)
    np.testing.assert_array_equal(wrapped[:28], first)
    for _ in range(50):
        action = rng.uniform(-1, 1, 11)
        expected = classic.step(action[:8])
        got = gait.step(action)
        np.testing.assert_array_equal(got[0][:28], expected[0])
        assert got[1] == expected[1]
    classic.close()
    gait.close()


def test_the_policy_sets_the_frequency_and_the_phase_follows_the_episodes_control_step():
    env = gym.make("MinitaurBulletTrotRandomized-v0", gait={"frequency": 2.0, "modulation": 0.5})
    observation, info = env.reset(seed=5)
    dt = env.unwrapped.dt
    # Drawn for the episode, rounded to the 2 ms physics step.
    assert dt != 0.01 and info["realism"].control_time_step == dt
    np.testing.assert_allclose(observation[-2:], [0.0, 1.0])  # sin, cos of phase 0
    faster = STILL.copy()
    faster[8] = 1.0  # frequency x (1 + 0.5)
    observation, _, _, _, info = env.step(faster)
    assert info["gait_frequency"] == pytest.approx(3.0)
    phase = 2 * math.pi * 3.0 * dt
    np.testing.assert_allclose(observation[-2:], [math.sin(phase), math.cos(phase)], atol=1e-6)
    _, _, _, _, info = env.step(STILL)
    assert info["gait_phase"] == pytest.approx(phase) and info["gait_frequency"] == 2.0
    env.close()


def test_observe_control_step_ends_each_observation_with_the_episodes_drawn_step():
    env = gym.make("MinitaurBulletTrotRandomized-v0", history=2, observe_control_step=True)
    seen = set()
    for seed in range(4):
        observation, _ = env.reset(seed=seed)
        frames = observation.reshape(2, -1)
        assert frames.shape[1] == 31  # the 28 sensors, sin and cos of the phase, the step
        observation, *_ = env.step(STILL)
        for frame in (*frames, *observation.reshape(2, -1)):
            assert frame[-1] == pytest.approx(env.unwrapped.dt / 0.01)
        assert env.observation_space.contains(observation)
        seen.add(env.unwrapped.dt)
    assert len(seen) > 1  # drawn per episode, so the policy can tell the episodes apart
    env.close()
    # The policy's period is the step times action_repeat; the space holds the longest.
    slow = gym.make(
        "MinitaurBulletTrot-v0",
        observe_control_step=True,
        action_repeat=3,
        realism={"control_time_step": 0.1},
    )
    observation, _ = slow.reset(seed=0)
    assert observation[-1] == pytest.approx(30.0)
    assert slow.observation_space.contains(observation)
    slow.close()
    # Negative control: without it the observation ends with the phase, as before.
    plain = gym.make("MinitaurBulletTrotRandomized-v0")
    assert plain.observation_space.shape == (30,)
    plain.close()
    with pytest.raises(ValueError, match=r"^observe_control_step must be True or False, got 1$"):
        gym.make("MinitaurBulletTrotRandomized-v0", observe_control_step=1)


def test_the_amplitudes_the_policy_asks_for_reach_the_legs():
    gait = TrottingGait(MinitaurBulletEnv(), {"extension": 0.4, "swing": 0.2, "modulation": 0.5})
    gait.reset(seed=0)
    wider = np.zeros(11)
    wider[9:] = 1.0
    leg_action, _ = gait.leg_action(wider)
    np.testing.assert_allclose(leg_action, Trot().leg_actions(0.0, 0.6, 0.3))
    np.testing.assert_allclose(leg_action[:4], [0.6, -0.6, -0.6, 0.6], atol=1e-12)
    gait.close()


@pytest.mark.parametrize(
    ("gait", "message"),
    [
        ({"frequency": 0}, "gait frequency must be in (0, 10] Hz, got 0"),
        ({"swing": "wide"}, "gait swing must be a number in [0, 1], got 'wide'"),
        ({"modulation": 1}, "gait modulation must be in [0, 1), got 1"),
        ({"speed": 2}, "Trot has no field 'speed'"),
        ("trot", "gait must be a mapping of Trot settings, got 'trot'"),
    ],
)
def test_bad_gait_settings_are_one_line_naming_the_setting(gait, message):
    with pytest.raises(ValueError, match="^" + re.escape(message)):
        gym.make("MinitaurBulletTrot-v0", gait=gait)


@pytest.mark.parametrize(
    ("action", "message"),
    [
        (np.zeros(8), r"action must have shape \(11,\), got \(8,\)"),
        (np.full(11, np.nan), "action must be finite"),
        (np.full(11, 1.5), r"action\[0\] = 1.5 is outside \[-1, 1\]"),
        (np.zeros(11, dtype=bool), "action must be real numbers"),
    ],
)
def test_bad_actions_are_refused_before_they_reach_the_robot(action, message):
    env = gym.make("MinitaurBulletTrot-v0").env.env  # below the passive checker
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(action)
    env.close()


def test_a_gait_prior_policy_trains_plays_and_packages_with_its_generator(tmp_path):
    needs("huggingface_hub")
    trained = run_main(
        train.main,
        "--algo",
        "ppo",
        "--env",
        "MinitaurBulletTrot-v0",
        "-n",
        "256",
        "--hyperparams",
        "n_envs=2",
        "n_steps=64",
        "batch_size=64",
        "--eval-freq",
        "0",
        "--env-kwargs",
        "max_episode_steps=40",
        "gait={frequency: 3.0}",
        "-v",
        "0",
        cwd=tmp_path,
    )
    assert trained.returncode == 0, trained.stderr
    run = tmp_path / "logs" / "ppo" / "MinitaurBulletTrot-v0_1"
    packaged = run_main(
        package_main,
        str(run / "MinitaurBulletTrot-v0.zip"),
        "-o",
        "hub",
        "--episodes",
        "1",
        "--video-steps",
        "10",
        cwd=tmp_path,
    )
    assert packaged.returncode == 0, packaged.stderr
    card = (tmp_path / "hub" / "ppo-MinitaurBulletTrot-v0" / "README.md").read_text()
    # The card makes the env the policy was trained on: the id with the run's kwargs.
    (make,) = set(re.findall(r'gym\.make\("MinitaurBulletTrot-v0".*?\)(?=\]|`)', card))
    env = eval(make, {"gym": gym})
    trot = env
    while not isinstance(trot, TrottingGait):
        trot = trot.env  # below TimeLimit and gymnasium's checkers
    assert trot.trot.frequency == 3.0
    env.close()
    assert "the gait prior's 11 entries" in card  # ONNX users learn the generator runs in the env
    # The ONNX actor plays on the same env through evaluate.py (config.yml beside it).
    played = run_main(
        evaluate.main,
        "--model",
        str(tmp_path / "hub/ppo-MinitaurBulletTrot-v0/policy.onnx"),
        "--episodes",
        "1",
        cwd=tmp_path,
    )
    assert played.returncode == 0, played.stderr
    assert "on MinitaurBulletTrot-v0" in played.stdout


@pytest.mark.parametrize(
    ("env_id", "size", "actions"),
    [("MinitaurBulletTrotRandomized-v0", 30, 11), ("MinitaurBulletEnv-v0", 28, 8)],
)
def test_history_shows_the_last_observations_newest_last(env_id, size, actions):
    single = gym.make(env_id)
    stacked = gym.make(env_id, history=3)
    assert single.observation_space.shape == (size,)  # the default is the env's own
    assert stacked.observation_space.shape == (3 * size,)
    rng = np.random.default_rng(1)
    seen = [single.reset(seed=4)[0]]
    first, _ = stacked.reset(seed=4)
    np.testing.assert_array_equal(first, np.tile(seen[0], 3))  # the first, repeated
    for _ in range(5):
        action = rng.uniform(-1, 1, actions)
        seen.append(single.step(action)[0])
        observation = stacked.step(action)[0]
        np.testing.assert_array_equal(observation[2 * size :], seen[-1])
        np.testing.assert_array_equal(observation[size : 2 * size], seen[-2])
        np.testing.assert_array_equal(observation[:size], seen[-3] if len(seen) > 2 else seen[0])
        assert not np.array_equal(observation[2 * size :], observation[size : 2 * size])
    single.close()
    stacked.close()
    with pytest.raises(ValueError, match=r"^history must be an int in \[1, 16\], got 0"):
        gym.make(env_id, history=0)


def test_the_gait_prior_is_read_from_the_env_spec_not_the_id():
    from minitaur_env.gait import has_gait_prior

    assert has_gait_prior("MinitaurBulletTrot-v0")
    assert has_gait_prior("MinitaurBulletTrotRandomized-v0")
    assert not has_gait_prior("MinitaurBulletEnv-v0")
    # an id that says "Trot" without the prior, and one with the prior that does not
    gym.register("MyTrotLookalike-v0", entry_point="minitaur_env.env:MinitaurBulletEnv")
    gym.register("MyPacer-v0", entry_point="minitaur_env.gait:make_trotting_env")
    try:
        assert not has_gait_prior("MyTrotLookalike-v0")
        assert has_gait_prior("MyPacer-v0")
    finally:
        del gym.registry["MyTrotLookalike-v0"], gym.registry["MyPacer-v0"]
