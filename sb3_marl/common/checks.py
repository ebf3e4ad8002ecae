"""The value checks of every setting (env config, hyperparameters, wrapper options, command-line
flags, benchmark settings): one predicate per kind of value, and one error per check that names the
setting, the value and what is allowed (``Invalid <key>=<value>: expected <what>.``)."""

from __future__ import annotations

import math
from collections.abc import Collection
from numbers import Integral, Real
from typing import Any


def is_number(value: Any) -> bool:
    """A finite real number (not a bool)."""
    return not isinstance(value, bool) and isinstance(value, Real) and math.isfinite(value)


def is_integer(value: Any) -> bool:
    """An integer (not a bool)."""
    return not isinstance(value, bool) and isinstance(value, Integral)


def invalid(key: str, value: Any, expected: str) -> ValueError:
    """The error of a setting: ``Invalid <key>=<value>: expected <expected>.``"""
    return ValueError(f"Invalid {key}={value!r}: expected {expected}.")


def check_number(
    key: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
    expected: str | None = None,
) -> float:
    """``value`` as a float if a finite number within the bounds (inclusive unless ``*_open``);
    a ValueError naming ``key`` otherwise (``expected``: the allowed values in words)."""
    ok = is_number(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value < high if high_open else value <= high
    if not ok:
        bounds = "" if low is None else f" {'>' if low_open else '>='} {low:g}"
        bounds += "" if high is None else f"{' and' if bounds else ''} {'<' if high_open else '<='} {high:g}"
        raise invalid(key, value, expected or f"a finite number{bounds}")
    return float(value)


def check_integer(
    key: str, value: Any, low: int | None = None, high: int | None = None, *, expected: str | None = None
) -> int:
    """``value`` as an int if an integer in [low, high]; a ValueError naming ``key`` otherwise."""
    if not is_integer(value) or (low is not None and value < low) or (high is not None and value > high):
        bounds = "" if low is None else f" >= {low}"
        bounds += "" if high is None else f" and <= {high}"
        raise invalid(key, value, expected or f"an integer{bounds}")
    return int(value)


def check_choice(key: str, value: Any, allowed: Collection[Any]) -> Any:
    """``value`` if one of ``allowed``; a ValueError naming ``key`` and the allowed values otherwise
    (a list or tuple in its order, other collections sorted)."""
    if isinstance(value, bool) or value not in allowed:
        choices = list(allowed) if isinstance(allowed, (list, tuple)) else sorted(allowed)
        raise invalid(key, value, f"one of {choices}")
    return value


__all__ = ["check_choice", "check_integer", "check_number", "invalid", "is_integer", "is_number"]
