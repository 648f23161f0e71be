"""GroupedSubprocVecEnv: the same transitions as a DummyVecEnv, in several processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import TransformObservation
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from minitaur_env.training import envs
from minitaur_env.training.envs import make_training_env
from minitaur_env.training.vec_env import EnvWorkerError, GroupedSubprocVecEnv

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def dict_cartpole() -> gym.Env:
    env = gym.make("CartPole-v1")
    space = gym.spaces.Dict({"state": env.observation_space})
    return TransformObservation(env, lambda obs: {"state": obs}, space)


def rollout(vec, steps: int, seed: int):
    vec.seed(seed)
    first = vec.reset()
    actions = np.random.default_rng(seed).integers(0, 2, (steps, vec.num_envs))
    transitions = [vec.step(action) for action in actions]
    return first, transitions, vec.reset_infos


def assert_same_obs(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    else:
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("make", [lambda: gym.make("CartPole-v1"), dict_cartpole])
def test_same_transitions_as_dummy_vec_env(make):
    fns = [lambda: Monitor(make()) for _ in range(5)]
    expected = rollout(DummyVecEnv(fns), 120, seed=4)
    grouped = GroupedSubprocVecEnv(fns, n_processes=3)
    assert [len(group) for group in grouped.groups] == [2, 1, 2]
    got = rollout(grouped, 120, seed=4)
    grouped.close()

    assert_same_obs(got[0], expected[0])
    dones = 0
    for (obs, rew, done, infos), (e_obs, e_rew, e_done, e_infos) in zip(
        got[1], expected[1], strict=True
    ):
        assert_same_obs(obs, e_obs)
        np.testing.assert_array_equal(rew, e_rew)
        np.testing.assert_array_equal(done, e_done)
        dones += done.sum()
        for info, e_info in zip(infos, e_infos, strict=True):
            assert info.keys() == e_info.keys()
            if "terminal_observation" in e_info:
                assert_same_obs(info["terminal_observation"], e_info["terminal_observation"])
                assert info["episode"] == {**e_info["episode"], "t": info["episode"]["t"]}
    assert dones > 5  # episodes ended and were reset inside the groups
    assert len(got[2]) == 5


def test_minitaur_runs_grouped_like_in_one_process():
    grouped = make_training_env("MinitaurBulletEnv-v0", n_envs=3, seed=1, vec_env="grouped")
    single = make_training_env("MinitaurBulletEnv-v0", n_envs=3, seed=1, vec_env="dummy")
    assert isinstance(grouped.venv, GroupedSubprocVecEnv)
    np.testing.assert_array_equal(grouped.reset(), single.reset())
    actions = np.random.default_rng(0).uniform(-1, 1, (20, 3, 8)).astype(np.float32)
    for action in actions:
        obs, rewards, _, _ = grouped.step(action)
        expected_obs, expected_rewards, _, _ = single.step(action)
        np.testing.assert_array_equal(obs, expected_obs)
        np.testing.assert_array_equal(rewards, expected_rewards)
    grouped.close()
    single.close()


@pytest.mark.parametrize("cores", [1, 2, 8])
def test_auto_groups_several_envs_on_several_cores_and_keeps_one_in_process(monkeypatch, cores):
    monkeypatch.setattr(envs, "available_cores", lambda: cores)
    several = make_training_env("CartPole-v1", n_envs=2, seed=0)
    one = make_training_env("CartPole-v1", n_envs=1, seed=0)
    assert isinstance(several.venv, GroupedSubprocVecEnv if cores > 1 else DummyVecEnv)
    assert isinstance(one.venv, DummyVecEnv)
    several.close()
    one.close()


def test_per_env_access_reaches_the_right_process():
    vec = make_vec_env("CartPole-v1", n_envs=4, vec_env_cls=GroupedSubprocVecEnv)
    vec.set_attr("marker", 7, indices=[3, 0])
    vec.set_attr("marker", 1, indices=[1, 2])
    assert vec.get_attr("marker") == [7, 1, 1, 7]
    assert vec.get_attr("marker", indices=[3, 1]) == [7, 1]
    assert vec.env_method("get_wrapper_attr", "marker", indices=2) == [1]
    assert vec.env_is_wrapped(Monitor) == [True] * 4
    assert vec.env_is_wrapped(TransformObservation, indices=[2]) == [False]
    vec.close()
    vec.close()  # twice is fine


def test_renders_every_env():
    vec = make_vec_env(
        "minitaur_env:MinitaurBulletEnv-v0",
        n_envs=3,
        vec_env_cls=GroupedSubprocVecEnv,
        env_kwargs={"render_mode": "rgb_array", "width": 64, "height": 48},
    )
    vec.reset()
    images = vec.get_images()
    assert len(images) == 3 and all(image.shape == (48, 64, 3) for image in images)
    assert all(image.std() > 0 for image in images)
    vec.close()


def test_rejects_bad_sizes():
    with pytest.raises(ValueError, match="at least one env"):
        GroupedSubprocVecEnv([])
    with pytest.raises(ValueError, match="n_processes must be at least 1"):
        GroupedSubprocVecEnv([lambda: gym.make("CartPole-v1")], n_processes=-1)


# -- failures, with more worker processes than this machine has cores ------------------


class FailsAtStep(gym.Wrapper):
    """CartPole that raises RuntimeError at its ``fail_at``-th step (never if None)."""

    def __init__(self, fail_at: int | None = None, hang: bool = False) -> None:
        super().__init__(gym.make("CartPole-v1"))
        self.fail_at, self.hang, self.steps = fail_at, hang, 0

    def step(self, action):
        self.steps += 1
        if self.steps == self.fail_at:
            if self.hang:
                time.sleep(3600)
            raise RuntimeError(f"boom at step {self.steps}")
        return super().step(action)


def failing_envs(index: int, n_envs: int = 6, **kwargs):
    return [
        (lambda i=i: Monitor(FailsAtStep(30 if i == index else None, **kwargs)))
        for i in range(n_envs)
    ]


def step_until_error(vec, steps=100):
    vec.reset()
    for _ in range(steps):
        vec.step(np.zeros(vec.num_envs, dtype=int))


@pytest.mark.parametrize("index", [4, 0], ids=["in-a-worker", "in-the-calling-process"])
def test_an_env_exception_names_the_env_and_close_returns(index):
    vec = GroupedSubprocVecEnv(failing_envs(index), n_processes=3)
    assert len(vec.processes) == 2  # 3 processes on this 2-core machine, forced
    with pytest.raises(
        EnvWorkerError, match=rf"^env {index} raised RuntimeError: boom at step 30$"
    ):
        step_until_error(vec)
    started = time.monotonic()
    vec.close()
    assert time.monotonic() - started < 60  # not the stuck env's hour, however slow
    assert not any(process.is_alive() for process in vec.processes)


def test_a_dead_worker_is_reported_not_waited_for():
    vec = GroupedSubprocVecEnv(failing_envs(-1), n_processes=3)
    vec.reset()
    os.kill(vec.processes[1].pid, signal.SIGKILL)
    with pytest.raises(EnvWorkerError, match=r"worker process of envs 4\.\.5 exited"):
        step_until_error(vec)
    started = time.monotonic()
    vec.close()
    assert time.monotonic() - started < 60  # not the stuck env's hour, however slow


def test_close_never_blocks_on_unread_answers_or_a_stuck_env():
    # Actions sent and answers never read, as when Ctrl-C lands inside step_wait.
    vec = GroupedSubprocVecEnv(failing_envs(-1), n_processes=3)
    vec.reset()
    vec.step_async(np.zeros(6, dtype=int))
    vec._receive(0)  # one worker answered, the other did not
    started = time.monotonic()
    vec.close()
    assert time.monotonic() - started < 60  # not the stuck env's hour, however slow

    stuck = GroupedSubprocVecEnv(failing_envs(5, hang=True), n_processes=3, close_timeout=1.0)
    stuck.reset()
    for _ in range(29):
        stuck.step(np.zeros(6, dtype=int))
    stuck.step_async(np.zeros(6, dtype=int))  # env 5 never returns from its 30th step
    started = time.monotonic()
    stuck.close()
    assert time.monotonic() - started < 60  # close_timeout, not the hour of the stuck env
    assert not any(process.is_alive() for process in stuck.processes)


def test_workers_leave_ctrl_c_and_sigterm_to_the_caller():
    vec = GroupedSubprocVecEnv(failing_envs(-1), n_processes=3)
    vec.reset()
    for process in vec.processes:
        os.kill(process.pid, signal.SIGINT)
        os.kill(process.pid, signal.SIGTERM)
    time.sleep(0.5)
    assert all(process.is_alive() for process in vec.processes)
    obs, *_ = vec.step(np.zeros(6, dtype=int))  # still serving
    assert obs.shape == (6, 4)
    vec.close()


LEFT_OPEN = """
import gymnasium as gym
from minitaur_env.training.vec_env import GroupedSubprocVecEnv

if __name__ == "__main__":
    vec = GroupedSubprocVecEnv([lambda: gym.make("CartPole-v1")] * 4, n_processes=3)
    vec.reset()
    raise SystemExit("ended with its env open")
"""


def test_a_script_that_ends_with_its_env_open_still_exits(tmp_path):
    script = tmp_path / "left_open.py"
    script.write_text(LEFT_OPEN)
    # Without the exit handler this run waits forever on workers that ignore SIGTERM.
    ended = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=300
    )
    assert ended.returncode == 1 and ended.stderr.splitlines()[-1] == "ended with its env open"
