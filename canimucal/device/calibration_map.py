"""Calibration record (docs/design.md §5) ⇄ the device's calibration block (§4), on typed records.

The file holds the sensor models (K counts per m/s², S counts per rad/s, G, biases, tilt in
degrees); the device holds their inverses M = K⁻¹ and N = S⁻¹ (m/s² and rad/s per count),
biases, G, the tilt and the mounting trim in radians. ``null`` in the file means "not
estimated: nominal" (zero bias, the nominal LSB's diagonal, G = 0, zero tilt, zero trim). A
backup carries an ``objects`` map of the raw device values, written back verbatim for a
bit-exact restore.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import UTC, datetime

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.device import od
from canimucal.device.client import CalibrationReadout, Identity
from canimucal.errors import InputError
from canimucal.io.calibration import (
    AccelBlock,
    BaseTilt,
    Calibration,
    Conditions,
    Device,
    Fit,
    GyroBlock,
    Matrix,
    MountingTrim,
    Readback,
    Tool,
    Vector,
)
from canimucal.model.vocabulary.plans import PLANS, plan_named_by
from canimucal.version import __version__


def _inverse(matrix: NDArray[np.float64], name: str) -> NDArray[np.float64]:
    """M = K⁻¹ or N = S⁻¹, refusing a singular or non-finite model."""
    if not np.all(np.isfinite(matrix)):
        raise InputError(f"{name} has non-finite entries")
    if abs(np.linalg.det(matrix)) < 1e-300 or np.linalg.cond(matrix) > 1e12:
        raise InputError(f"{name} is singular and cannot be inverted for the device")
    return np.asarray(np.linalg.inv(matrix), dtype=float)


def _unix_time(created: str | None) -> int:
    """Convert ``created`` (ISO 8601 UTC) to Unix seconds; 0 if absent."""
    if created is None:
        return 0
    moment = datetime.fromisoformat(created.replace("Z", "+00:00"))
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return max(int(moment.timestamp()), 0)


def block_from_record(
    record: Calibration, accel_lsb: float, gyro_lsb: float
) -> od.CalibrationBlock:
    """Build the device block of a calibration: M = K⁻¹, N = S⁻¹, nulls nominal, tilt radians."""
    gyro = record.gyro or GyroBlock()
    tilt = record.base_tilt_deg or BaseTilt()
    return od.CalibrationBlock(
        accel_bias=record.accel.bias_counts(),
        accel_correction=_inverse(record.accel.K_matrix(accel_lsb), "accel.K"),
        gyro_bias=gyro.bias_counts(),
        gyro_correction=_inverse(gyro.S_matrix(gyro_lsb), "gyro.S"),
        gyro_g=gyro.G_matrix(),
        base_tilt_rad=np.deg2rad([tilt.alpha0 or 0.0, tilt.beta0 or 0.0]),
        time_unix_s=_unix_time(record.created),
        plan_code=PLANS.lookup(record.plan).device_code if record.plan is not None else 0,
        temp_c=_or_zero(record.conditions.temp_c if record.conditions else None),
        rms_ms2=_or_zero(record.fit.rms if record.fit else None),
        mounting_trim_rad=(record.mounting_trim_deg or MountingTrim()).radians(),
    )


def _or_zero(value: float | None) -> float:
    return 0.0 if value is None else float(value)


def backup_objects(record: Calibration) -> dict[tuple[int, int], float | int] | None:
    """Return a backup's ``objects`` map keyed ``(index, sub)``, or None when it has none.

    Every calibration object (valid flag and CRC included) must be present; the mounting
    trim's three only in a backup of a node that has them (the 42-object layout).
    """
    if record.objects is None:
        return None
    objects = {od.parse_key(key): value for key, value in record.objects.items()}
    for key, value in backup_raw(record).items():
        objects[key] = od.decode(od.OBJECT_CODES[key], value)
    expected = od.calibration_objects(od.has_trim(objects))
    missing = [od.format_key(i, s) for i, s, _ in expected if (i, s) not in objects]
    if missing:
        raise InputError(f"backup objects missing: {', '.join(missing)}")
    return {
        (index, sub): float(objects[(index, sub)]) if code == "f32" else int(objects[(index, sub)])
        for index, sub, code in expected
    }


def _finite(value: float) -> float | None:
    """``value``, or ``None`` (JSON ``null``) when it is not finite."""
    return float(value) if math.isfinite(value) else None


def _vector(values: ArrayLike) -> Vector:
    return tuple(_finite(v) for v in np.asarray(values, float).ravel())


def _matrix(values: ArrayLike) -> Matrix:
    return tuple(_vector(row) for row in np.asarray(values, float).reshape(3, 3))


def _model_matrix(correction: ArrayLike) -> Matrix:
    """K = M⁻¹ (or S = N⁻¹); all ``None`` when M cannot be inverted (nominal)."""
    try:
        return _matrix(_inverse(np.asarray(correction, float), "correction"))
    except InputError:
        return ((None,) * 3,) * 3


def backup_raw(record: Calibration) -> dict[tuple[int, int], bytes]:
    """Return a backup's ``objects_raw`` (values JSON cannot hold) as bytes by (index, sub)."""
    out: dict[tuple[int, int], bytes] = {}
    for key, text in (record.objects_raw or {}).items():
        index_sub = od.parse_key(key)
        code = od.OBJECT_CODES.get(index_sub)
        if code is None:
            raise InputError(f"objects_raw: {key} is not a calibration object")
        data = bytes.fromhex(text)
        if len(data) != len(od.encode(code, 0)):
            raise InputError(f"objects_raw: {key} needs {len(od.encode(code, 0))} bytes")
        out[index_sub] = data
    return out


def record_from_block(
    block: od.CalibrationBlock,
    identity: Identity,
    *,
    node_id: int | None = None,
    objects: Mapping[tuple[int, int], float | int] | None = None,
    raw: Mapping[tuple[int, int], bytes] | None = None,
) -> Calibration:
    """Build the calibration record of a device block; with ``objects`` a restorable backup.

    Values JSON cannot hold (NaN, ±inf) go to ``objects_raw`` as the SDO bytes (``raw``,
    the bytes the node returned, else their encoding).
    """
    created = None
    if block.time_unix_s > 0:
        created = datetime.fromtimestamp(block.time_unix_s, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    alpha0, beta0 = np.rad2deg(np.asarray(block.base_tilt_rad, float))
    return Calibration(
        created=created,
        plan=plan_named_by(block.plan_code),
        tool=Tool(name="canimucal", version=__version__),
        device=Device(
            node_id=node_id,
            vendor_id=int(identity.vendor_id),
            product_code=int(identity.product_code),
            revision=int(identity.revision),
            serial=int(identity.serial),
        ),
        conditions=Conditions(temp_c=_finite(block.temp_c)),
        accel=AccelBlock(bias=_vector(block.accel_bias), K=_model_matrix(block.accel_correction)),
        gyro=GyroBlock(
            bias=_vector(block.gyro_bias),
            S=_model_matrix(block.gyro_correction),
            G=_matrix(block.gyro_g),
        ),
        base_tilt_deg=BaseTilt(alpha0=_finite(alpha0), beta0=_finite(beta0)),
        mounting_trim_deg=_trim_of(block),
        fit=Fit(rms=_finite(block.rms_ms2)),
        objects=None if objects is None else objects_json(objects, raw),
        objects_raw=None if objects is None else (objects_raw_json(objects, raw) or None),
    )


def _trim_of(block: od.CalibrationBlock) -> MountingTrim | None:
    """Return the block's mounting trim in degrees; None on a node without 0x2122."""
    if block.mounting_trim_rad is None:
        return None
    alpha, beta, psi = (_finite(v) for v in np.rad2deg(np.asarray(block.mounting_trim_rad, float)))
    return MountingTrim(alpha=alpha, beta=beta, psi=psi)


def objects_json(
    objects: Mapping[tuple[int, int], float | int],
    raw: Mapping[tuple[int, int], bytes] | None = None,
) -> dict[str, float | int]:
    """``{"0x2100:01": value, …}`` in CALIBRATION_OBJECTS order (valid flag included).

    Non-finite values are left out: :func:`objects_raw_json` keeps them as bytes.
    """
    out: dict[str, float | int] = {}
    for index, sub, code in od.CALIBRATION_OBJECTS:
        if (index, sub) in objects:
            value = objects[(index, sub)]
            if not math.isfinite(value):
                continue
            out[od.format_key(index, sub)] = float(value) if code == "f32" else int(value)
    return out


def objects_raw_json(
    objects: Mapping[tuple[int, int], float | int],
    raw: Mapping[tuple[int, int], bytes] | None = None,
) -> dict[str, str]:
    """``{"0x2100:01": "0000c07f"}`` for every non-finite value: the SDO bytes in hex."""
    out: dict[str, str] = {}
    for index, sub, code in od.CALIBRATION_OBJECTS:
        value = objects.get((index, sub))
        if value is None or math.isfinite(value):
            continue
        data = raw.get((index, sub)) if raw is not None else None
        out[od.format_key(index, sub)] = (data or od.encode(code, value)).hex()
    return out


def record_from_readout(
    readout: CalibrationReadout, identity: Identity, node_id: int | None = None
) -> Calibration:
    """Build the backup record of a :class:`~canimucal.device.client.CalibrationReadout`."""
    return record_from_block(
        readout.block, identity, node_id=node_id, objects=readout.objects, raw=readout.raw
    )


def readback_of(block: od.CalibrationBlock, valid: int, crc_ok: bool) -> Readback:
    """docs/design.md §5 ``readback``: the device's values as read (tilt in rad), valid, CRC ok."""
    return Readback(
        accel_bias=_vector(block.accel_bias),
        accel_correction=_matrix(block.accel_correction),
        gyro_bias=_vector(block.gyro_bias),
        gyro_correction=_matrix(block.gyro_correction),
        gyro_g=_matrix(block.gyro_g),
        base_tilt_rad=_vector(block.base_tilt_rad),
        mounting_trim_rad=(
            None if block.mounting_trim_rad is None else _vector(block.mounting_trim_rad)
        ),
        valid=int(valid),
        crc_ok=bool(crc_ok),
    )
