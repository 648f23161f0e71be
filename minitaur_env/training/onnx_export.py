"""Write a trained policy's deterministic actor as ONNX, normalization folded in.

The graph maps raw float32 observations, shape (batch, obs_dim), to the action in env
units: VecNormalize's ``(obs - mean) / sqrt(var + eps)`` clipped to ``clip_obs``, the
actor's mean action, then the squashed policies' (SAC, TQC, CrossQ, TD3) rescaling from
[-1, 1] to the action bounds, or the Gaussian policies' (PPO, A2C) clipping to them.
A policy trained with ``actor_ema`` exports its averaged actor, as its deterministic
``predict`` does, and one with ``action_gain`` its multiplied and clipped action. The
deterministic heads are written out here rather than traced through SB3's distribution
objects, which torch's exporter cannot follow.

Nothing is assumed: before the file is written, onnxruntime plays the graph on
observations drawn around the training statistics and must agree with the model's own
``predict`` to ``TOLERANCE``.
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from torch import nn

from minitaur_env.onnx_policy import METADATA_KEY, load_session
from minitaur_env.training import UsageError
from minitaur_env.training.evaluation import LoadedPolicy, load_policy
from minitaur_env.training.files import atomic_path
from minitaur_env.training.policies import motor_action
from minitaur_env.training.run_folder import RunFolder

TOLERANCE = 1e-5
OPSET = 18
CHECK_OBSERVATIONS = 256


class DeterministicActor(nn.Module):
    """Normalization, the actor's mean action and the env's action units, as one module."""

    def __init__(self, loaded: LoadedPolicy) -> None:
        super().__init__()
        policy = loaded.model.policy
        if not isinstance(policy.observation_space, spaces.Box):
            raise UsageError(
                f"{loaded.path}: only flat Box observations export to ONNX, this policy "
                f"takes {policy.observation_space}"
            )
        if len(policy.observation_space.shape) != 1:
            raise UsageError(
                f"{loaded.path}: only flat observations export to ONNX (image policies do "
                f"not), this one has shape {policy.observation_space.shape}"
            )
        if not isinstance(policy.action_space, spaces.Box):
            raise UsageError(
                f"{loaded.path}: only continuous (Box) actions export to ONNX, this policy "
                f"acts in {policy.action_space}"
            )
        self.policy = policy
        self.head = _head(loaded)
        normalizer = loaded.normalizer
        obs_dim = policy.observation_space.shape[0]
        mean, scale, clip = np.zeros(obs_dim), np.ones(obs_dim), np.inf
        if normalizer is not None and normalizer.norm_obs:
            mean = normalizer.mean
            scale = np.sqrt(normalizer.var + normalizer.epsilon)
            clip = float(normalizer.clip_obs)
        # In float64, as VecNormalize computes it: float32 normalization alone moved actions
        # by 5e-6, and over 1000 chaotic steps that turned a walk into a fall.
        self.register_buffer("obs_mean", torch.as_tensor(mean, dtype=torch.float64))
        self.register_buffer("obs_scale", torch.as_tensor(scale, dtype=torch.float64))
        self.clip_obs = clip
        self.squashed = bool(policy.squash_output) or self.head != "gaussian"
        low, high = policy.action_space.low, policy.action_space.high
        self.register_buffer("low", torch.as_tensor(low, dtype=torch.float32))
        self.register_buffer("high", torch.as_tensor(high, dtype=torch.float32))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        x = (obs.to(torch.float64) - self.obs_mean) / self.obs_scale
        if np.isfinite(self.clip_obs):
            x = torch.clamp(x, -self.clip_obs, self.clip_obs)
        x = x.to(torch.float32)
        if self.head == "squashed_gaussian":  # SAC, TQC, CrossQ: tanh of the Gaussian mean
            actor = getattr(self.policy, "averaged_actor", None) or self.policy.actor
            mean, _, _ = actor.get_action_dist_params(x)
            action = motor_action(actor, torch.tanh(mean))
        elif self.head == "deterministic":  # TD3: the actor ends in tanh
            action = self.policy.actor(x)
        else:  # PPO, A2C: the Gaussian mean
            # The actor's own extractor: with share_features_extractor=False, SB3's
            # extract_features returns both the actor's and the critic's features.
            features = self.policy.pi_features_extractor(x)
            mean = self.policy.action_net(self.policy.mlp_extractor.forward_actor(features))
            action = torch.tanh(mean) if self.policy.squash_output else mean
        if self.squashed:
            return self.low + 0.5 * (action + 1.0) * (self.high - self.low)
        return torch.clamp(action, self.low, self.high)


def _head(loaded: LoadedPolicy) -> str:
    policy = loaded.model.policy
    if "Recurrent" in type(policy).__name__:  # sb3-contrib's RecurrentActorCriticPolicy
        raise UsageError(f"{loaded.path}: recurrent policies do not export to ONNX")
    if loaded.algo in ("sac", "tqc", "crossq"):
        return "squashed_gaussian"
    if loaded.algo == "td3":
        return "deterministic"
    if loaded.algo in ("ppo", "a2c"):
        return "gaussian"
    raise UsageError(f"{loaded.path}: no ONNX export for {loaded.algo}")


def export_onnx(run_or_model: Path, output: Path, trust_pickle: bool = False) -> dict[str, Any]:
    """Write ``output``; returns the metadata stored in it and the measured agreement."""
    model_path = RunFolder.model_of(run_or_model)
    loaded = load_policy(model_path, device="cpu", trust_pickle=trust_pickle)
    if loaded.backend == "sbx":
        raise UsageError(
            f"{model_path} is an SBX (JAX) model: export it to PyTorch first "
            "(minitaur ship does), then to ONNX"
        )
    actor = DeterministicActor(loaded).eval()
    obs_dim = actor.obs_mean.shape[0]
    metadata = {
        "algo": loaded.algo,
        "env_id": loaded.env_id,
        "env_kwargs": loaded.env_kwargs,
        "source": model_path.name,
        "observation_normalization": "folded" if loaded.normalizer is not None else "none",
        "deterministic": True,
    }
    # The exporter warns of every torchvision op it cannot register; none is used here.
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        program = torch.onnx.export(
            actor,
            (torch.zeros(1, obs_dim),),
            input_names=["obs"],
            output_names=["action"],
            dynamic_shapes=({0: torch.export.Dim("batch")},),
            opset_version=OPSET,
            dynamo=True,
            verbose=False,
        )
    onnx_model = program.model_proto
    entry = onnx_model.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, json.dumps(metadata)
    data = onnx_model.SerializeToString()
    metadata["max_abs_difference"] = check_agreement(loaded, data)
    output.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(output) as temp:
        temp.write_bytes(data)
    return metadata


def check_agreement(loaded: LoadedPolicy, onnx_bytes: bytes) -> float:
    """Largest action difference between onnxruntime and ``predict``; refuses above
    ``TOLERANCE``. Observations are drawn at up to 3 standard deviations of the training
    statistics, so that the clipping of both paths is exercised."""
    obs_space = loaded.model.policy.observation_space
    rng = np.random.default_rng(0)
    normalizer = loaded.normalizer
    if normalizer is not None and normalizer.norm_obs:
        center, spread = normalizer.mean, np.sqrt(normalizer.var)
    else:
        center, spread = np.zeros(obs_space.shape), np.ones(obs_space.shape)
    draws = center + rng.uniform(-3, 3, (CHECK_OBSERVATIONS, *obs_space.shape)) * spread
    observations = draws.astype(np.float32)
    expected = np.stack([loaded.act(obs) for obs in observations])
    session = load_session(onnx_bytes)
    got = session.run(None, {"obs": observations})[0]
    difference = float(np.max(np.abs(got - expected)))
    if not difference <= TOLERANCE:
        raise UsageError(
            f"{loaded.path}: the ONNX graph's actions differ from predict's by {difference:.2e} "
            f"(> {TOLERANCE:g}); not written"
        )
    return difference
