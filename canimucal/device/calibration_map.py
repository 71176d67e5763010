"""Calibration JSON record (DESIGN §5) ⇄ device calibration block (DESIGN §4).

The file holds the sensor models (K counts per m/s², S counts per rad/s, G, biases, tilt in
degrees); the device holds their inverses M = K⁻¹ and N = S⁻¹ (m/s² and rad/s per count),
biases, G and the tilt in radians. ``null`` in the file means "not estimated: nominal"
(zero bias, the nominal LSB's diagonal, G = 0, zero tilt). A backup carries an ``objects``
map of the raw device values, written back verbatim for a bit-exact restore.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal import __version__
from canimucal.device import od
from canimucal.errors import InputError
from canimucal.io.calibration import calibration_to_dict, read_calibration

logger = logging.getLogger(__name__)

SCHEMA = "canimucal.calibration/1"
PLAN_NAMES = {code: name for name, code in od.PLAN_CODES.items()}


def record_dict(record: Any) -> dict[str, Any]:
    """Return the JSON form of a ``CalibrationRecord`` (a mapping is taken as it is)."""
    if isinstance(record, Mapping):
        return dict(record)
    return dict(calibration_to_dict(record))


def _vector(value: Any, n: int, nominal: NDArray[np.float64]) -> NDArray[np.float64]:
    """``n`` floats with ``None`` (whole or per entry) replaced by the nominal entry."""
    if value is None:
        return nominal.copy()
    out = nominal.copy()
    for i, entry in enumerate(np.asarray(value, dtype=object).reshape(n)):
        if entry is not None:
            out[i] = float(entry)
    return out


def _matrix(value: Any, nominal: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return a 3×3 matrix, ``None`` entries (or a ``None`` matrix) taken as nominal."""
    return _vector(value, 9, nominal.reshape(9)).reshape(3, 3)


def _inverse(matrix: NDArray[np.float64], name: str) -> NDArray[np.float64]:
    """M = K⁻¹ or N = S⁻¹, refusing a singular or non-finite model."""
    if not np.all(np.isfinite(matrix)):
        raise InputError(f"{name} has non-finite entries")
    if abs(np.linalg.det(matrix)) < 1e-300 or np.linalg.cond(matrix) > 1e12:
        raise InputError(f"{name} is singular and cannot be inverted for the device")
    return np.asarray(np.linalg.inv(matrix), dtype=float)


def _unix_time(created: Any) -> int:
    """Convert ``created`` (ISO 8601 UTC) to Unix seconds; 0 if absent."""
    if created is None:
        return 0
    try:
        moment = datetime.fromisoformat(str(created).replace("Z", "+00:00"))
    except ValueError as exc:
        raise InputError(f"created {created!r} is not an ISO 8601 time") from exc
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return max(int(moment.timestamp()), 0)


def _plan_code(plan: Any) -> int:
    if plan is None:
        return 0
    if plan not in od.PLAN_CODES:
        raise InputError(f"plan {plan!r} is not one of {sorted(od.PLAN_CODES)}")
    return od.PLAN_CODES[plan]


def _number(value: Any, default: float = 0.0) -> float:
    return default if value is None else float(value)


def block_from_record(record: Any, accel_lsb: float, gyro_lsb: float) -> od.CalibrationBlock:
    """Build the device block of a calibration: M = K⁻¹, N = S⁻¹, nulls nominal, tilt in radians."""
    d = record_dict(record)
    accel, gyro = d.get("accel") or {}, d.get("gyro") or {}
    tilt = d.get("base_tilt_deg") or {}
    k = _matrix(accel.get("K"), np.eye(3) / accel_lsb)
    s = _matrix(gyro.get("S"), np.eye(3) / gyro_lsb)
    return od.CalibrationBlock(
        accel_bias=_vector(accel.get("bias"), 3, np.zeros(3)),
        accel_correction=_inverse(k, "accel.K"),
        gyro_bias=_vector(gyro.get("bias"), 3, np.zeros(3)),
        gyro_correction=_inverse(s, "gyro.S"),
        gyro_g=_matrix(gyro.get("G"), np.zeros((3, 3))),
        base_tilt_rad=np.deg2rad([_number(tilt.get("alpha0")), _number(tilt.get("beta0"))]),
        time_unix_s=_unix_time(d.get("created")),
        plan_code=_plan_code(d.get("plan")),
        temp_c=_number((d.get("conditions") or {}).get("temp_c")),
        rms_ms2=_number((d.get("fit") or {}).get("rms")),
    )


def backup_objects(record: Any) -> dict[tuple[int, int], float | int] | None:
    """Return a backup's ``objects`` map keyed ``(index, sub)``, or None when the record has none.

    Every calibration object (valid flag and CRC included) must be present.
    """
    raw = record_dict(record).get("objects")
    if raw is None:
        return None
    objects = {od.parse_key(key): value for key, value in raw.items()}
    missing = [od.format_key(i, s) for i, s, _ in od.CALIBRATION_OBJECTS if (i, s) not in objects]
    if missing:
        raise InputError(f"backup objects missing: {', '.join(missing)}")
    out: dict[tuple[int, int], float | int] = {}
    for index, sub, code in od.CALIBRATION_OBJECTS:
        value = objects[(index, sub)]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"backup object {od.format_key(index, sub)} is not a number")
        out[(index, sub)] = float(value) if code == "f32" else int(value)
    return out


def _json_list(array: NDArray[np.float64]) -> Any:
    """Nested lists of floats, ``None`` for non-finite entries (JSON has no NaN)."""
    if array.ndim == 0:
        value = float(array)
        return value if math.isfinite(value) else None
    return [_json_list(row) for row in array]


def _model_matrix(correction: NDArray[np.float64]) -> Any:
    """K = M⁻¹ (or S = N⁻¹); all ``None`` when M cannot be inverted (nominal)."""
    try:
        return _json_list(_inverse(np.asarray(correction, float), "correction"))
    except InputError:
        return [[None] * 3 for _ in range(3)]


def record_dict_from_block(
    block: od.CalibrationBlock,
    identity: Any,
    *,
    node_id: int | None = None,
    objects: Mapping[tuple[int, int], float | int] | None = None,
) -> dict[str, Any]:
    """Build a calibration JSON dict for ``block`` (a backup when ``objects`` is given)."""
    d: dict[str, Any] = {"schema": SCHEMA}
    if block.time_unix_s > 0:
        moment = datetime.fromtimestamp(block.time_unix_s, UTC)
        d["created"] = moment.strftime("%Y-%m-%dT%H:%M:%SZ")
    if block.plan_code in PLAN_NAMES:
        d["plan"] = PLAN_NAMES[block.plan_code]
    d["tool"] = {"name": "canimucal", "version": __version__}
    device = {"node_id": node_id} if node_id is not None else {}
    device |= {
        "vendor_id": int(identity.vendor_id),
        "product_code": int(identity.product_code),
        "revision": int(identity.revision),
        "serial": int(identity.serial),
    }
    d["device"] = device
    d["conditions"] = {"temp_c": _json_list(np.asarray(block.temp_c, float))}
    d["accel"] = {
        "bias": _json_list(np.asarray(block.accel_bias, float)),
        "K": _model_matrix(block.accel_correction),
    }
    d["gyro"] = {
        "bias": _json_list(np.asarray(block.gyro_bias, float)),
        "S": _model_matrix(block.gyro_correction),
        "G": _json_list(np.asarray(block.gyro_g, float)),
    }
    alpha0, beta0 = np.rad2deg(np.asarray(block.base_tilt_rad, float))
    d["base_tilt_deg"] = {
        "alpha0": _json_list(np.asarray(alpha0)),
        "beta0": _json_list(np.asarray(beta0)),
    }
    d["fit"] = {"rms": _json_list(np.asarray(block.rms_ms2, float))}
    if objects is not None:
        d["objects"] = objects_json(objects)
    return d


def objects_json(objects: Mapping[tuple[int, int], float | int]) -> dict[str, float | int]:
    """``{"0x2100:01": value, …}`` in CALIBRATION_OBJECTS order (valid flag included)."""
    out: dict[str, float | int] = {}
    for index, sub, code in od.CALIBRATION_OBJECTS:
        if (index, sub) in objects:
            value = objects[(index, sub)]
            out[od.format_key(index, sub)] = float(value) if code == "f32" else int(value)
    bad = [key for key, value in out.items() if not math.isfinite(value)]
    if bad:
        raise InputError(f"device holds non-finite values in {', '.join(bad)}; cannot back up")
    return out


def _parse(d: Mapping[str, Any]) -> Any:
    """Parse a ``CalibrationRecord`` from its JSON dict, through the strict reader."""
    return read_calibration(json.dumps(d, allow_nan=False))


def record_from_block(
    block: od.CalibrationBlock,
    identity: Any,
    *,
    node_id: int | None = None,
    objects: Mapping[tuple[int, int], float | int] | None = None,
) -> Any:
    """Build a ``CalibrationRecord`` for ``block``; with ``objects`` a restorable backup."""
    return _parse(record_dict_from_block(block, identity, node_id=node_id, objects=objects))


def record_from_readout(readout: Any, identity: Any, node_id: int | None = None) -> Any:
    """Build the backup record of a :class:`~canimucal.device.client.CalibrationReadout`."""
    return record_from_block(readout.block, identity, node_id=node_id, objects=readout.objects)


def readback_dict(block: od.CalibrationBlock, valid: int, crc_ok: bool) -> dict[str, Any]:
    """DESIGN §5 ``readback``: the device's values as read (tilt in radians), valid, CRC ok."""
    return {
        "accel_bias": _json_list(np.asarray(block.accel_bias, float)),
        "accel_correction": _json_list(np.asarray(block.accel_correction, float)),
        "gyro_bias": _json_list(np.asarray(block.gyro_bias, float)),
        "gyro_correction": _json_list(np.asarray(block.gyro_correction, float)),
        "gyro_g": _json_list(np.asarray(block.gyro_g, float)),
        "base_tilt_rad": _json_list(np.asarray(block.base_tilt_rad, float)),
        "valid": int(valid),
        "crc_ok": bool(crc_ok),
    }
