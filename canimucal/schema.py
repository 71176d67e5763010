"""Strict JSON and TOML for every file the tool reads: parsing, value readers, schemas.

``parse_json`` refuses ``NaN``/``Infinity`` literals and duplicate keys and reports syntax
errors as ``FILE:LINE:COLUMN``; it and ``parse_toml`` bound nesting (:data:`MAX_NESTING`)
and integers (:data:`MAX_INT_DIGITS`), so a hostile file is a one-line error, never a
``RecursionError`` or Python's own integer-conversion limit. The readers (``read_number``,
``read_array``, ...) check one value found at a key path and raise
:class:`~canimucal.errors.SchemaError` as ``key.path: problem``; documents with free-form
structure (the simulator's truth, its fault block) call them directly. A schema is a frozen
dataclass whose fields carry a checker in their metadata (``field(metadata=number(...))``);
:func:`build` turns a parsed object into it with the same readers, refusing unknown keys.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import tomllib
from collections.abc import Callable, Collection, Mapping
from dataclasses import MISSING, fields, is_dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError, SchemaError

T = TypeVar("T")
Checker = Callable[[Any, str], Any]
"""Validates one non-null value found at a key path and returns it normalised."""

PARAMETER_NAME = re.compile(
    r"(accel|gyro)\.bias\[[0-2]\]|(accel\.K|gyro\.S|gyro\.G)\[[0-2]\]\[[0-2]\]"
    r"|base_tilt\.(alpha0|beta0)|mounting_trim\.(alpha|beta|psi)"
)
"""Names of the parameter vector (the calibration JSON's ``covariance.order``)."""

OBJECT_KEY = re.compile(r"0x[0-9A-Fa-f]{4}:[0-9A-Fa-f]{2}")
"""Keys of a backup's ``objects`` map, e.g. ``0x2100:01``."""


class _NotFinite(ValueError):
    pass


class _DuplicateKey(ValueError):
    pass


class _TooLong(ValueError):
    pass


# ------------------------------------------------------------------------- text and JSON


def load_text(path_or_text: str | os.PathLike[str], what: str) -> tuple[str, str]:
    """Return ``(source name, text)``: a ``str`` starting with ``{`` is text, else a path."""
    if isinstance(path_or_text, str) and path_or_text.lstrip().startswith("{"):
        return what, path_or_text
    return str(path_or_text), read_text(path_or_text)


def read_text(path: str | os.PathLike[str]) -> str:
    """Read a UTF-8 file; unreadable or undecodable files raise :class:`InputError`."""
    try:
        return Path(path).read_text(encoding="utf-8-sig")  # a leading BOM is skipped
    except UnicodeDecodeError:
        raise InputError(f"{path}: not UTF-8 text") from None
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc


def parse_json(text: str, source: str) -> Any:
    """Parse JSON text; syntax errors, non-finite literals and duplicate keys are refused."""
    try:
        document = json.loads(
            text,
            parse_constant=_refuse_constant,
            parse_int=_bounded_int,
            object_pairs_hook=_no_dupes,
        )
    except json.JSONDecodeError as exc:
        raise InputError(f"{source}:{exc.lineno}:{exc.colno}: invalid JSON ({exc.msg})") from None
    except _TooLong as exc:
        raise InputError(f"{source}: integer of {exc} digits (at most {MAX_INT_DIGITS})") from None
    except _NotFinite as exc:
        raise InputError(f"{source}: {exc} is not allowed (numbers must be finite)") from None
    except _DuplicateKey as exc:
        raise InputError(f"{source}: duplicate key {exc}") from None
    except RecursionError:
        raise InputError(f"{source}: JSON nested too deeply") from None
    check_nesting(document, source)
    return document


def parse_toml(text: str, source: str) -> dict[str, Any]:
    """Parse TOML text; syntax errors, huge integers and deep nesting are one-line errors."""
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: invalid TOML ({str(exc).splitlines()[0]})") from None
    except RecursionError:
        raise InputError(f"{source}: TOML nested too deeply") from None
    except ValueError:  # int(): Python refuses to convert more than 4300 digits
        raise InputError(
            f"{source}: invalid TOML (an integer of more than {MAX_INT_DIGITS} digits)"
        ) from None
    check_nesting(document, source)
    return document


MAX_NESTING = 32
"""Deepest nesting of arrays and tables accepted in a JSON or TOML file: the deepest of
the tool's own documents is 4 (a covariance in a calibration), so 32 leaves room and
keeps a hostile file from reaching the interpreter's recursion limit anywhere later."""


def check_nesting(document: Any, source: str, limit: int = MAX_NESTING) -> None:
    """Refuse a document nested deeper than ``limit`` (walked without recursion)."""
    stack: list[tuple[Any, int]] = [(document, 1)]
    while stack:
        value, depth = stack.pop()
        children = (
            value.values() if isinstance(value, dict) else value if isinstance(value, list) else ()
        )
        for child in children:
            if isinstance(child, dict | list):
                if depth + 1 > limit:
                    raise InputError(f"{source}: nested deeper than {limit} levels")
                stack.append((child, depth + 1))


MAX_INT_DIGITS = 4300
"""Longest JSON integer parsed (Python's own limit for ``int(str)``); shorter ones that are
too large for their key are refused by the schema checks, which name the key."""


def _bounded_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_INT_DIGITS:
        raise _TooLong(str(digits))
    return int(text)


def _refuse_constant(name: str) -> Any:
    raise _NotFinite(name)


def _no_dupes(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(repr(key))
        out[key] = value
    return out


def sha256_of(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes; unreadable files raise :class:`InputError`."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for chunk in iter(lambda: handle.read(1 << 20), b""):
                digest.update(chunk)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc
    return digest.hexdigest()


# ----------------------------------------------------------------------------- readers


def fail(path: str, problem: str) -> NoReturn:
    """Raise the :class:`SchemaError` ``path: problem`` (``top level`` for the document)."""
    raise SchemaError(f"{path or 'top level'}: {problem}")


def key_path(path: str, key: str) -> str:
    """Return the dotted path of ``key`` inside the object at ``path``."""
    return f"{path}.{key}" if path else key


def read_object(value: Any, path: str, allowed: Collection[str]) -> Mapping[str, Any]:
    """Check a JSON object whose keys are all in ``allowed``."""
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        fail(path, "must be a JSON object")
    for key in value:
        if key not in allowed:
            fail(key_path(path, key), "unknown key")
    return value


def read_list(value: Any, path: str) -> list[Any]:
    """Check a JSON array."""
    if not isinstance(value, list):
        fail(path, "must be a JSON array")
    return value


def _is_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float | np.integer | np.floating)


def read_number(
    value: Any,
    path: str,
    low: float | None = None,
    high: float | None = None,
    *,
    open_low: bool = False,
) -> float:
    """Check a finite number (bools and strings refused) within ``[low, high]``."""
    if not _is_number(value):
        fail(path, f"must be a finite number, got {type(value).__name__}")
    try:
        x = float(value)
    except OverflowError:
        fail(path, "number out of range")
    if not math.isfinite(x):
        fail(path, "must be a finite number")
    too_low = low is not None and (x < low or (open_low and x == low))
    too_high = high is not None and x > high
    if (too_low or too_high) and low is not None and high is not None:
        left = "(" if open_low else "["
        fail(path, f"must be within {left}{low:g}, {high:g}], got {x:g}")
    if too_low:
        fail(path, f"must be {'>' if open_low else '≥'} {low:g}, got {x:g}")
    if too_high:
        fail(path, f"must be ≤ {high:g}, got {x:g}")
    return x


def read_integer(value: Any, path: str, low: int | None = None, high: int | None = None) -> int:
    """Check an integer (not a bool, not a float) within ``[low, high]``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        fail(path, f"must be an integer, got {type(value).__name__}")
    n = int(value)
    if (low is not None and n < low) or (high is not None and n > high):
        if low is not None and high is not None:
            fail(path, f"must be {low}..{high}, got {n}")
        fail(path, f"must be ≥ {low}, got {n}" if low is not None else f"must be ≤ {high}, got {n}")
    return n


def is_numeric_tree(value: Any) -> bool:
    """Tell whether ``value`` is a number or a (nested) list of numbers (bools refused)."""
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf"
    if isinstance(value, list | tuple):
        return all(is_numeric_tree(v) for v in value)
    return _is_number(value)


def read_array(value: Any, path: str, shape: tuple[int, ...]) -> NDArray[np.float64]:
    """Check a finite float array of exactly ``shape``; return it read-only."""
    arr = None
    if isinstance(value, list | tuple | np.ndarray) and is_numeric_tree(value):
        try:
            arr = np.array(value, dtype=float)
        except (ValueError, OverflowError):  # ragged nesting, or a huge integer
            arr = None
    if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
        what = f"an array of {shape[0]}" if len(shape) == 1 else "a " + "x".join(map(str, shape))
        fail(path, f"must be {what}{'' if len(shape) == 1 else ' array of'} finite numbers")
    arr.setflags(write=False)
    return arr


def frozen_array(value: ArrayLike) -> NDArray[np.float64]:
    """Return ``value`` as a read-only float array."""
    arr = np.array(value, dtype=float)
    arr.setflags(write=False)
    return arr


# ----------------------------------------------------------------------------- schemas


def build(cls: type[T], obj: Any, path: str) -> T:
    """Instantiate the schema dataclass ``cls`` from the parsed object ``obj``."""
    known = {f.name: f for f in fields(cls)}  # type: ignore[arg-type]
    read_object(obj, path, known)
    kwargs = {}
    for name, spec in known.items():
        sub = key_path(path, name)
        value = obj.get(name)
        if value is None:
            if spec.default is MISSING and spec.default_factory is MISSING:
                raise SchemaError(f"{sub}: required" + (" (null given)" if name in obj else ""))
            continue
        kwargs[name] = spec.metadata["check"](value, sub)
    return cls(**kwargs)


def to_plain(value: Any) -> Any:
    """Convert a schema dataclass to plain JSON types (``None`` fields omitted, tuples as lists)."""
    if is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: to_plain(getattr(value, f.name))
            for f in fields(value)
            if getattr(value, f.name) is not None
        }
    if isinstance(value, tuple | list):
        return [to_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: to_plain(v) for k, v in value.items()}
    return value


def _meta(check: Checker) -> dict[str, Checker]:
    return {"check": check}


def number(
    low: float | None = None, high: float | None = None, *, open_low: bool = False
) -> dict[str, Checker]:
    """Field metadata: a finite number within ``[low, high]`` (``(low`` with ``open_low``)."""
    return _meta(lambda value, path: read_number(value, path, low, high, open_low=open_low))


def integer(low: int, high: int | None) -> dict[str, Checker]:
    """Field metadata: an integer (not a bool, not a float) within ``[low, high]``."""
    return _meta(lambda value, path: read_integer(value, path, low, high))


def text(choices: Collection[str] | None = None, pattern: str | None = None) -> dict[str, Checker]:
    """Field metadata: a string, optionally one of ``choices`` or matching ``pattern``.

    ``choices`` is read when a value is checked, so a registry given here (the plans) checks
    against the entries it holds then.
    """

    def check(value: Any, path: str) -> str:
        if not isinstance(value, str):
            fail(path, f"must be a string, got {type(value).__name__}")
        if choices is not None and value not in choices:
            fail(path, f"must be one of {', '.join(choices)}, got {value!r}")
        if pattern is not None and not re.fullmatch(pattern, value):
            fail(path, f"malformed value {value[:40]!r}")
        return value

    return _meta(check)


def boolean() -> dict[str, Checker]:
    """Field metadata: ``true`` or ``false``."""

    def check(value: Any, path: str) -> bool:
        if not isinstance(value, bool):
            fail(path, "must be true or false")
        return value

    return _meta(check)


def timestamp() -> dict[str, Checker]:
    """Field metadata: an ISO 8601 time such as ``2026-01-01T00:00:00Z``."""

    def check(value: Any, path: str) -> str:
        if not isinstance(value, str):
            fail(path, "must be an ISO 8601 time string")
        try:
            datetime.fromisoformat(value)
        except ValueError:
            fail(path, f"not an ISO 8601 time: {value[:40]!r}")
        return value

    return _meta(check)


def array(shape: tuple[int, ...]) -> dict[str, Checker]:
    """Field metadata: nested lists of the given shape; entries are numbers or ``null``."""

    def check(value: Any, path: str, depth: int = 0) -> tuple[Any, ...]:
        dims = "x".join(map(str, shape[depth:]))
        if not isinstance(value, list) or len(value) != shape[depth]:
            fail(path, f"must be a {dims} array")
        if depth == len(shape) - 1:
            return tuple(
                None if v is None else read_number(v, f"{path}[{i}]") for i, v in enumerate(value)
            )
        return tuple(check(v, f"{path}[{i}]", depth + 1) for i, v in enumerate(value))

    return _meta(check)


def block(cls: type) -> dict[str, Checker]:
    """Field metadata: a nested object of schema ``cls``."""
    return _meta(lambda value, path: build(cls, value, path))


def block_list(cls: type) -> dict[str, Checker]:
    """Field metadata: a list of objects of schema ``cls``."""

    def check(value: Any, path: str) -> tuple[Any, ...]:
        if not isinstance(value, list):
            fail(path, "must be a list")
        return tuple(build(cls, item, f"{path}[{i}]") for i, item in enumerate(value))

    return _meta(check)


def names() -> dict[str, Checker]:
    """Field metadata: distinct parameter names (``accel.bias[0]``, ``base_tilt.alpha0``…)."""

    def check(value: Any, path: str) -> tuple[str, ...]:
        if not isinstance(value, list):
            fail(path, "must be a list of parameter names")
        for i, name in enumerate(value):
            if not isinstance(name, str) or not PARAMETER_NAME.fullmatch(name):
                raise SchemaError(f"{path}[{i}]: unknown parameter name {str(name)[:40]!r}")
        if len(set(value)) != len(value):
            fail(path, "repeated parameter name")
        return tuple(value)

    return _meta(check)


def square() -> dict[str, Checker]:
    """Field metadata: an n×n matrix of finite numbers (no ``null``)."""

    def check(value: Any, path: str) -> tuple[tuple[float, ...], ...]:
        if not isinstance(value, list):
            fail(path, "must be a square matrix")
        rows = []
        for i, row in enumerate(value):
            if not isinstance(row, list) or len(row) != len(value):
                fail(path, f"must be a square matrix (row {i})")
            rows.append(tuple(read_number(v, f"{path}[{i}][{j}]") for j, v in enumerate(row)))
        return tuple(rows)

    return _meta(check)


def objects() -> dict[str, Checker]:
    """Field metadata: ``{"0x2100:01": value}`` raw device values, type (int/float) kept."""

    def check(value: Any, path: str) -> dict[str, int | float]:
        if not isinstance(value, dict):
            fail(path, "must be an object")
        out: dict[str, int | float] = {}
        for key, raw in value.items():
            if not OBJECT_KEY.fullmatch(key):
                fail(path, f"malformed object key {key[:40]!r} (want 0x2100:01)")
            read_number(raw, f"{path}.{key}")
            out[key] = raw
        return out

    return _meta(check)


def raw_objects() -> dict[str, Checker]:
    """Field metadata: ``{"0x2100:01": "0000c07f"}``, an object's SDO bytes in hex (1–8 bytes)."""

    def check(value: Any, path: str) -> dict[str, str]:
        if not isinstance(value, dict):
            fail(path, "must be an object")
        out: dict[str, str] = {}
        for key, raw in value.items():
            if not OBJECT_KEY.fullmatch(key):
                fail(path, f"malformed object key {key[:40]!r} (want 0x2100:01)")
            if not isinstance(raw, str) or not re.fullmatch(r"(?:[0-9a-fA-F]{2}){1,8}", raw):
                fail(f"{path}.{key}", "must be 1 to 8 bytes in hex, e.g. '0000c07f'")
            out[key] = raw.lower()
        return out

    return _meta(check)


def number_map() -> dict[str, Checker]:
    """Field metadata: an object of ``name: number`` pairs (names are identifiers)."""

    def check(value: Any, path: str) -> dict[str, float]:
        if not isinstance(value, dict):
            fail(path, "must be an object")
        out: dict[str, float] = {}
        for key, raw in value.items():
            if not re.fullmatch(r"[a-z][a-z0-9_]{0,63}", key):
                fail(path, f"malformed name {key[:40]!r}")
            out[key] = read_number(raw, key_path(path, key))
        return out

    return _meta(check)
