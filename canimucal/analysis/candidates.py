"""Candidate effects of the discrepancy loop as extra columns of the linearised base fit.

The columns are the effect registry's (:mod:`canimucal.model.vocabulary.effects`), for two
data sets (docs/design.md §5, §6):

- **known positions** (angles labelled): the base model is the joint model with bias and
  diagonal K, no tilt, and the gyro bias with the Earth rate seen through the nominal S
  (``solve_joint`` with ``JointSpec(accel_k="diag", tilt="none", gyro="mems")``); each
  candidate's ``known`` columns at the positions' poses, rows ``position × channel``.
- **unknown positions** (scalar ``|f| = g`` fit, model "6"): each candidate's ``scalar``
  columns, one row per position mean, then 3 gyro rows per position.

All columns are in the raw units of the observation they predict (counts, or m/s² for the
scalar residual) per unit of the parameter (the effect's unit in that fit).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.model.positions import PositionAverage
from canimucal.model.vocabulary.effects import PoseInputs, ScalarInputs, column_effects

Array = NDArray[np.float64]


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
    """Candidates of the joint base fit at poses ``angles`` ``(n, 3)`` rad (any poses).

    ``temperatures`` per pose (°C), taken from their mean; None: no temperature candidate.
    """
    dt = None if temperatures is None else temperatures - np.mean(temperatures)
    inputs = PoseInputs.at(
        angles, g=g, k_matrix=k_matrix, s_matrix=s_matrix, w_level=w_level,
        channels=channels, temperatures=dt,
    )  # fmt: skip
    return candidates_at_inputs(inputs)


def candidates_at_inputs(inputs: PoseInputs) -> list[Candidate]:
    """Candidates of the joint fit linearised at ``inputs`` (any specific force and K).

    :func:`candidates_at_angles` linearises at a tilt-free base; the exact fits of
    :mod:`.exact_fit` at the extended model's own tilt and K.
    """
    out = []
    for effect in column_effects():
        for sensor in effect.sensors if effect.known is not None else ():
            cols = effect.known(inputs, sensor)  # type: ignore[misc]
            if cols is not None:
                flat = np.asarray(cols, dtype=float).reshape(-1, cols.shape[-1])
                out.append(Candidate(effect.name, sensor, flat, effect.labels))
    return out


def scalar_jacobian(state: ScalarInputs) -> Array:
    """Differentiate ``|M (U_i − b)|`` with respect to ``(b, diag M)``, ``(n, 6)``."""
    d = state.means - state.bias
    f = d @ state.m_matrix.T
    unit = f / np.linalg.norm(f, axis=1, keepdims=True)
    return np.hstack([-(unit @ state.m_matrix), unit * d])


def scalar_candidates(state: ScalarInputs) -> list[Candidate]:
    """Candidates of the scalar fit. Rows: one per mean, then 3 gyro rows per position."""
    out = []
    for effect in column_effects():
        for sensor in effect.sensors if effect.scalar is not None else ():
            cols = effect.scalar(state, sensor)  # type: ignore[misc]
            if cols is not None:
                out.append(Candidate(effect.name, sensor, cols, effect.labels_in(scalar=True)))
    return out
