"""The tutorials' other tasks: the shipped entries, and the zoo's ``lin_`` schedules they use."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3.common.callbacks import StopTrainingOnRewardThreshold

import train
from minitaur_env.training import Experiment, ExperimentConfig, UsageError
from minitaur_env.training.hyperparams import algorithm_kwargs
from tests.scripts import error_lines, run_main

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


def test_cartpole_reaches_475_with_the_shipped_ppo_entry(tmp_path):
    config = ExperimentConfig.resolve(
        "ppo",
        "CartPole-v1",
        eval_freq=5_000,
        eval_episodes=10,
        save_freq=0,
        vec_env="dummy",
        device="cpu",
    )
    assert config.n_envs == 8 and config.hyperparams["learning_rate"] == "lin_0.001"
    stop = StopTrainingOnRewardThreshold(reward_threshold=475, verbose=0)
    experiment = Experiment.create(
        config, tmp_path, verbose=0, progress="none", num_threads=1, after_eval=[stop]
    )
    result = experiment.run()
    assert result.status == "completed"
    with np.load(result.run.evaluations) as data:
        returns = data["results"].mean(axis=1)
    # A random policy scores ~20: the first evaluations are the control.
    assert returns[-1] >= 475 and result.num_timesteps < config.n_timesteps
    assert experiment.model.lr_schedule(0.5) == pytest.approx(0.0005)  # lin_0.001, halfway


def test_lin_schedules_decay_linearly_to_zero():
    kwargs = algorithm_kwargs(
        {"learning_rate": "lin_0.001", "clip_range": "lin_0.2", "gamma": 0.98}
    )
    assert kwargs["gamma"] == 0.98
    assert [kwargs["learning_rate"](p) for p in (1.0, 0.25, 0.0)] == pytest.approx(
        [1e-3, 2.5e-4, 0]
    )
    assert kwargs["clip_range"](0.5) == pytest.approx(0.1)


@pytest.mark.parametrize("value", ["cos_0.1", "lin_fast", "lin"])
def test_a_bad_schedule_is_one_line(value):
    with pytest.raises(UsageError, match="expected a number or lin_<number>"):
        algorithm_kwargs({"learning_rate": value})


def test_train_rejects_a_bad_schedule_in_one_line(tmp_path):
    result = run_main(
        train.main,
        "--algo",
        "ppo",
        "--env",
        "CartPole-v1",
        "--hyperparams",
        "learning_rate=cos_0.1",
        "-f",
        str(tmp_path),
        cwd=tmp_path,
    )
    assert result.returncode == 2
    assert error_lines(result) == [
        "train.py: error: learning_rate: expected a number or lin_<number> (linear decay), "
        "got 'cos_0.1'"
    ]
    assert not list(tmp_path.iterdir())  # nothing created
