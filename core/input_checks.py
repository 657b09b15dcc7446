"""The input-check vocabulary: whole numbers, finite numbers, booleans, choices and array shapes.

Numpy only (the torch-free predict path uses it). One wording for every such error, so that a user
reads the same sentence whichever verb refused the value: ``NAME must be a whole number >= 1, got 0``,
``NAME must be a finite number in (0, 1], got nan``, ``NAME must be true or false, got 'maybe'``,
``NAME must be 'cpu' or 'cuda', got 'tpu'``, ``NAME must be (N, 3), got (5, 2)``.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Sequence
from typing import Any

import numpy as np

from hupbench.core.errors import BadValueError

__all__ = ["check_bool", "check_bool_fields", "check_choice", "check_int", "check_interval", "check_number",
           "check_shape", "is_number", "is_whole"]


def is_whole(value: Any) -> bool:
    """True for a Python or numpy integer (not a bool, not an integral float such as 2.0)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def is_number(value: Any) -> bool:
    """True for a finite Python or numpy real number (not a bool, not NaN or inf; an integer of any size)."""
    return (isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
            and (isinstance(value, numbers.Integral) or math.isfinite(value)))


def _bounds(low, high, low_open: bool = False, fmt: str = "") -> str:
    """The words of an interval: " from 1 to 8" / " in (0, 1]", " >= 1" / " > 0", " <= 8" or ""."""
    if low is not None and high is not None:
        return (f" in {'(' if low_open else '['}{low:{fmt}}, {high:{fmt}}]" if fmt or low_open
                else f" from {low} to {high}")
    if low is not None:
        return f" {'>' if low_open else '>='} {low:{fmt}}"
    return f" <= {high:{fmt}}" if high is not None else ""


def check_int(value: Any, name: str, low: int | None = None, high: int | None = None, *, optional: bool = False,
              hint: str = "", error: type[Exception] = BadValueError) -> int | None:
    """``value`` when it is a whole number within [low, high] (either bound may be None).

    Args:
        value: what came. name: the field or option, as the user wrote it. low, high: inclusive bounds.
        optional: None is accepted (and returned). hint: words after the range, e.g. " (4 x the 2 CPU
            cores)". error: the exception for a value that is not a whole number (TypeError where a
            caller's contract says so); a whole number out of range is always a ValueError.

    Returns:
        ``int(value)``, or None when ``optional`` and ``value`` is None.
    """
    if value is None and optional:
        return None
    whole = is_whole(value)
    if whole and (low is None or value >= low) and (high is None or value <= high):
        return int(value)
    raise (BadValueError if whole else error)(
        f"{name} must be a whole number{_bounds(low, high)}{hint}{' or null' if optional else ''}, got {value!r}")


def check_number(value: Any, name: str, low: float | None = None, high: float | None = None, *,
                 low_open: bool = False, optional: bool = False) -> float | None:
    """``value`` when it is a finite real number within its interval ((low, high] with ``low_open``)."""
    if value is None and optional:
        return None
    above = is_number(value) and (low is None or (value > low if low_open else value >= low))
    if above and (high is None or value <= high):
        return float(value)
    raise BadValueError(f"{name} must be a finite number{_bounds(low, high, low_open, 'g')}"
                     f"{' or null' if optional else ''}, got {value!r}")


def check_interval(value: Any, name: str, low: float, high: float, unit: str = "") -> tuple[float, float]:
    """``value`` as (lower, upper) when it is two finite numbers with low <= lower <= upper <= high (a list, a
    tuple or a config's list); the error names the range, e.g. ``NAME must be two numbers [low, high],
    low <= high, from 0.1 to 10 m, got [0.8, 0.35]``."""
    pair = list(value) if isinstance(value, Sequence) and not isinstance(value, (str, bytes)) else None
    if pair is not None and len(pair) == 2 and all(is_number(v) for v in pair) and low <= pair[0] <= pair[1] <= high:
        return float(pair[0]), float(pair[1])
    written = "[" + ", ".join(repr(v) for v in pair) + "]" if pair is not None else repr(value)
    raise BadValueError(f"{name} must be two numbers [low, high], low <= high, from {low:g} to {high:g}"
                        f"{' ' + unit if unit else ''}, got {written}")


def check_bool(value: Any, name: str) -> bool:
    """``value`` when it is a boolean (Python or numpy); anything else, the string "maybe" from a command line
    or the number 1 included, is refused naming ``name``."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise BadValueError(f"{name} must be true or false, got {value!r}")


def check_bool_fields(node: Any, prefix: str = "") -> None:
    """Every field of the dataclass ``node`` annotated ``bool`` is a boolean (:func:`check_bool`), named
    ``prefix`` + its name (a config node's ``__post_init__`` calls it with its dotted path, e.g. ``"train."``)."""
    for field in dataclasses.fields(node):
        if field.type in (bool, "bool"):
            check_bool(getattr(node, field.name), prefix + field.name)


def check_choice(value: Any, name: str, choices: Sequence) -> Any:
    """``value`` when it is one of ``choices`` (a bool matches only a bool: ``True`` is not ``1``)."""
    if any(value == choice and isinstance(value, bool) == isinstance(choice, bool) for choice in choices):
        return value
    raise BadValueError(f"{name} must be {' or '.join(repr(c) for c in choices)}, got {value!r}")


def check_shape(array: Any, shape: tuple, name: str) -> np.ndarray:
    """``array`` as a numpy array when its shape matches ``shape`` (ints, or names such as "N" for any size;
    a name used twice must take one size).

    Args:
        array: what came (anything ``np.asarray`` takes). shape: e.g. ``("N", 3)`` or ``(3, 3)``.
        name: the argument, for the message.

    Returns:
        ``np.asarray(array)``.
    """
    array = np.asarray(array)
    sizes: dict[str, int] = {}
    ok = array.ndim == len(shape)
    for got, want in zip(array.shape, shape):
        if not ok:
            break
        ok = got == want if isinstance(want, int) else sizes.setdefault(want, got) == got
    if not ok:
        shown = ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "")
        raise BadValueError(f"{name} must be ({shown}), got {tuple(array.shape)}")
    return array


def check_finite_points(value: Any, shape: tuple, name: str) -> np.ndarray:
    """``value`` as a float64 array of finite numbers whose shape matches ``shape`` (:func:`check_shape`), e.g.
    ``("T", 21, 3)`` for a set of hands; a value that is not an array of numbers, or holds NaN or inf, is refused
    naming ``name``."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadValueError(f"{name} must be an array of numbers of shape ({', '.join(map(str, shape))}), got "
                            f"{str(value)[:80]}") from None
    check_shape(array, shape, name)
    if not np.isfinite(array).all():
        raise BadValueError(f"{name} must hold finite numbers, got NaN or inf")
    return array
