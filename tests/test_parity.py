"""The env against trajectories recorded from the classic pybullet_envs MinitaurBulletEnv.

Tolerances are those of the reference data's README: the dynamics are chaotic, so
only the first `horizon` steps are compared entry by entry.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from minitaur_env import MinitaurBulletEnv

SEQUENCES = [f"{kind}_{i}" for kind in ("uniform", "sine", "bang") for i in range(3)] + ["zero_0"]
# Per-entry scale of the 1e-4 tolerance: angle, velocity, torque and quaternion bounds.
SCALE = np.concatenate([np.full(8, math.pi), np.full(8, 16 / 0.0954), np.full(8, 5.7), np.ones(4)])


def rollout(env: MinitaurBulletEnv, actions: np.ndarray):
    obs0, _ = env.reset(seed=0)
    observations, rewards, terminated = [], [], []
    for action in actions:
        obs, reward, term, _, _ = env.step(action.astype(np.float32))
        observations.append(obs)
        rewards.append(reward)
        terminated.append(term)
        if term:
            break
    return obs0, np.array(observations), np.array(rewards), np.array(terminated)


@pytest.fixture(scope="module")
def env():
    env = MinitaurBulletEnv(randomize_dynamics=False)
    yield env
    env.close()


@pytest.mark.parametrize("name", SEQUENCES)
def test_matches_classic_trajectory(env, reference, name):
    actions = reference[f"{name}/actions"]
    obs0, obs, rewards, terminated = rollout(env, actions)

    np.testing.assert_allclose(obs0, reference[f"{name}/obs0"], rtol=0, atol=1e-5)

    ref_terminated = reference[f"{name}/terminated"]
    horizon = min(int(reference[f"{name}/horizon"]), len(ref_terminated), len(terminated))
    deviation = np.abs(obs[:horizon] - reference[f"{name}/obs"][:horizon]) / SCALE
    assert deviation.max() <= 1e-4, f"{name}: worst deviation {deviation.max():.3g} x bound"
    np.testing.assert_allclose(
        rewards[:horizon], reference[f"{name}/rewards"][:horizon], rtol=0, atol=1e-6
    )
    np.testing.assert_array_equal(terminated[:horizon], ref_terminated[:horizon])

    classic_fall = len(ref_terminated) if ref_terminated[-1] else None
    if classic_fall is not None and classic_fall <= 60:
        assert terminated[-1], (
            f"{name}: the classic robot fell at step {classic_fall}, ours did not"
        )
        assert abs(len(terminated) - classic_fall) <= 3


def test_zero_action_stands_for_the_whole_episode(env, reference):
    _, obs, rewards, terminated = rollout(env, reference["zero_0/actions"])
    assert len(obs) == 1000 and not terminated.any()
    assert abs(rewards.sum() - reference["zero_0/rewards"].sum()) <= 1e-3
