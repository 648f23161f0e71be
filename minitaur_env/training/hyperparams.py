"""Hyperparameter files (one YAML per algorithm, one entry per env id) and ``key=value``
overrides."""

from __future__ import annotations

import copy
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from minitaur_env.training import UsageError, env_name
from minitaur_env.training.files import parse_yaml, read_yaml

# Keys of a hyperparameter entry that configure the run rather than the algorithm.
RUN_KEYS = ("n_timesteps", "n_envs", "normalize", "policy")
# Keys that take rl-baselines3-zoo's ``lin_<initial value>`` (linear decay to 0).
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")


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
    table = read_yaml(path, "hyperparameter file")
    if not isinstance(table, dict):
        raise UsageError(f"hyperparameter file {path} must map env ids to settings")
    if entry is not None:
        if entry not in table:
            names = ", ".join(k for k in table if isinstance(table[k], dict) or table[k] is None)
            raise UsageError(f"{path} has no entry {entry!r}; it has: {names}")
        return _resolve(table, entry, path)
    bare_id = env_name(env_id)
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
            result[key.strip()] = parse_yaml(text)
        except yaml.YAMLError as error:
            raise UsageError(f"{flag} {key}: cannot parse {text!r}: {error}") from error
    return result


def algorithm_kwargs(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """``hyperparams`` with the zoo's ``lin_0.001`` turned into a schedule SB3 accepts.

    The schedule decays linearly from the value to 0 over training, as the zoo's does;
    the config files keep the string, so the zoo reads them too.
    """
    from stable_baselines3.common.utils import LinearSchedule

    kwargs = copy.deepcopy(hyperparams)  # SBX's TQC writes into policy_kwargs
    for key in SCHEDULE_KEYS:
        value = kwargs.get(key)
        if not isinstance(value, str):
            continue
        kind, _, number = value.partition("_")
        try:
            if kind != "lin":
                raise ValueError
            initial = float(number)
        except ValueError:
            raise UsageError(
                f"{key}: expected a number or lin_<number> (linear decay), got {value!r}"
            ) from None
        kwargs[key] = LinearSchedule(initial, 0.0, 1.0)
    return kwargs
