"""Overlapped updates: the same gradient steps, run while the env computes the next step."""

from __future__ import annotations

import numpy as np
import torch
import yaml
from stable_baselines3 import SAC
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import SubprocVecEnv

from minitaur_env.training.config import load_model
from minitaur_env.training.pipeline import OverlappingVecEnv, overlapped
from tests.scripts import TINY, run_script

SMALL_SAC = dict(
    learning_starts=30, batch_size=16, buffer_size=1000, seed=0, device="cpu",
    policy_kwargs={"net_arch": [16]},
)  # fmt: skip


class EventLog(OverlappingVecEnv):
    """Records when actions go out and transitions come back."""

    events: list[str] = []

    def step_async(self, actions):
        self.events.append("send")
        super().step_async(actions)

    def step_wait(self):
        result = super().step_wait()
        self.events.append("receive")
        return result


def logging_sac(events):
    class LoggingSAC(SAC):
        def train(self, gradient_steps, batch_size=64):
            events.append(f"train {gradient_steps}")
            super().train(gradient_steps, batch_size)

    return overlapped(LoggingSAC)


def test_gradient_steps_run_between_sending_actions_and_receiving_transitions():
    events = EventLog.events
    env = make_vec_env("Pendulum-v1", seed=0, vec_env_cls=EventLog)
    model = logging_sac(events)("MlpPolicy", env, train_freq=2, gradient_steps=3, **SMALL_SAC)
    model.learn(60)
    env.close()
    trained = [i for i, event in enumerate(events) if event.startswith("train")]
    # Rounds after steps 32, 34, ..., 60: each but the last runs while the next step is out.
    assert len(trained) == 15 and all(events[i] == "train 3" for i in trained)
    for i in trained[:-1]:
        assert events[i - 1] == "send" and events[i + 1] == "receive"
    assert trained[-1] == len(events) - 1  # flushed when learn() returns
    assert model._n_updates == 15 * 3


def test_overlapped_class_without_the_wrapper_is_the_original_algorithm():
    def trained(algorithm):
        model = algorithm("MlpPolicy", make_vec_env("Pendulum-v1", seed=0), **SMALL_SAC)
        model.learn(80)
        return model.policy.state_dict()

    plain, same = trained(SAC), trained(overlapped(SAC))
    assert plain.keys() == same.keys()
    for key in plain:
        torch.testing.assert_close(plain[key], same[key], rtol=0, atol=0)


def test_overlapped_training_in_a_subprocess_makes_every_update(tmp_path):
    result = run_script(
        "train.py", "-n", "150", "--overlap-updates", "--eval-freq", "150",
        "--eval-episodes", "1", "--save-freq", "0", *TINY,
        "--hyperparams", "learning_starts=50", "batch_size=32", "buffer_size=1000",
        "train_freq=1", "gradient_steps=1", "policy_kwargs={net_arch: [32]}",
        cwd=tmp_path,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    run = tmp_path / "logs" / "sac" / "MinitaurBulletEnv-v0_1"
    assert yaml.safe_load((run / "config.yml").read_text())["overlap_updates"] is True
    model = load_model(SAC, run / "final_model.zip")
    assert model.num_timesteps == 150
    assert model._n_updates == 100  # one per step after learning_starts, none lost
    action, _ = model.predict(np.zeros(28, np.float32), deterministic=True)
    assert np.all(np.isfinite(action))


def test_steps_are_those_of_a_subproc_vec_env():
    plain = make_vec_env("Pendulum-v1", n_envs=2, seed=3, vec_env_cls=SubprocVecEnv)
    overlapping = make_vec_env("Pendulum-v1", n_envs=2, seed=3, vec_env_cls=OverlappingVecEnv)
    np.testing.assert_array_equal(overlapping.reset(), plain.reset())
    ran = []
    overlapping.run_while_stepping(lambda: ran.append(1))
    actions = np.ones((2, 1), np.float32)
    np.testing.assert_array_equal(overlapping.step(actions)[0], plain.step(actions)[0])
    assert ran == [1]
    overlapping.close()
    plain.close()
