"""Argument checks that name the argument, the value and what is accepted, in one line.

Constructor arguments arrive from Python, from ``--env-kwargs`` and from the zoo's
``env_kwargs.yml``, where a string, a bool or milliseconds slip in easily; each check
refuses them rather than letting them reach the simulator as a plausible number.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from typing import Any

import numpy as np

ACTION_TOLERANCE = 0.01  # the classic env accepts actions up to 1.01 in magnitude


def _interval(low: float, high: float, low_open: bool, high_open: bool) -> str:
    def shown(value: float) -> str:
        return f"{value:g}"

    return f"{'(' if low_open else '['}{shown(low)}, {shown(high)}{')' if high_open else ']'}"


def number(
    name: str,
    value: Any,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
) -> float:
    """``value`` as a float, if it is a real number in the interval (NaN never is).

    An infinite bound is accepted as a value only where its end is closed, so
    ``number("x", v, 0, math.inf, high_open=True)`` asks for a finite ``v >= 0``.
    """
    accepted = _interval(low, high, low_open, high_open) + (f" {unit}" if unit else "")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a number in {accepted}, got {value!r}")
    result = float(value)
    inside = (
        not math.isnan(result)
        and (low < result if low_open else low <= result)
        and (result < high if high_open else result <= high)
    )
    if not inside:
        raise ValueError(f"{name} must be in {accepted}, got {value!r}")
    return result


def integer(name: str, value: Any, low: int, high: int) -> int:
    """``value`` if it is an int (not a bool) in ``[low, high]``."""
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Integral)
        or not (low <= value <= high)
    ):
        raise ValueError(f"{name} must be an int in [{low}, {high}], got {value!r}")
    return int(value)


def boolean(name: str, value: Any) -> bool:
    """``value`` if it is a bool: ``"no"`` or ``0`` would otherwise read as a choice."""
    if not isinstance(value, bool) and type(value).__name__ != "bool_":  # numpy's bool too
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def choice(name: str, value: Any, options: tuple[str, ...]) -> str:
    if value not in options:
        raise ValueError(f"{name} must be one of {options}, got {value!r}")
    return value


def checked_action(action: Any, size: int) -> np.ndarray:
    """``action`` as float64 if it is ``size`` finite real numbers within [-1.01, 1.01]."""
    given = np.asarray(action)
    # Bools and complex numbers convert to floats silently; an action is a real number.
    if given.dtype.kind not in "iuf":
        raise ValueError(f"action must be real numbers, got {given.dtype} {action!r}")
    checked = given.astype(np.float64, copy=False)
    if checked.shape != (size,):
        raise ValueError(f"action must have shape ({size},), got {checked.shape}")
    if not np.all(np.isfinite(checked)):
        raise ValueError(f"action must be finite, got {checked.tolist()}")
    if np.any(np.abs(checked) > 1.0 + ACTION_TOLERANCE):
        worst = int(np.argmax(np.abs(checked)))
        raise ValueError(
            f"action[{worst}] = {checked[worst]} is outside [-1, 1] (tolerance {ACTION_TOLERANCE})"
        )
    return checked


def from_mapping(cls: Any, values: Mapping[str, Any], base: Any = None) -> Any:
    """``cls(**values)`` for a dataclass (or ``values`` set on top of ``base``), refusing
    a key that is not one of its fields."""
    unknown = sorted(set(values) - {field.name for field in dataclasses.fields(cls)})
    if unknown:
        raise ValueError(f"{cls.__name__} has no field {unknown[0]!r}")
    return cls(**values) if base is None else dataclasses.replace(base, **values)


def preset_or_fields(cls: Any, argument: str, value: Any, base: Any) -> Any:
    """``value`` as a ``cls`` (a settings dataclass with a ``tan2018`` preset): itself,
    ``"classic"`` (the defaults), ``"tan2018"``, or a mapping of fields set on top of
    ``base``; None is ``base``."""
    if value is None:
        return base
    if isinstance(value, cls):
        return value
    if isinstance(value, str) and value in ("classic", "tan2018"):
        return cls() if value == "classic" else cls.tan2018()
    if isinstance(value, Mapping):
        return from_mapping(cls, value, base)
    raise ValueError(
        f"{argument} must be a {cls.__name__}, a mapping of its fields, 'classic' or "
        f"'tan2018', got {value!r}"
    )
