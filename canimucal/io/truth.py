"""The simulator truth JSON (docs/design.md §5): reading with located syntax errors, writing.

:func:`read_truth` only parses (syntax, finite numbers, an object at the top);
the meaning of the keys is checked by :meth:`canimucal.sim.truth.Truth.from_dict`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canimucal.errors import InputError
from canimucal.io.atomic import write_text_atomic
from canimucal.schema import parse_json, read_text

if TYPE_CHECKING:
    from canimucal.sim.truth import Truth


def read_truth(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Parse a truth JSON file into a dict; syntax errors name file, line and column."""
    document = parse_json(read_text(path), str(path))
    if not isinstance(document, dict):
        raise InputError(f"{path}: top level is not a JSON object")
    return document


def load_truth(path: str | os.PathLike[str]) -> Truth:
    """Read and validate a truth file (``Truth.from_dict`` checks the keys)."""
    from canimucal.sim.truth import Truth

    document = read_truth(path)
    try:
        return Truth.from_dict(document)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from exc


def write_truth(
    path: str | os.PathLike[str], truth: Truth | Mapping[str, Any], *, overwrite: bool
) -> Path:
    """Write a truth JSON (a :class:`Truth` or its dict) atomically, indent 2."""
    document = truth if isinstance(truth, Mapping) else truth.to_dict()
    try:
        text = json.dumps(document, indent=2, allow_nan=False) + "\n"
    except ValueError as exc:  # json refuses NaN/inf
        raise InputError(f"{path}: truth holds a non-finite number ({exc})") from exc
    return write_text_atomic(path, text, overwrite=overwrite)
