"""Export an SBX (JAX) SAC model as an SB3 (PyTorch) SAC model with the same weights.

SBX saves its flax modules pickled, which makes a (256, 256) SAC zip about 9 MB; the
SB3 zip of the same networks is about 3 MB and loads without JAX. The two share their
architecture (ReLU MLPs; the actor's mean and log-std heads; two Q-networks on
[obs, action]), so the weights map one to one.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC


def _dense_layers(params: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """(kernel, bias) of Dense_0, Dense_1, ... in order."""
    names = sorted((k for k in params if k.startswith("Dense_")), key=lambda k: int(k[6:]))
    return [(np.asarray(params[n]["kernel"]), np.asarray(params[n]["bias"])) for n in names]


def _copy_linear(layer: torch.nn.Linear, kernel: np.ndarray, bias: np.ndarray) -> None:
    with torch.no_grad():
        layer.weight.copy_(torch.as_tensor(kernel.T.copy()))
        layer.bias.copy_(torch.as_tensor(bias.copy()))


def _copy_critics(critic: Any, params: Any) -> None:
    layers = _dense_layers(params["params"]["VmapContinuousCritic_0"])
    for index, q_net in enumerate(critic.q_networks):
        linears = [m for m in q_net if isinstance(m, torch.nn.Linear)]
        for linear, (kernel, bias) in zip(linears, layers, strict=True):
            _copy_linear(linear, kernel[index], bias[index])


def sbx_sac_to_sb3(model: Any, env: gym.Env) -> SAC:
    """An SB3 SAC with ``model``'s actor, critics, target critics and entropy coefficient."""
    net_arch = list(model.actor.net_arch)
    sb3 = SAC(
        "MlpPolicy",
        env,
        policy_kwargs={"net_arch": net_arch},
        gamma=model.gamma,
        batch_size=model.batch_size,
        tau=model.tau,
        learning_starts=0,
        device="cpu",
    )
    actor_layers = _dense_layers(model.policy.actor_state.params["params"])
    hidden = [m for m in sb3.actor.latent_pi if isinstance(m, torch.nn.Linear)]
    targets = [*hidden, sb3.actor.mu, sb3.actor.log_std]
    for linear, (kernel, bias) in zip(targets, actor_layers, strict=True):
        _copy_linear(linear, kernel, bias)
    _copy_critics(sb3.critic, model.policy.qf_state.params)
    _copy_critics(sb3.critic_target, model.policy.qf_state.target_params)
    entropy = getattr(model, "ent_coef_state", None)
    if entropy is not None and sb3.log_ent_coef is not None:
        log_coef = float(np.asarray(entropy.params["log_ent_coef"]))
        with torch.no_grad():
            sb3.log_ent_coef.fill_(log_coef)
    sb3.num_timesteps = model.num_timesteps
    return sb3
