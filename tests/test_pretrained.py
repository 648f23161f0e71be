"""The policies shipped in pretrained/ load, fit the env and walk."""

from __future__ import annotations

import pytest
import yaml

from minitaur_env.training.envs import make_env
from minitaur_env.training.evaluation import PRETRAINED_DIR, load_policy, pretrained_models

SHIPPED = [path for _, path in pretrained_models()]


def test_something_is_shipped_with_provenance():
    assert SHIPPED, f"no policy in {PRETRAINED_DIR}"
    for path in SHIPPED:
        provenance = yaml.safe_load(path.with_suffix(".yml").read_text())
        for key in ("algo", "env", "eval_mean_return", "eval_episodes", "training"):
            assert key in provenance, (path.name, key)


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_policy_walks_forward_without_falling(path):
    policy = load_policy(path, device="cpu")
    env = make_env(policy.env_id, policy.env_kwargs)
    obs, info = env.reset(seed=2024)
    start = info["base_position"][0]
    for _ in range(300):
        obs, _, terminated, _, info = env.step(policy.act(obs))
        assert not terminated
    speed = (info["base_position"][0] - start) / 3.0
    claimed = yaml.safe_load(path.with_suffix(".yml").read_text())["eval_mean_return"]
    # The return is about metres walked in 10 s: the first 3 s should show a good part of it.
    assert speed > 0.5 * claimed / 10, f"{speed:.2f} m/s for a claimed return of {claimed}"
    env.close()
