"""Custom position plans and pose schedules (docs/design.md §3 and §5): JSON or TOML files.

``{"positions": [{"alpha_deg", "beta_deg", "psi_deg", "seconds", "tolerance_deg"}]}`` in
JSON, or ``[[positions]]`` tables in TOML; an optional ``psi_tolerance_deg`` gives the
turn its own tolerance (a vehicle turned on the spot). ``alpha_deg`` and ``beta_deg`` are required;
``psi_deg`` defaults to 0, ``seconds`` to 30 and ``tolerance_deg`` to 0.1. Tilts are at most
180° in magnitude (an upside-down pose of a measured six-position session is alpha = 180°);
the turn ``psi_deg`` about the unit's own y axis at most 360° (the recommended plan turns the
unit 0/90/180/270°).
The built-in plans live in the plan registry, :mod:`canimucal.model.vocabulary.plans`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.errors import InputError, SchemaError
from canimucal.io.atomic import write_text_atomic
from canimucal.model.positions import DEFAULT_SECONDS, Plan, PlannedPosition
from canimucal.model.vocabulary.plans import CUSTOM, builtin_names, builtin_plan
from canimucal.schema import parse_json, parse_toml, read_number, read_text

DEFAULT_TOLERANCE_DEG = 0.1
"""Angle-setting tolerance of a position that names none (docs/design.md §3)."""

_LIMITS_DEG = {"alpha_deg": 180.0, "beta_deg": 180.0, "psi_deg": 360.0}
_KEYS = ("alpha_deg", "beta_deg", "psi_deg", "seconds", "tolerance_deg", "psi_tolerance_deg")
_DECIMALS = 10
"""Degrees are written rounded to 1e-10°, hiding the radian round trip's last bits."""


def read_plan(path: str | os.PathLike[str]) -> Plan:
    """Read a custom plan (``.json``/``.toml``, else detected from the content)."""
    source = str(path)
    text = read_text(path)
    suffix = Path(path).suffix.lower()
    is_json = suffix == ".json" or (suffix != ".toml" and text.lstrip().startswith("{"))
    if is_json:
        document = parse_json(text, source)
    else:
        document = parse_toml(text, source)
    return plan_from_document(document, source)


def plan_from_document(document: Any, source: str = "plan") -> Plan:
    """Validate a parsed plan document and return it as the ``custom`` :class:`Plan`."""
    if not isinstance(document, dict):
        raise InputError(f"{source}: top level is not an object")
    unknown = [key for key in document if key != "positions"]
    if unknown:
        raise InputError(f"{source}: unknown key {unknown[0]!r} (only 'positions')")
    positions = document.get("positions")
    if not isinstance(positions, list) or not positions:
        raise InputError(f"{source}: 'positions' must be a non-empty list")
    return Plan(CUSTOM, tuple(_position(p, i + 1, source) for i, p in enumerate(positions)))


def _position(entry: Any, number: int, source: str) -> PlannedPosition:
    where = f"{source}: position {number}"
    if not isinstance(entry, dict):
        raise InputError(f"{where}: must be an object")
    for key in entry:
        if key not in _KEYS:
            raise InputError(f"{where}: unknown key {key!r}")
    for key in ("alpha_deg", "beta_deg"):
        if key not in entry:
            raise InputError(f"{where}: missing {key!r}")
    values = {key: _number(entry, key, where) for key in _KEYS if key in entry}
    for key, limit in _LIMITS_DEG.items():
        if abs(values.get(key, 0.0)) > limit:
            raise InputError(f"{where}: {key} must be within ±{limit:g}°, got {values[key]:g}")
    seconds = values.get("seconds", DEFAULT_SECONDS)
    if seconds <= 0:
        raise InputError(f"{where}: seconds must be > 0, got {seconds:g}")
    tolerance = values.get("tolerance_deg", DEFAULT_TOLERANCE_DEG)
    psi_tolerance = values.get("psi_tolerance_deg")
    for key, value in (("tolerance_deg", tolerance), ("psi_tolerance_deg", psi_tolerance)):
        if value is not None and value < 0:
            raise InputError(f"{where}: {key} must be ≥ 0, got {value:g}")
    return PlannedPosition(
        alpha=float(np.deg2rad(values["alpha_deg"])),
        beta=float(np.deg2rad(values["beta_deg"])),
        psi=float(np.deg2rad(values.get("psi_deg", 0.0))),
        tolerance=float(np.deg2rad(tolerance)),
        seconds=seconds,
        psi_tolerance=None if psi_tolerance is None else float(np.deg2rad(psi_tolerance)),
    )


def _number(entry: dict[str, Any], key: str, where: str) -> float:
    try:
        return read_number(entry[key], key)
    except SchemaError as exc:
        raise InputError(f"{where}: {exc}") from None


def plan_to_dict(plan: Plan) -> dict[str, Any]:
    """Return the JSON object of ``plan`` (degrees, every key written)."""

    def deg(angle: float) -> float:
        return round(float(np.rad2deg(angle)), _DECIMALS) + 0.0  # + 0.0: no "-0.0"

    return {
        "positions": [
            {
                "alpha_deg": deg(p.alpha),
                "beta_deg": deg(p.beta),
                "psi_deg": deg(p.psi),
                "seconds": float(p.seconds),
                "tolerance_deg": deg(p.tolerance),
                **({} if p.psi_tolerance is None else {"psi_tolerance_deg": deg(p.psi_tolerance)}),
            }
            for p in plan.positions
        ]
    }


def write_plan(path: str | os.PathLike[str], plan: Plan, *, overwrite: bool) -> Path:
    """Write ``plan`` as JSON (the pose-schedule file of ``sim --poses``), atomically."""
    document = plan_to_dict(plan)
    plan_from_document(document, str(path))  # what we write, we must be able to read
    text = json.dumps(document, indent=2, allow_nan=False) + "\n"
    return write_text_atomic(path, text, overwrite=overwrite)


def resolve_plan(name_or_path: str | os.PathLike[str]) -> Plan:
    """Return a built-in plan by name (the plan registry's), else read a plan file.

    Built-in names win over a file of the same name (write ``./five`` for the file).
    """
    names = builtin_names()
    if isinstance(name_or_path, str) and name_or_path in names:
        return builtin_plan(name_or_path)
    if not Path(name_or_path).is_file():
        raise InputError(
            f"unknown plan {str(name_or_path)!r}: not one of {', '.join(names)} and no such file"
        )
    return read_plan(name_or_path)
