"""The algorithms train.py offers, by name and backend, and loading their saved models."""

from __future__ import annotations

import json
import warnings
import zipfile
from pathlib import Path
from typing import Any

from stable_baselines3 import A2C, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

from minitaur_env.training import ALGORITHM_NAMES, BACKENDS, UsageError

try:
    from sb3_contrib import TQC, CrossQ
except ImportError:  # sb3-contrib is a dependency, but keep SB3's own algorithms usable
    TQC = CrossQ = None

# The JAX implementations of the same algorithms by SB3's maintainers (pip install sbx-rl).
SBX_ALGORITHMS = ("sac", "td3", "ppo", "tqc", "crossq")

ALGORITHMS: dict[str, type[BaseAlgorithm] | None] = {
    "sac": SAC,
    "td3": TD3,
    "ppo": PPO,
    "a2c": A2C,
    "tqc": TQC,
    "crossq": CrossQ,
}
assert tuple(ALGORITHMS) == ALGORITHM_NAMES
OFF_POLICY = {"sac", "td3", "tqc", "crossq"}
# StabilizedMlpPolicy's SBX counterpart (minitaur_env.training.sbx_policies); named here,
# not imported, so that telling a zip's backend needs no JAX.
SBX_POLICY_MODULE = "minitaur_env.training.sbx_policies"


def algorithm_class(name: str, backend: str = "sb3") -> type[BaseAlgorithm]:
    if backend not in BACKENDS:
        raise UsageError(f"unknown backend {backend!r}; choose from {', '.join(BACKENDS)}")
    if name not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {name!r}; choose from {', '.join(ALGORITHMS)}")
    if backend == "sbx":
        if name not in SBX_ALGORITHMS:
            raise UsageError(f"--backend sbx has no {name}; it has {', '.join(SBX_ALGORITHMS)}")
        try:
            import sbx
        except ImportError as error:
            raise UsageError("--backend sbx needs SBX: pip install 'minitaur-env[sbx]'") from error
        return getattr(sbx, {"crossq": "CrossQ"}.get(name, name.upper()))
    cls = ALGORITHMS[name]
    if cls is None:
        raise UsageError(f"--algo {name} needs sb3-contrib: pip install sb3-contrib")
    return cls


def resolve_policy(
    algo: str, name: Any, backend: str = "sb3", policy_kwargs: dict[str, Any] | None = None
) -> Any:
    """The class for one of this package's policy names; anything else as given.

    On ``--backend sbx`` the name stands for :mod:`~minitaur_env.training.sbx_policies`'
    SBX policy, which takes ``noise_color`` and SBX's own keys; the PyTorch-only keys
    are refused in one line.
    """
    from minitaur_env.training.policies import POLICIES, TORCH_ONLY_KEYS  # imports torch

    if not isinstance(name, str) or name not in POLICIES.get(algo, {}):
        return name
    if backend == "sb3":
        return POLICIES[algo][name]
    torch_only = sorted(set(policy_kwargs or {}) & TORCH_ONLY_KEYS)
    if torch_only:
        raise UsageError(
            f"policy {name} on --backend {backend} takes noise_color, not {', '.join(torch_only)} "
            "(PyTorch only); SBX's SAC has its own LayerNorm critics and held noise: "
            "'policy_kwargs={layer_norm: true}', use_sde=true"
        )
    from minitaur_env.training.sbx_policies import ColoredNoiseSACPolicy  # imports JAX

    return ColoredNoiseSACPolicy


def load_model(cls: type[BaseAlgorithm], path: Path, **kwargs: Any) -> BaseAlgorithm:
    """``cls.load``, without SB3's false alarm about n-step returns on reload.

    A model saved with ``n_steps > 1`` stores ``NStepReplayBuffer`` with its n-step
    kwargs; reloading it warns that ``n_steps`` is ignored although the saved kwargs
    keep the n-step returns.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored because a custom")
        return cls.load(path, **kwargs)


def saved_backend(policy_module: str) -> str:
    """ "sbx" or "sb3", from the module of a saved model's policy class."""
    sbx = policy_module.startswith("sbx.") or policy_module == SBX_POLICY_MODULE
    return "sbx" if sbx else "sb3"


def infer_algo(path: Path) -> tuple[str, str]:
    """(algorithm, backend) of an SB3/SBX zip, from the module of its saved policy class."""
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError, OSError) as error:
        raise UsageError(f"{path} is not a Stable-Baselines3 model file: {error}") from error
    from minitaur_env.training import policies  # imports torch

    module = str(data.get("policy_class", {}).get("__module__", ""))
    backend = saved_backend(module)
    for name in ALGORITHM_NAMES:
        if f".{name}." in module or module.endswith(f".{name}"):
            return name, backend
    if module in (policies.__name__, SBX_POLICY_MODULE) and len(policies.POLICIES) == 1:
        return next(iter(policies.POLICIES)), backend
    # PPO and A2C share SB3's common ActorCriticPolicy; only PPO clips.
    if module.endswith("common.policies"):
        return ("ppo" if "clip_range" in data else "a2c"), backend
    raise UsageError(f"cannot tell the algorithm of {path} ({module!r}); pass --algo")
