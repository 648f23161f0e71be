"""Algorithms, hyperparameter files and ``key=value`` overrides."""

from __future__ import annotations

import warnings
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3 import A2C, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm

from minitaur_env.training import UsageError

try:
    from sb3_contrib import TQC, CrossQ
except ImportError:  # sb3-contrib is a dependency, but keep SB3's own algorithms usable
    TQC = CrossQ = None

BACKENDS = ("sb3", "sbx")
# "auto": several envs grouped over the CPU cores, a single env in the calling process.
VEC_ENVS = ("auto", "dummy", "subproc", "grouped")
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
OFF_POLICY = {"sac", "td3", "tqc", "crossq"}

# Keys of a hyperparameter entry that configure the run rather than the algorithm.
RUN_KEYS = ("n_timesteps", "n_envs", "normalize", "policy")


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


def load_model(cls: type[BaseAlgorithm], path: Path, **kwargs: Any) -> BaseAlgorithm:
    """``cls.load``, without SB3's false alarm about n-step returns on reload.

    A model saved with ``n_steps > 1`` stores ``NStepReplayBuffer`` with its n-step
    kwargs; reloading it warns that ``n_steps`` is ignored although the saved kwargs
    keep the n-step returns.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored because a custom")
        return cls.load(path, **kwargs)


def hyperparams_file(algo: str) -> Path:
    return Path(str(resources.files("minitaur_env") / "hyperparams" / f"{algo}.yml"))


def load_hyperparams(
    algo: str, env_id: str, conf_file: str | None = None, entry: str | None = None
) -> dict[str, Any]:
    """The entry for ``env_id`` (or ``default``) of the algorithm's YAML file.

    ``entry`` picks a named entry instead (e.g. ``tutorial``). An entry may name another
    with ``base: <key>`` to start from it.
    """
    path = Path(conf_file) if conf_file else hyperparams_file(algo)
    try:
        table = yaml.safe_load(path.read_text())
    except OSError as error:
        raise UsageError(f"cannot read hyperparameter file {path}: {error.strerror}") from error
    except yaml.YAMLError as error:
        raise UsageError(f"hyperparameter file {path} is not valid YAML: {error}") from error
    if not isinstance(table, dict):
        raise UsageError(f"hyperparameter file {path} must map env ids to settings")
    if entry is not None:
        if entry not in table:
            names = ", ".join(k for k in table if isinstance(table[k], dict) or table[k] is None)
            raise UsageError(f"{path} has no entry {entry!r}; it has: {names}")
        return _resolve(table, entry, path)
    bare_id = env_id.split(":")[-1]
    key = bare_id if bare_id in table else "default"
    if key not in table:
        raise UsageError(f"{path} has no entry for {bare_id} and no 'default' entry")
    return _resolve(table, key, path)


def _resolve(table: dict[str, Any], key: str, path: Path, seen: tuple[str, ...] = ()) -> dict:
    if key in seen:
        raise UsageError(f"{path}: 'base' entries form a cycle: {' -> '.join((*seen, key))}")
    entry = dict(table.get(key) or {})
    base = entry.pop("base", None)
    if base is None:
        return entry
    if base not in table:
        raise UsageError(f"{path}: entry {key!r} has base {base!r}, which is not in the file")
    return {**_resolve(table, base, path, (*seen, key)), **entry}


def parse_overrides(pairs: list[str] | None, flag: str) -> dict[str, Any]:
    """``["lr=3e-4", "policy_kwargs={net_arch: [64, 64]}"]`` -> a dict of YAML values."""
    result: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{flag} expects key=value, got {pair!r}")
        try:
            result[key.strip()] = _number_if_numeric(yaml.safe_load(text))
        except yaml.YAMLError as error:
            raise UsageError(f"{flag} {key}: cannot parse {text!r}: {error}") from error
    return result


def _number_if_numeric(value: Any) -> Any:
    """YAML 1.1 reads ``1e-3`` (no dot) as a string; users mean a number."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value
