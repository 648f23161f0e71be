"""SAC policies with the stabilizers the SAC ablation measures (docs/results.md, "Stabilizing SAC").

``StabilizedMlpPolicy`` is SB3's ``SACPolicy`` with six opt-in changes, each a policy
keyword so that SB3's own ``SAC`` class trains it unchanged:

- ``critic_layer_norm``: LayerNorm after every hidden linear layer of the critics (DroQ,
  SimBa, BRO), which keeps Q-targets from running away at high learning rates;
- ``max_grad_norm``: gradient-norm clipping before every optimizer step (SB3's SAC has
  none; DLR-RM/stable-baselines3#2123);
- ``actor_ema``: an exponential moving average of the actor's weights, updated after
  every actor step, that acts whenever the policy is deterministic: evaluation, saving
  and ``evaluate.py`` see the average while exploration keeps the live actor;
- ``noise_hold``: the exploring action's Gaussian noise is drawn once every
  ``noise_hold`` steps and held in between (per env), so exploration is correlated in
  time, as SBX's SAC explores with ``use_sde`` (it reuses one noise draw per rollout).
  Updates and evaluations are unchanged.
- ``noise_color``: the exploring action's Gaussian noise is colored noise with a power
  spectrum ``1 / f ** noise_color`` per env and action dimension (Eberhard et al. 2023,
  "Pink noise is all you need"; ``pink-noise-rl``'s process, cut every 1000 steps, the
  classic time limit, as the paper sets it to the episode length): 0 is SAC's own white
  noise, 1 pink, 2 red. Between white noise and the held draw, it keeps some of the
  held noise's low frequencies without holding one draw for a whole stride. Updates
  and evaluations are unchanged.
- ``action_gain``: the actor's squashed action is multiplied by the gain and clipped to
  [-1, 1], so the motor limits are reached at ``tanh(u) = ±1/gain``, where the squashing
  costs the Gaussian little entropy, instead of at tanh's asymptote. The log-probability
  is the multiplied action's (before the clip), so the entropy target stays a target on
  the commands the robot gets: at the default's target 0 the motors' exploration noise
  is the default's, and the per-step entropy bonus stays centred on 0 (a negative target
  in the actor's own units makes ending an episode pay).

They hook into the optimizers (``register_step_pre_hook``/``register_step_post_hook``)
rather than into ``SAC.train``, so a saved model rebuilds them on load.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from pink import ColoredNoiseProcess
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.sac.policies import Actor, SACPolicy
from torch import nn

from minitaur_env.training.noise import checked_noise_color, colored_noise_process

POLICY_NAME = "StabilizedMlpPolicy"


class LayerNormCritic(ContinuousCritic):
    """SB3's twin critics with LayerNorm between each hidden linear layer and its ReLU."""

    def __init__(
        self,
        observation_space: Any,
        action_space: Any,
        net_arch: list[int],
        features_extractor: BaseFeaturesExtractor,
        features_dim: int,
        activation_fn: type[nn.Module] = nn.ReLU,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            observation_space,
            action_space,
            net_arch,
            features_extractor,
            features_dim,
            activation_fn,
            **kwargs,
        )
        action_dim = self.action_space.shape[0]
        self.q_networks = []
        for index in range(self.n_critics):
            layers = create_mlp(
                features_dim + action_dim,
                1,
                net_arch,
                activation_fn,
                post_linear_modules=[nn.LayerNorm],
            )
            q_net = nn.Sequential(*layers)
            self.add_module(f"qf{index}", q_net)  # replaces SB3's plain one of that name
            self.q_networks.append(q_net)


class GainActor(Actor):
    """SB3's actor with its squashed action multiplied by ``action_gain`` and clipped."""

    def __init__(self, *args: Any, action_gain: float, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.action_gain = action_gain
        # log|det| of the gain, once per action dimension: the multiplied action's density
        self.log_gain = self.action_space.shape[0] * math.log(action_gain)

    def motor_action(self, squashed: torch.Tensor) -> torch.Tensor:
        return torch.clamp(squashed * self.action_gain, -1.0, 1.0)

    def forward(self, obs: Any, deterministic: bool = False) -> torch.Tensor:
        return self.motor_action(super().forward(obs, deterministic))

    def action_log_prob(self, obs: Any) -> tuple[torch.Tensor, torch.Tensor]:
        squashed, log_prob = super().action_log_prob(obs)
        return self.motor_action(squashed), log_prob - self.log_gain


def motor_action(actor: Actor, squashed: torch.Tensor) -> torch.Tensor:
    """What ``actor`` acts with, from its tanh-squashed Gaussian sample or mean."""
    return actor.motor_action(squashed) if isinstance(actor, GainActor) else squashed


class StabilizedSACPolicy(SACPolicy):
    """``SACPolicy`` plus the stabilizers and exploration settings of the module's list."""

    def __init__(
        self,
        *args: Any,
        critic_layer_norm: bool = False,
        max_grad_norm: float | None = None,
        actor_ema: float | None = None,
        noise_hold: int = 1,
        noise_color: float = 0.0,
        action_gain: float = 1.0,
        **kwargs: Any,
    ) -> None:
        if isinstance(action_gain, bool) or not isinstance(action_gain, (int, float)):
            raise ValueError(f"action_gain must be a number >= 1, got {action_gain!r}")
        if not 1 <= action_gain < math.inf:
            raise ValueError(f"action_gain must be a number >= 1, got {action_gain}")
        if isinstance(noise_hold, bool) or not isinstance(noise_hold, int) or noise_hold < 1:
            raise ValueError(f"noise_hold must be a whole number of steps >= 1, got {noise_hold}")
        noise_color = checked_noise_color(noise_color)
        if noise_color and noise_hold > 1:
            raise ValueError("noise_color and noise_hold: two kinds of exploring noise; pick one")
        if max_grad_norm is not None and not max_grad_norm > 0:
            raise ValueError(f"max_grad_norm must be > 0, got {max_grad_norm}")
        if actor_ema is not None and not 0 < actor_ema < 1:
            raise ValueError(f"actor_ema is a decay in (0, 1), got {actor_ema}")
        self.critic_layer_norm = critic_layer_norm
        self.max_grad_norm = max_grad_norm
        self.actor_ema = actor_ema
        self.averaged_actor: Actor | None = None
        self.noise_hold = noise_hold
        self.action_gain = float(action_gain)
        self._held_noise: torch.Tensor | None = None
        self._held_steps = 0
        self.noise_color = noise_color
        self._colored_noise: ColoredNoiseProcess | None = None
        super().__init__(*args, **kwargs)
        if noise_hold > 1 and self.actor_kwargs.get("use_sde"):
            raise ValueError("noise_hold holds SAC's own noise; it does not combine with use_sde")
        if noise_color and self.actor_kwargs.get("use_sde"):
            raise ValueError("noise_color colors SAC's own noise; it does not combine with use_sde")

    def _build(self, lr_schedule: Any) -> None:
        super()._build(lr_schedule)
        if self.max_grad_norm is not None:
            for optimizer in (self.actor.optimizer, self.critic.optimizer):
                optimizer.register_step_pre_hook(self._clip_gradients)
        if self.actor_ema is not None:
            # A fresh actor loaded with the live one's weights: deepcopy fails on a gSDE
            # actor's exploration matrices, and the forked RNG keeps the run's random
            # stream (and so its training) the same as without the average.
            with torch.random.fork_rng(devices=[]):
                self.averaged_actor = self.make_actor()
            self.averaged_actor.load_state_dict(self.actor.state_dict())
            self.averaged_actor.requires_grad_(False)
            self.averaged_actor.set_training_mode(False)
            self.actor.optimizer.register_step_post_hook(self._update_averaged_actor)

    def make_actor(self, features_extractor: BaseFeaturesExtractor | None = None) -> Actor:
        if self.action_gain == 1:
            return super().make_actor(features_extractor)
        kwargs = self._update_features_extractor(self.actor_kwargs, features_extractor)
        return GainActor(**kwargs, action_gain=self.action_gain).to(self.device)

    def make_critic(
        self, features_extractor: BaseFeaturesExtractor | None = None
    ) -> ContinuousCritic:
        if not self.critic_layer_norm:
            return super().make_critic(features_extractor)
        kwargs = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return LayerNormCritic(**kwargs).to(self.device)

    def _clip_gradients(self, optimizer: torch.optim.Optimizer, *_: Any) -> None:
        params = [p for group in optimizer.param_groups for p in group["params"]]
        nn.utils.clip_grad_norm_(params, self.max_grad_norm)

    @torch.no_grad()
    def _update_averaged_actor(self, *_: Any) -> None:
        averaged = list(self.averaged_actor.parameters())
        torch._foreach_lerp_(averaged, list(self.actor.parameters()), 1.0 - self.actor_ema)

    def _predict(self, observation: Any, deterministic: bool = False) -> torch.Tensor:
        if deterministic and self.averaged_actor is not None:
            return self.averaged_actor(observation, deterministic=True)
        if deterministic or (self.noise_hold == 1 and not self.noise_color):
            return self.actor(observation, deterministic)
        mean, log_std, _ = self.actor.get_action_dist_params(observation)
        noise = self._colored(mean) if self.noise_color else self._held(mean)
        return motor_action(self.actor, torch.tanh(mean + log_std.exp() * noise))

    def _held(self, mean: torch.Tensor) -> torch.Tensor:
        held = self._held_noise
        if held is None or held.shape != mean.shape or self._held_steps >= self.noise_hold:
            self._held_noise = held = torch.randn_like(mean)
            self._held_steps = 0
        self._held_steps += 1
        return held

    def _colored(self, mean: torch.Tensor) -> torch.Tensor:
        process = self._colored_noise
        if process is None or tuple(process.size[:-1]) != tuple(mean.shape):
            # Seeded from torch's generator, so the run's seed fixes the noise as it fixes
            # SAC's own draws.
            seed = int(torch.randint(2**62, (1,)).item())
            process = colored_noise_process(self.noise_color, tuple(mean.shape), seed)
            self._colored_noise = process
        return torch.as_tensor(process.sample(), dtype=mean.dtype, device=mean.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            critic_layer_norm=self.critic_layer_norm,
            max_grad_norm=self.max_grad_norm,
            actor_ema=self.actor_ema,
            noise_hold=self.noise_hold,
            noise_color=self.noise_color,
            action_gain=self.action_gain,
        )
        return data


# Policy names a hyperparameter entry may give besides SB3's own, per algorithm.
POLICIES: dict[str, dict[str, type]] = {"sac": {POLICY_NAME: StabilizedSACPolicy}}
# StabilizedSACPolicy's keys that hook into PyTorch and have no SBX counterpart here.
TORCH_ONLY_KEYS = {"critic_layer_norm", "max_grad_norm", "actor_ema", "noise_hold", "action_gain"}
