"""The SB3/SBX internals the package relies on, each checked so that an upgrade that renames
one fails here, loudly, instead of misbehaving in a training run. pyproject pins the
versions these pass on."""

from __future__ import annotations

import inspect
import zipfile

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecCheckNan

from minitaur_env.training.callbacks import ResumableEvalCallback
from minitaur_env.training.safe_load import embed_evaluation
from tests.scripts import needs


def pendulum() -> DummyVecEnv:
    return DummyVecEnv([lambda: gym.make("Pendulum-v1")])


def test_vec_env_keeps_the_next_resets_seeds_and_options_where_grouping_reads_them():
    # GroupedSubprocVecEnv hands each worker its slice of _seeds/_options, then resets them.
    env = pendulum()
    env.seed(7)
    env.set_options({"x": 1})
    assert env._seeds == [7] and env._options == [{"x": 1}]
    env._reset_seeds()
    env._reset_options()
    assert env._seeds == [None] and env._options == [{}]
    env.close()


def test_vec_check_nan_checks_through_check_val():
    # NanGuard overrides _check_val(event, **kwargs) to raise TrainingDiverged.
    parameters = inspect.signature(VecCheckNan._check_val).parameters
    assert list(parameters)[:2] == ["self", "event"]
    assert any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())


def test_eval_callback_keeps_the_history_a_resume_restores(tmp_path):
    callback = EvalCallback(pendulum(), eval_freq=10)
    for name in (
        "evaluations_timesteps",
        "evaluations_results",
        "evaluations_length",
        "best_mean_reward",
        "n_calls",
    ):
        assert hasattr(callback, name), name
    evaluations = tmp_path / "evaluations.npz"
    np.savez(
        evaluations,
        timesteps=np.array([10, 20]),
        results=np.array([[1.0], [3.0]]),
        ep_lengths=np.array([[5], [5]]),
    )
    resumed = ResumableEvalCallback(pendulum(), eval_freq=10)
    resumed.continue_from(evaluations, tmp_path / "best_model.zip", steps=20, n_envs=1)
    assert resumed.evaluations_timesteps == [10, 20] and resumed.best_mean_reward == 3.0
    assert resumed.n_calls == 20


def test_a_resume_keeps_the_best_models_own_score_when_the_evaluations_lost_it(tmp_path):
    # evaluations.npz torn (set aside) or rewound past the best model's evaluation: the
    # best model's zip still says what it scored, so a worse model cannot replace it
    best_model = tmp_path / "best_model.zip"
    with zipfile.ZipFile(best_model, "w") as archive:
        archive.writestr("data", "{}")
    resumed = ResumableEvalCallback(pendulum(), eval_freq=10)
    resumed.continue_from(tmp_path / "evaluations.npz", best_model, steps=20, n_envs=1)
    assert resumed.best_mean_reward == -np.inf  # control: a zip without the record
    embed_evaluation(best_model, 30, 5.0)
    resumed.continue_from(tmp_path / "evaluations.npz", best_model, steps=20, n_envs=1)
    assert resumed.best_mean_reward == 5.0


def test_sbx_critic_parameters_are_named_as_the_sb3_export_reads_them():
    sbx = needs("sbx")
    model = sbx.SAC("MlpPolicy", "Pendulum-v1", policy_kwargs={"net_arch": [8]}, seed=0)
    assert "VmapContinuousCritic_0" in model.policy.qf_state.params["params"]
    assert "VmapContinuousCritic_0" in model.policy.qf_state.target_params["params"]
