"""A hyperparameter search space, read from YAML and checked before Ray starts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from minitaur_env.training import UsageError
from minitaur_env.training.files import parse_yaml, read_yaml

SEARCH_KINDS = ("uniform", "loguniform", "choice", "int")


def load_search_space(path: str | Path) -> dict[str, Any]:
    """A YAML search space as Ray Tune domains.

    ::

        learning_rate: {loguniform: [1.0e-4, 1.0e-3]}
        gamma: {uniform: [0.98, 0.999]}
        batch_size: {choice: [128, 256, 512]}
        gradient_steps: {int: [1, 8]}             # both ends included
        policy_kwargs: {choice: ["{net_arch: [256, 256]}", "{net_arch: [400, 300]}"]}

    Choices must be numbers, booleans or strings (Optuna's rule); a string that holds a
    YAML mapping or list is read as one when the trial starts.
    """
    from ray import tune

    table = read_yaml(path, "search space")
    if not isinstance(table, dict) or not table:
        raise UsageError(f"search space {path} must map hyperparameter names to ranges")
    space = {}
    for name, spec in table.items():
        if not (isinstance(spec, dict) and len(spec) == 1 and next(iter(spec)) in SEARCH_KINDS):
            raise UsageError(
                f"search space {path}: {name} must be one of "
                + ", ".join(f"{{{kind}: ...}}" for kind in SEARCH_KINDS)
                + f", got {spec!r}"
            )
        kind, values = next(iter(spec.items()))
        if kind == "choice":
            if not isinstance(values, list) or not values:
                raise UsageError(f"search space {path}: {name} choice needs a non-empty list")
            bad = [v for v in values if not isinstance(v, (bool, int, float, str))]
            if bad:
                raise UsageError(
                    f"search space {path}: {name} choices must be numbers, booleans or "
                    f"strings (write {bad[0]!r} as a YAML string)"
                )
            space[name] = tune.choice(values)
            continue
        numbers = isinstance(values, list) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
        )
        if not (numbers and len(values) == 2 and values[0] < values[1]):
            raise UsageError(f"search space {path}: {name} {kind} needs [low, high], low < high")
        low, high = values
        if kind == "uniform":
            space[name] = tune.uniform(float(low), float(high))
        elif kind == "loguniform":
            if low <= 0:
                raise UsageError(f"search space {path}: {name} loguniform needs low > 0")
            space[name] = tune.loguniform(float(low), float(high))
        else:
            space[name] = tune.randint(int(low), int(high) + 1)
    return space


def decode(value: Any) -> Any:
    if isinstance(value, str) and value.strip()[:1] in ("{", "["):
        return parse_yaml(value)
    return value


def group_name(sampled: dict[str, Any]) -> str:
    """A readable name for a configuration: its sampled values, or ``default``."""
    if not sampled:
        return "default"

    def text(value: Any) -> str:
        return f"{value:.3g}" if isinstance(value, float) else str(value).replace(" ", "")

    return ",".join(f"{key}={text(value)}" for key, value in sorted(sampled.items()))
