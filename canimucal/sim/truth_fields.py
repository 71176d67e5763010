"""Readers of the truth JSON's values: each checks one value and names the bad key.

Shared by :mod:`canimucal.sim.truth` and :mod:`canimucal.sim.truth`, so both refuse
a bad value with the same one-line :class:`InputError` (``truth: accel.bias must be …``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NoReturn

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError

Vector = NDArray[np.float64]


def fail(path: str, what: str) -> NoReturn:
    """Raise the :class:`InputError` naming the bad key: ``truth: <path> <what>``."""
    raise InputError(f"truth: {path} {what}")


def key_path(path: str, key: str) -> str:
    """Return the dotted path of ``key`` inside the object at ``path``."""
    return f"{path}.{key}" if path else key


def json_object(value: Any, path: str, allowed: tuple[str, ...]) -> Mapping[str, Any]:
    """Check that ``value`` is a JSON object whose keys are all in ``allowed``."""
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        fail(path or "document", "must be a JSON object")
    for key in value:
        if key not in allowed:
            fail(key_path(path, key), "is not a known key")
    return value


def number(value: Any, path: str, *, minimum: float | None = None) -> float:
    """Read a finite number (bools and strings refused), at least ``minimum`` if given."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        fail(path, "must be a finite number")
    x = float(value)
    if not np.isfinite(x):
        fail(path, "must be a finite number")
    if minimum is not None and x < minimum:
        fail(path, f"must be >= {minimum:g}")
    return x


def is_numeric_tree(value: Any) -> bool:
    """Tell whether ``value`` is a number or a (nested) list of numbers (bools refused)."""
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf"
    if isinstance(value, list | tuple):
        return all(is_numeric_tree(v) for v in value)
    return not isinstance(value, bool) and isinstance(value, int | float | np.integer | np.floating)


def float_array(value: Any, path: str, shape: tuple[int, ...]) -> Vector:
    """Read a finite float array of exactly ``shape`` (read-only)."""
    desc = "a 3x3 array of" if len(shape) == 2 else "an array of 3"
    arr = None
    if isinstance(value, list | tuple | np.ndarray) and is_numeric_tree(value):
        try:
            arr = np.array(value, dtype=float)
        except ValueError:  # ragged nesting
            arr = None
    if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
        fail(path, f"must be {desc} finite numbers")
    arr.setflags(write=False)
    return arr


def nonneg(arr: Vector, path: str) -> Vector:
    """Return ``arr`` after checking that no entry is negative."""
    if np.any(arr < 0):
        fail(path, "must be non-negative")
    return arr


def frozen_array(value: ArrayLike) -> Vector:
    """Return ``value`` as a read-only float array."""
    arr = np.array(value, dtype=float)
    arr.setflags(write=False)
    return arr
