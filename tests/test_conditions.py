"""The episode's conditions in the observation, and PPO's critic that alone sees them."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

import minitaur_env  # noqa: F401  (registers the ids)
from minitaur_env.conditions import CONDITION_NAMES, CONDITION_RANGES, scaled_conditions
from minitaur_env.training import ExperimentConfig, UsageError

SIZE = len(CONDITION_NAMES)


def test_tan2018_ranges_span_minus_one_to_one():
    low = {name: low for name, (low, _) in CONDITION_RANGES.items()}
    high = {name: high for name, (_, high) in CONDITION_RANGES.items()}
    np.testing.assert_allclose(scaled_conditions(low), -1.0, atol=1e-6)
    np.testing.assert_allclose(scaled_conditions(high), 1.0, atol=1e-6)


def test_the_observation_ends_with_the_episodes_draws_held_all_episode():
    env = gym.make("MinitaurBulletTrotRandomized-v0", history=2, privileged=True)
    plain = gym.make("MinitaurBulletTrotRandomized-v0", history=2)
    assert env.observation_space.shape[0] == plain.observation_space.shape[0] + SIZE
    first, info = env.reset(seed=5)
    conditions = first[-SIZE:]
    step = CONDITION_NAMES.index("control_time_step")
    drawn = info["realism"].control_time_step
    assert conditions[step] == pytest.approx((drawn - 0.003) / 0.0085 - 1.0, abs=1e-5)
    strength = CONDITION_NAMES.index("motor_strength_3")
    assert conditions[strength] == pytest.approx(
        (info["dynamics"].motor_strength[3] - 0.8) / 0.2 - 1.0, abs=1e-5
    )
    observation, *_ = env.step(np.zeros(env.action_space.shape))
    np.testing.assert_array_equal(observation[-SIZE:], conditions)
    # The same seed without the flag gives the same robot observation, and another seed
    # other draws.
    np.testing.assert_array_equal(plain.reset(seed=5)[0], first[:-SIZE])
    assert not np.array_equal(env.reset(seed=6)[0][-SIZE:], conditions)
    env.close()
    plain.close()


def test_values_the_env_does_not_draw_enter_as_in_effect():
    # The classic ranges draw no inertias, motor strengths or knee frictions, and the
    # classic realism nothing: full strength, URDF inertias, the 10 ms step.
    env = gym.make("MinitaurBulletTrot-v0", privileged=True)
    conditions = dict(zip(CONDITION_NAMES, env.reset(seed=0)[0][-SIZE:], strict=True))
    assert conditions["motor_strength_0"] == pytest.approx(0.0)  # 1.0 in 0.8-1.2
    assert conditions["base_inertia_scale"] == pytest.approx(0.0)  # 1.0 in 0.5-1.5
    assert conditions["joint_friction_7"] == pytest.approx(-1.0)  # 0 N m
    assert conditions["control_time_step"] == pytest.approx((0.01 - 0.003) / 0.0085 - 1.0)
    env.close()


def test_an_env_that_draws_no_dynamics_is_refused_in_one_line():
    env = gym.make("MinitaurBulletTrot-v0", privileged=True, randomize_dynamics=False)
    with pytest.raises(ValueError, match="privileged needs dynamics drawn at every reset"):
        env.reset(seed=0)
    env.close()


def _policy():
    from minitaur_env.training.policies import PrivilegedCriticPolicy

    space = spaces.Box(-np.inf, np.inf, (40 + SIZE,), np.float32)
    actions = spaces.Box(-1.0, 1.0, (3,), np.float32)
    return PrivilegedCriticPolicy(space, actions, lambda _: 1e-3, net_arch=[16])


def test_the_actor_ignores_the_conditions_and_the_critic_reads_them():
    torch.manual_seed(0)
    policy = _policy()
    obs = torch.randn(8, 40 + SIZE)
    other_conditions = obs.clone()
    other_conditions[:, 40:] = torch.randn(8, SIZE)
    other_observation = obs.clone()
    other_observation[:, 0] += 1.0
    with torch.no_grad():
        action = policy._predict(obs, deterministic=True)
        assert torch.equal(policy._predict(other_conditions, deterministic=True), action)
        assert not torch.allclose(policy._predict(other_observation, deterministic=True), action)
        assert not torch.allclose(
            policy.predict_values(other_conditions), policy.predict_values(obs)
        )


def test_the_policy_on_an_env_without_conditions_is_refused_in_one_line():
    with pytest.raises(UsageError, match="needs an env whose observation ends with the episode"):
        ExperimentConfig.resolve(
            "ppo",
            "MinitaurBulletTrotRandomized-v0",
            hyperparams={"policy": "PrivilegedCriticPolicy"},
            env_kwargs={"history": 2},
        )
    with pytest.raises(UsageError, match="PrivilegedCriticPolicy is PyTorch's"):
        ExperimentConfig.resolve(
            "ppo",
            "MinitaurBulletTrotRandomized-v0",
            backend="sbx",
            hyperparams={"policy": "PrivilegedCriticPolicy"},
            env_kwargs={"privileged": True},
        )


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_trained_run_loads_without_pickles_resumes_and_exports_an_actor_blind_to_them(tmp_path):
    from minitaur_env.onnx_policy import OnnxPolicy
    from minitaur_env.training import Experiment
    from minitaur_env.training.algorithms import infer_algo
    from minitaur_env.training.evaluation import load_policy
    from minitaur_env.training.onnx_export import export_onnx

    config = ExperimentConfig.resolve(
        "ppo",
        "MinitaurBulletTrotRandomized-v0",
        hyperparams={"policy": "PrivilegedCriticPolicy", "n_steps": 32, "batch_size": 32},
        env_kwargs={"privileged": True},
        n_envs=2,
        n_timesteps=64,
        eval_freq=0,
        save_freq=32,
        vec_env="dummy",
        device="cpu",
    )
    run = Experiment.create(config, tmp_path / "logs", verbose=0).run().run
    resumed = Experiment.resume(run.path, n_timesteps=128, verbose=0).run()
    assert resumed.num_timesteps == 128
    assert infer_algo(run.final_model) == ("ppo", "sb3")
    loaded = load_policy(run.final_model, device="cpu")  # the safe loader: no pickle runs
    assert type(loaded.model.policy).__name__ == "PrivilegedCriticPolicy"
    export_onnx(run.final_model, tmp_path / "p.onnx")
    onnx = OnnxPolicy(tmp_path / "p.onnx")
    size = loaded.model.observation_space.shape[0]
    obs = np.random.default_rng(2).normal(size=(16, size)).astype(np.float32)
    got = onnx.session.run(None, {"obs": obs})[0]
    np.testing.assert_allclose(got, np.stack([loaded.act(o) for o in obs]), atol=1e-5)
    obs[:, -SIZE:] = np.random.default_rng(3).normal(size=(16, SIZE))
    np.testing.assert_allclose(onnx.session.run(None, {"obs": obs})[0], got, atol=1e-6)
