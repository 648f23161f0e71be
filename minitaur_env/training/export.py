"""Export an SBX (JAX) SAC or TQC model as an SB3 / sb3-contrib (PyTorch) one, same weights.

SBX saves its flax modules pickled, which makes a (256, 256) SAC zip about 9 MB; the
SB3 zip of the same networks is about 3 MB and loads without JAX. The two share their
architecture (ReLU MLPs; the actor's mean and log-std heads; critics on [obs, action],
Q-values for SAC, quantiles for TQC), so the weights map one to one.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import TQC
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm


def _dense_layers(params: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """(kernel, bias) of Dense_0, Dense_1, ... in order."""
    names = sorted((k for k in params if k.startswith("Dense_")), key=lambda k: int(k[6:]))
    return [(np.asarray(params[n]["kernel"]), np.asarray(params[n]["bias"])) for n in names]


def _copy_linear(layer: torch.nn.Linear, kernel: np.ndarray, bias: np.ndarray) -> None:
    with torch.no_grad():
        layer.weight.copy_(torch.as_tensor(kernel.T.copy()))
        layer.bias.copy_(torch.as_tensor(bias.copy()))


def _copy_mlp(q_net: torch.nn.Module, params: Any, index: int | None = None) -> None:
    linears = [m for m in q_net if isinstance(m, torch.nn.Linear)]
    for linear, (kernel, bias) in zip(linears, _dense_layers(params), strict=True):
        if index is None:
            _copy_linear(linear, kernel, bias)
        else:
            _copy_linear(linear, kernel[index], bias[index])


def _copy_actor(sb3: SAC | TQC, params: Any) -> None:
    hidden = [m for m in sb3.actor.latent_pi if isinstance(m, torch.nn.Linear)]
    targets = [*hidden, sb3.actor.mu, sb3.actor.log_std]
    for linear, (kernel, bias) in zip(targets, _dense_layers(params["params"]), strict=True):
        _copy_linear(linear, kernel, bias)


def _copy_entropy_coefficient(sb3: SAC | TQC, model: Any) -> None:
    entropy = getattr(model, "ent_coef_state", None)
    if entropy is not None and sb3.log_ent_coef is not None:
        log_coef = float(np.asarray(entropy.params["log_ent_coef"]))
        with torch.no_grad():
            sb3.log_ent_coef.fill_(log_coef)


def sbx_to_sb3(model: Any, env: gym.Env) -> BaseAlgorithm:
    """An SB3 SAC or sb3-contrib TQC with ``model``'s actor, critics, target critics and
    entropy coefficient; ``model`` is an SBX SAC or TQC."""
    name = type(model).__name__
    if name not in ("SAC", "TQC"):
        raise ValueError(f"only SBX SAC and TQC export to SB3, not {name}")
    common = {
        "gamma": model.gamma,
        "batch_size": model.batch_size,
        "tau": model.tau,
        "learning_starts": 0,
        "device": "cpu",
    }
    net_arch = {"pi": list(model.policy.net_arch_pi), "qf": list(model.policy.net_arch_qf)}
    if name == "TQC":
        policy = model.policy
        sb3 = TQC(
            "MlpPolicy",
            env,
            top_quantiles_to_drop_per_net=policy.top_quantiles_to_drop_per_net,
            policy_kwargs={
                "net_arch": net_arch,
                "n_quantiles": policy.n_quantiles,
                "n_critics": policy.n_critics,
            },
            **common,
        )
        for index, state in enumerate((policy.qf1_state, policy.qf2_state)):
            _copy_mlp(sb3.critic.q_networks[index], state.params["params"])
            _copy_mlp(sb3.critic_target.q_networks[index], state.target_params["params"])
    else:
        sb3 = SAC("MlpPolicy", env, policy_kwargs={"net_arch": net_arch}, **common)
        critics = model.policy.qf_state
        for index, q_net in enumerate(sb3.critic.q_networks):
            _copy_mlp(q_net, critics.params["params"]["VmapContinuousCritic_0"], index)
        for index, q_net in enumerate(sb3.critic_target.q_networks):
            _copy_mlp(q_net, critics.target_params["params"]["VmapContinuousCritic_0"], index)
    _copy_actor(sb3, model.policy.actor_state.params)
    _copy_entropy_coefficient(sb3, model)
    sb3.num_timesteps = model.num_timesteps
    return sb3
