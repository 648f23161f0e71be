"""Exporting an SBX SAC or TQC model to SB3 / sb3-contrib keeps its policy and critics."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from minitaur_env.onnx_policy import OnnxPolicy
from minitaur_env.training.algorithms import load_model
from minitaur_env.training.envs import make_env
from minitaur_env.training.evaluation import load_policy
from minitaur_env.training.export import sbx_to_sb3
from tests.scripts import TINY, needs, run_script

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def _jax_critic_outputs(model, obs: np.ndarray, actions: np.ndarray) -> list[np.ndarray]:
    policy = model.policy
    if hasattr(policy, "qf_state"):  # SAC: both Q-networks in one vmapped module
        return list(np.asarray(policy.qf.apply(policy.qf_state.params, obs, actions)))
    return [
        np.asarray(policy.qf.apply(s.params, obs, actions))
        for s in (policy.qf1_state, policy.qf2_state)
    ]


@pytest.mark.parametrize("algo", ["SAC", "TQC"])
def test_sbx_model_exports_to_sb3_with_the_same_actions_and_critic_outputs(algo):
    sbx = needs("sbx")
    env = make_env("MinitaurBulletEnv-v0")
    model = getattr(sbx, algo)("MlpPolicy", env, seed=3, policy_kwargs={"net_arch": [64, 64]})
    exported = sbx_to_sb3(model, env)
    assert type(exported).__name__ == algo
    obs = np.random.default_rng(0).normal(size=(32, 28)).astype(np.float32)
    expected, _ = model.predict(obs, deterministic=True)
    actions, _ = exported.predict(obs, deterministic=True)
    np.testing.assert_allclose(actions, expected, atol=1e-5)
    assert np.abs(actions).max() > 1e-3  # not a trivially zero policy
    torch_outputs = exported.critic(torch.as_tensor(obs), torch.as_tensor(actions))
    if algo == "TQC":  # (batch, critic, quantile)
        torch_outputs = torch_outputs.transpose(0, 1)
    for torch_output, jax_output in zip(
        torch_outputs, _jax_critic_outputs(model, obs, actions), strict=True
    ):
        np.testing.assert_allclose(
            torch_output.detach().numpy(), jax_output.reshape(32, -1), atol=1e-5
        )
    env.close()


def test_other_sbx_algorithms_are_refused_by_name():
    sbx = needs("sbx")
    env = make_env("MinitaurBulletEnv-v0")
    with pytest.raises(ValueError, match="not TD3"):
        sbx_to_sb3(sbx.TD3("MlpPolicy", env, seed=0, policy_kwargs={"net_arch": [8]}), env)
    env.close()


def test_shipping_an_sbx_run_writes_an_sb3_model_that_acts_like_the_chosen_one(tmp_path):
    sbx = needs("sbx")
    hyperparams = [
        "learning_starts=50",
        "buffer_size=5000",
        "batch_size=32",
        "policy_kwargs={net_arch: [16]}",
    ]
    trained = run_script(
        "train.py",
        "--algo",
        "tqc",
        "--backend",
        "sbx",
        "-n",
        "200",
        "--hyperparams",
        *hyperparams,
        "--eval-freq",
        "100",
        "--eval-episodes",
        "1",
        "--save-freq",
        "100",
        *TINY,
        cwd=tmp_path,
    )
    assert trained.returncode == 0, trained.stderr
    run = tmp_path / "logs" / "tqc" / "MinitaurBulletEnv-v0_1"
    shipped = tmp_path / "pretrained" / "tqc" / "MinitaurBulletEnv-v0_1"
    selected = run_script(
        "-m",
        "minitaur_env.ship",
        str(run),
        "--from-steps",
        "200",
        "--episodes",
        "1",
        "--select-episodes",
        "2",
        "--json",
        "report.json",
        "--ship",
        str(shipped),
        cwd=tmp_path,  # no --trust-pickle: the SBX zips load from their msgpack state
    )
    assert selected.returncode == 0, selected.stderr
    chosen = Path(json.loads((tmp_path / "report.json").read_text())["chosen"]["model"])
    policy = load_policy(shipped / "MinitaurBulletEnv-v0.zip", device="cpu")
    assert type(policy.model).__module__.startswith("sb3_contrib") and policy.backend == "sb3"
    assert policy.normalizer is not None  # the run's VecNormalize statistics came along
    original = load_model(sbx.TQC, tmp_path / chosen)  # chosen: relative to tmp_path
    obs = np.random.default_rng(1).normal(size=(16, 28)).astype(np.float32)
    expected, _ = original.predict(obs, deterministic=True)
    actions, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_allclose(actions, expected, atol=1e-5)
    provenance = yaml.safe_load((shipped / "provenance.yml").read_text())
    assert provenance["backend"] == "sbx" and "sbx_to_sb3" in provenance["exported"]["how"]
    # ...and its ONNX actor beside it, checked against the shipped zip when written.
    assert provenance["onnx"]["max_abs_action_difference_from_predict"] <= 1e-5
    onnx = OnnxPolicy(shipped / provenance["onnx"]["file"])
    np.testing.assert_allclose(
        np.stack([onnx.act(o) for o in obs]), np.stack([policy.act(o) for o in obs]), atol=1e-5
    )
    assert provenance["selection"]["seeds"] == "5000..5001"  # --select-episodes, not --episodes
    assert provenance["eval_seeds"] == "12345..12345"
    # its figures are evaluate.py's on the shipped file, statistics and all
    played = run_script(
        "evaluate.py",
        "--model",
        str(shipped / "MinitaurBulletEnv-v0.zip"),
        "--episodes",
        "1",
        "--seed",
        "12345",
        "--json",
        "played.json",
        cwd=tmp_path,
    )
    assert played.returncode == 0, played.stderr
    shown = json.loads((tmp_path / "played.json").read_text())
    assert provenance["eval_mean_return"] == round(shown["summary"]["return"]["mean"], 3)


def test_ship_refuses_zero_selection_episodes_in_one_line(tmp_path):
    refused = run_script(
        "-m",
        "minitaur_env.ship",
        str(tmp_path),
        "--select-episodes",
        "0",
        "--json",
        "report.json",
        cwd=tmp_path,
    )
    assert refused.returncode == 2
    last_line = refused.stderr.strip().splitlines()[-1]
    assert last_line.endswith("--episodes and --select-episodes must be at least 1")
    assert not (tmp_path / "report.json").exists()
