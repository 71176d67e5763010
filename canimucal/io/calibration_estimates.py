"""Calibration records built from a solver's named estimates, and their covariance back in SI.

Kept apart from :mod:`canimucal.io.calibration` (the record, its strict reader and writer):
here the solver's parameter vector (tilt in radians) is mapped onto the file's blocks (tilt
in degrees) and back.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal import schema as cs
from canimucal.errors import ModelError
from canimucal.io.calibration import (
    AccelBlock,
    BaseTilt,
    CalibrationRecord,
    Conditions,
    Covariance,
    Device,
    Fit,
    GyroBlock,
    Matrix,
    PositionSummary,
    RecordingRef,
    Tool,
    Vector,
)
from canimucal.model.positions import PositionAverage

logger = logging.getLogger(__name__)

_RAD_TO_DEG = 180.0 / np.pi
_SCALED_MATRICES = ("accel.K", "gyro.S")
"""Matrices whose off-diagonal is held at 0.0 (sigma null) when only the diagonal is solved."""


def record_from_estimates(
    names: Sequence[str],
    values: ArrayLike,
    covariance: ArrayLike,
    *,
    device: Device,
    held_fixed: Mapping[str, str] | None = None,
    plan: str | None = None,
    created: str | None = None,
    tool: Tool | None = None,
    conditions: Conditions | None = None,
    positions: Sequence[PositionSummary] | None = None,
    fit: Fit | None = None,
    recording: RecordingRef | None = None,
) -> CalibrationRecord:
    """Build a record from a solver's named parameter vector and its covariance.

    ``names`` follow ``accel.bias[i]``, ``accel.K[i][j]``, ``gyro.bias[i]``, ``gyro.S[i][j]``,
    ``gyro.G[i][j]``, ``base_tilt.alpha0``/``beta0``; tilt values are **radians** in
    ``values`` and ``covariance`` and come out in degrees (``base_tilt_deg`` and the tilt
    rows/columns of ``covariance.matrix``). A parameter not in ``names`` is ``null`` (value
    and sigma), except the off-diagonal of K or S when some of its diagonal was solved:
    those were held at zero by the model and read ``0.0`` with a ``null`` sigma.
    ``held_fixed`` maps names the solver could not identify to the reason; they are ``null``
    and the reasons are logged (warnings travel beside the record, not in it).
    """
    held = dict(held_fixed or {})
    x, cov = _check_estimates(list(names), values, covariance, held)
    for name, reason in held.items():
        logger.info("%s not estimated: %s", name, reason)
    sigma = np.sqrt(np.diag(cov))
    table = {n: (float(v), float(s)) for n, v, s in zip(names, x, sigma, strict=True)}
    everything = [*names, *held]
    accel, gyro = _sensor_blocks(table, held, everything)
    return CalibrationRecord(
        created=created or _utc_now(),
        plan=plan,
        tool=tool or Tool(name="canimucal", version=_tool_version()),
        device=device,
        conditions=conditions,
        accel=accel,
        gyro=gyro,
        base_tilt_deg=_base_tilt(table, everything),
        covariance=_covariance_deg(list(names), cov) if len(names) else None,
        positions=tuple(positions) if positions is not None else None,
        fit=fit,
        recording=recording,
    )


def _sensor_blocks(
    table: Mapping[str, tuple[float, float]], held: Mapping[str, str], everything: list[str]
) -> tuple[AccelBlock, GyroBlock | None]:
    """Build the ``accel`` block, and the ``gyro`` block when a gyro parameter is named."""
    accel = AccelBlock(
        bias=_vector("accel.bias", table, 0),
        bias_sigma=_vector("accel.bias", table, 1),
        K=_matrix("accel.K", table, held, 0),
        K_sigma=_matrix("accel.K", table, held, 1),
    )
    if not any(n.startswith("gyro.") for n in everything):
        return accel, None
    gyro = GyroBlock(
        bias=_vector("gyro.bias", table, 0),
        bias_sigma=_vector("gyro.bias", table, 1),
        S=_matrix("gyro.S", table, held, 0),
        S_sigma=_matrix("gyro.S", table, held, 1),
        G=_matrix("gyro.G", table, held, 0),
        G_sigma=_matrix("gyro.G", table, held, 1),
    )
    return accel, gyro


def _check_estimates(
    names: list[str], values: ArrayLike, covariance: ArrayLike, held: Mapping[str, str]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    n = len(names)
    for name in [*names, *held]:
        if not cs.PARAMETER_NAME.fullmatch(name):
            raise ModelError(f"unknown parameter name {name!r}")
    if len(set(names)) != n or set(names) & set(held):
        raise ModelError("parameter names repeat, or are both estimated and held fixed")
    x = np.asarray(values, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    if x.shape != (n,) or cov.shape != (n, n):
        raise ModelError(f"need {n} values and a {n}x{n} covariance, got {x.shape}, {cov.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(cov))):
        raise ModelError("estimates and covariance must be finite")
    cov = 0.5 * (cov + cov.T)
    if np.any(np.diag(cov) < 0):
        raise ModelError("covariance has a negative variance")
    return x, cov


def _vector(prefix: str, table: Mapping[str, tuple[float, float]], k: int) -> Vector:
    return tuple(
        table[f"{prefix}[{i}]"][k] if f"{prefix}[{i}]" in table else None for i in range(3)
    )


def _matrix(
    prefix: str, table: Mapping[str, tuple[float, float]], held: Mapping[str, str], k: int
) -> Matrix:
    diagonal_solved = any(f"{prefix}[{i}][{i}]" in table for i in range(3))
    zero_off = prefix in _SCALED_MATRICES and diagonal_solved

    def entry(i: int, j: int) -> float | None:
        name = f"{prefix}[{i}][{j}]"
        if name in table:
            return table[name][k]
        if zero_off and i != j and name not in held:
            return 0.0 if k == 0 else None
        return None

    return tuple(tuple(entry(i, j) for j in range(3)) for i in range(3))


def _base_tilt(table: Mapping[str, tuple[float, float]], everything: list[str]) -> BaseTilt | None:
    if not any(n.startswith("base_tilt.") for n in everything):
        return None

    def degrees(name: str, k: int) -> float | None:
        return table[name][k] * _RAD_TO_DEG if name in table else None

    return BaseTilt(
        alpha0=degrees("base_tilt.alpha0", 0),
        beta0=degrees("base_tilt.beta0", 0),
        sigma=(degrees("base_tilt.alpha0", 1), degrees("base_tilt.beta0", 1)),
    )


def _tilt_scale(names: Sequence[str]) -> NDArray[np.float64]:
    return np.array([_RAD_TO_DEG if n.startswith("base_tilt.") else 1.0 for n in names])


def _covariance_deg(names: list[str], cov: NDArray[np.float64]) -> Covariance:
    scale = _tilt_scale(names)
    matrix = cov * np.outer(scale, scale)
    return Covariance(order=tuple(names), matrix=tuple(tuple(row) for row in matrix.tolist()))


def covariance_si(record: CalibrationRecord) -> tuple[list[str], NDArray[np.float64]]:
    """Return the record's covariance with tilt rows/columns back in radians (empty when absent)."""
    if record.covariance is None:
        return [], np.zeros((0, 0))
    names = list(record.covariance.order)
    scale = _tilt_scale(names)
    return names, np.array(record.covariance.matrix, dtype=float) / np.outer(scale, scale)


def summarize_position(average: PositionAverage) -> PositionSummary:
    """Summarise one average as a ``positions`` entry (angles in degrees, NaN as ``null``)."""

    def vec(x: NDArray[np.float64] | None) -> Vector | None:
        return None if x is None else tuple(None if np.isnan(v) else float(v) for v in x)

    def deg(angle: float) -> float | None:
        return None if np.isnan(angle) else float(np.rad2deg(angle))

    return PositionSummary(
        alpha_deg=deg(average.pose.alpha),
        beta_deg=deg(average.pose.beta),
        psi_deg=deg(average.pose.psi),
        seconds=float(average.seconds),
        n=int(average.n),
        lost=int(average.lost),
        mean_accel=vec(average.mean_accel),
        mean_gyro=vec(average.mean_gyro),
        std_accel=vec(average.std_accel),
        std_gyro=vec(average.std_gyro),
        temp_c=average.temp_c,
    )


def _utc_now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _tool_version() -> str:
    from canimucal import __version__

    return __version__
