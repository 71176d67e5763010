"""Candidate effects of the discrepancy loop as extra columns of the linearised base fit.

Two data sets are supported (docs/design.md §5, §6):

- **known positions** (angles labelled): the base model is the joint model with bias and
  diagonal K, no tilt, and the gyro bias with the Earth rate seen through the nominal S
  (``solve_joint`` with ``JointSpec(accel_k="diag", tilt="none", gyro="mems")``). Each
  candidate is the derivative of the predicted means with respect to its extra parameters:
  ``base_tilt`` ``K dC/d(alpha0, beta0) f_L`` (rigid tilt, docs/design.md §2), ``cross_axis`` the
  off-diagonal K entries (``f_j`` on channel i, eq. 6), ``scale_nonlinearity`` ``f_i²`` on
  channel i, ``temperature_bias`` ``T − T̄`` on each channel, ``gyro_g_sensitivity`` ``f_j``
  on gyro channel i.
- **unknown positions** (scalar ``|f| = g`` fit, model "6"): ``cross_axis`` the lower
  off-diagonal entries of ``M = K⁻¹`` (model "9"), ``scale_nonlinearity`` and
  ``temperature_bias`` through ``f = M (U − b − q ⊙ f² − c (T − T̄))``, and
  ``gyro_g_sensitivity`` against the corrected specific force of each position.

All columns are in the raw units of the observation they predict (counts, or m/s² for the
scalar residual) per unit of the parameter (the units listed in :data:`UNITS`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.model.dcm_stack import dcm_stack
from canimucal.model.layout import ModelContext
from canimucal.model.positions import PositionAverage

Array = NDArray[np.float64]

UNITS = {
    "base_tilt": "rad",
    "cross_axis": "counts per m/s²",
    "scale_nonlinearity": "counts per (m/s²)²",
    "temperature_bias": "counts per °C",
    "gyro_g_sensitivity": "counts per m/s²",
    "bias_drift": "counts/√s",
    "axis_sign": "counts per m/s²",
}
"""Units of each effect's size in the analysis JSON (known-position fits)."""

SCALAR_UNITS = {**UNITS, "cross_axis": "m/s² per count"}
"""Units in scalar fits, where cross-axis terms are entries of ``M = K⁻¹``."""

_OFF_DIAGONAL = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))
_LOWER = ((1, 0), (2, 0), (2, 1))


@dataclass(frozen=True)
class Candidate:
    """One candidate effect: its raw columns ``(N, q)`` and the label of each column."""

    effect: str
    sensor: str
    columns: Array
    labels: tuple[str, ...]

    @property
    def key(self) -> str:
        """``sensor.effect``, the candidate's name in the selection."""
        return f"{self.sensor}.{self.effect}"


def body_specific_force(averages: Sequence[PositionAverage], g: float) -> Array:
    """``f = C(alpha, beta, psi) f_L`` of each labelled position (no tilt), ``(n, 3)`` m/s²."""
    return _specific_force(np.array([a.pose.angles for a in averages]), g)


def _specific_force(angles: Array, g: float) -> Array:
    c, _, _ = dcm_stack(angles, 0.0, 0.0, "rigid")
    return c @ ModelContext.build(g).f_level


def _tilt_columns(
    angles: Array,
    g: float,
    k_matrix: Array,
    s_matrix: Array,
    w_level: Array,
    m: int,
) -> Array:
    """``K dC/d(alpha0, beta0) f_L`` (and ``S dC w_L`` on gyro rows): rigid tilt, eq. (15)."""
    _, _, d_tilt = dcm_stack(angles, 0.0, 0.0, "rigid")
    f_level = ModelContext.build(g).f_level
    n = angles.shape[0]
    tilt = np.zeros((n, m, 2))
    tilt[:, :3] = k_matrix @ np.einsum("nkij,j->nik", d_tilt, f_level)
    if m == 6:
        tilt[:, 3:] = s_matrix @ np.einsum("nkij,j->nik", d_tilt, w_level)
    return tilt.reshape(n * m, 2)


def _rows(n: int, m: int, per_channel: Sequence[tuple[int, Array]]) -> Array:
    """Columns on a ``(n, m)`` grid flattened by position: ``(channel, values)`` each."""
    out = np.zeros((n * m, len(per_channel)))
    for k, (channel, values) in enumerate(per_channel):
        out[channel::m, k] = values
    return out


def known_position_candidates(
    averages: Sequence[PositionAverage],
    *,
    g: float,
    k_matrix: Array,
    s_matrix: Array,
    w_level: Array,
    channels: int,
    temperatures: Array | None,
) -> list[Candidate]:
    """Candidates of the joint (known-position) base fit; rows ``position × channel``."""
    return candidates_at_angles(
        np.array([a.pose.angles for a in averages]), g=g, k_matrix=k_matrix,
        s_matrix=s_matrix, w_level=w_level, channels=channels, temperatures=temperatures,
    )  # fmt: skip


def candidates_at_angles(
    angles: Array,
    *,
    g: float,
    k_matrix: Array,
    s_matrix: Array,
    w_level: Array,
    channels: int,
    temperatures: Array | None,
) -> list[Candidate]:
    """Candidates of the joint base fit at poses ``angles`` ``(n, 3)`` rad (any poses)."""
    n, m = angles.shape[0], channels
    f = _specific_force(angles, g)
    tilt = _tilt_columns(angles, g, k_matrix, s_matrix, w_level, m)
    out = [Candidate("base_tilt", "accel", tilt, ("alpha0", "beta0"))]
    out.append(
        Candidate(
            "cross_axis",
            "accel",
            _rows(n, m, [(i, f[:, j]) for i, j in _OFF_DIAGONAL]),
            tuple(f"K[{i}][{j}]" for i, j in _OFF_DIAGONAL),
        )
    )
    out.append(
        Candidate(
            "scale_nonlinearity",
            "accel",
            _rows(n, m, [(i, f[:, i] ** 2) for i in range(3)]),
            tuple(f"quadratic[{i}]" for i in range(3)),
        )
    )
    if temperatures is not None:
        dt = temperatures - np.mean(temperatures)
        for sensor, first in (("accel", 0), ("gyro", 3))[: m // 3]:
            cols = _rows(n, m, [(first + i, dt) for i in range(3)])
            out.append(
                Candidate(
                    "temperature_bias", sensor, cols, tuple(f"temp_coeff[{i}]" for i in range(3))
                )
            )
    if m == 6:
        pairs = [(3 + i, f[:, j]) for i in range(3) for j in range(3)]
        labels = tuple(f"G[{i}][{j}]" for i in range(3) for j in range(3))
        out.append(Candidate("gyro_g_sensitivity", "gyro", _rows(n, m, pairs), labels))
    return out


@dataclass(frozen=True)
class ScalarState:
    """The scalar base fit at which the scalar candidates are linearised."""

    means: Array
    bias: Array
    m_matrix: Array
    gyro_rows: int


def scalar_jacobian(state: ScalarState) -> Array:
    """Differentiate ``|M (U_i − b)|`` with respect to ``(b, diag M)``, ``(n, 6)``."""
    d = state.means - state.bias
    f = d @ state.m_matrix.T
    unit = f / np.linalg.norm(f, axis=1, keepdims=True)
    return np.hstack([-(unit @ state.m_matrix), unit * d])


def scalar_candidates(
    state: ScalarState, temperatures: Array | None, gyro_present: bool
) -> list[Candidate]:
    """Candidates of the scalar fit. Rows: one per mean, then 3 gyro rows per position."""
    n = state.means.shape[0]
    d = state.means - state.bias
    f = d @ state.m_matrix.T
    unit = f / np.linalg.norm(f, axis=1, keepdims=True)
    back = unit @ state.m_matrix  # d|f|/dU
    rows = n + (3 * n if gyro_present else 0)

    def accel(cols: Array) -> Array:
        out = np.zeros((rows, cols.shape[1]))
        out[:n] = cols
        return out

    lower = np.column_stack([unit[:, i] * d[:, j] for i, j in _LOWER])
    out = [Candidate("cross_axis", "accel", accel(lower), tuple(f"M[{i}][{j}]" for i, j in _LOWER))]
    quad = -back * f**2  # U = b + K f + q ⊙ f²
    out.append(
        Candidate(
            "scale_nonlinearity", "accel", accel(quad), tuple(f"quadratic[{i}]" for i in range(3))
        )
    )
    if temperatures is not None:
        dt = (temperatures - np.mean(temperatures))[:, None]
        labels = tuple(f"temp_coeff[{i}]" for i in range(3))
        out.append(Candidate("temperature_bias", "accel", accel(-back * dt), labels))
        if gyro_present:
            gyro = np.zeros((rows, 3))
            for i in range(3):
                gyro[n + i :: 3, i] = dt[:, 0]
            out.append(Candidate("temperature_bias", "gyro", gyro, labels))
    if gyro_present:
        gg = np.zeros((rows, 9))
        for i in range(3):
            for j in range(3):
                gg[n + i :: 3, 3 * i + j] = f[:, j]
        labels = tuple(f"G[{i}][{j}]" for i in range(3) for j in range(3))
        out.append(Candidate("gyro_g_sensitivity", "gyro", gg, labels))
    return out
