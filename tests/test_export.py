"""Exporting an SBX SAC model to SB3 keeps its policy and critics."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from minitaur_env.training.envs import make_env
from minitaur_env.training.export import sbx_sac_to_sb3


def test_sbx_sac_exports_to_sb3_with_the_same_actions_and_q_values():
    sbx = pytest.importorskip("sbx")
    env = make_env("MinitaurBulletEnv-v0")
    model = sbx.SAC("MlpPolicy", env, seed=3, policy_kwargs={"net_arch": [64, 64]})
    exported = sbx_sac_to_sb3(model, env)
    obs = np.random.default_rng(0).normal(size=(32, 28)).astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)
    actions, _ = exported.predict(obs, deterministic=True)
    np.testing.assert_allclose(actions, expected, atol=1e-5)
    assert np.abs(actions).max() > 1e-3  # not a trivially zero policy
    q_torch = exported.critic(torch.as_tensor(obs), torch.as_tensor(actions))
    q_jax = model.policy.qf.apply(model.policy.qf_state.params, obs, actions)
    for index in range(2):
        np.testing.assert_allclose(
            q_torch[index].detach().numpy().ravel(), np.asarray(q_jax[index]).ravel(), atol=1e-5
        )
    env.close()
