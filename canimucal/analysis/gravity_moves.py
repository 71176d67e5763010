"""Gyro S from a recording's motion between static intervals of unknown orientation (imu_tk).

imu_tk's sessions hold a long still start, then hand-placed still poses in many orientations
with the motion between them; no pose carries angles. The static intervals the detector
finds (:func:`canimucal.io.grouping.position_rows`) give, through the calibrated
accelerometer (the scalar ``|f| = g`` fit of the same recording), gravity's direction in
body axes at each; each unbroken stretch from one interval to the next is a move whose
rotation is known in two axes (:mod:`canimucal.model.gravity_moves`). The bias of a move is
the mean of its two intervals' gyro means (Earth rate stays in it: these recordings carry
no latitude, and a MEMS gyro cannot see it), and the fit starts from the nominal gyro
scale. What gravity cannot see — a column of S the moves never turn about except about
the vertical — is reported, not invented.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.calibrate import SiteConditions, Solution
from canimucal.analysis.gyro_moves import uniform_rows
from canimucal.errors import InputError
from canimucal.io.calibration import AccelBlock, re_estimated
from canimucal.io.grouping import position_rows
from canimucal.io.recording import Recording
from canimucal.model.gravity_moves import GravityMove, GravityMovesFit, solve_gravity_moves
from canimucal.model.moves import AXES

Array = NDArray[np.float64]


@dataclass(frozen=True)
class GravityMoves:
    """The moves of a recording, its static intervals' gyro means, and notes."""

    moves: tuple[GravityMove, ...]
    rate_sigma_counts: Array
    first_bias: Array
    first_bias_sigma: Array
    notes: tuple[str, ...]


def recording_gravity_moves(rec: Recording, accel: AccelBlock, accel_lsb: float) -> GravityMoves:
    """Build the gravity-only moves of ``rec`` (module doc); ``accel`` corrects the force."""
    intervals, labelled = position_rows(rec)
    if labelled:
        raise InputError("gravity-only moves are for recordings without position labels")
    if not np.isfinite(rec.gyro).any():
        raise InputError(f"{rec.source or 'recording'}: no gyro samples for gyro moves")
    fs = rec.sample_rate_hz
    ends = []
    for rows in intervals:
        f = accel.correct(rec.accel[rows], accel_lsb)
        f = f[np.all(np.isfinite(f), axis=1)]
        mean = f.mean(axis=0)
        norm = float(np.linalg.norm(mean))
        sigma_u = float(np.linalg.norm(f.std(axis=0, ddof=1)) / np.sqrt(f.shape[0]) / norm)
        g = np.asarray(rec.gyro[rows], dtype=np.float64)
        ends.append((mean / norm, sigma_u, np.nanmean(g, axis=0), np.nanstd(g, axis=0, ddof=1)))
    moves: list[GravityMove] = []
    notes: list[str] = []
    for k, (a, b) in enumerate(zip(intervals, intervals[1:], strict=False)):
        label = f"interval {k} → {k + 1}"
        gyro = uniform_rows(rec, int(a[-1]), int(b[0]) + 1, label, notes)
        if gyro is None:
            continue
        (ua, sa, ga, _), (ub, sb, gb, _) = ends[k], ends[k + 1]
        moves.append(
            GravityMove(gyro, 1.0 / fs, 0.5 * (ga + gb), ua, ub, float(np.hypot(sa, sb)), label)
        )
    stds = np.array([e[3] for e in ends])
    first = intervals[0]
    return GravityMoves(
        tuple(moves),
        np.median(stds, axis=0),
        ends[0][2],
        ends[0][3] / np.sqrt(first.size),
        tuple(notes),
    )


def solve_gravity_moves_recording(
    rec: Recording, solution: Solution, site: SiteConditions
) -> tuple[Solution, GravityMovesFit]:
    """Add gyro bias (first still interval) and S from gravity-only moves to a scalar solution."""
    scalar = solution.scalar
    if scalar is None:
        raise InputError("gravity-only gyro moves need the scalar fit of the same recording")
    found = recording_gravity_moves(rec, solution.record.accel, site.accel_lsb)
    fit = solve_gravity_moves(found.moves, np.eye(3) / site.gyro_lsb, found.rate_sigma_counts)
    names = [f"accel.{n}" for n in scalar.param_names]
    bias_names = [f"gyro.bias[{i}]" for i in range(3)]
    s_names = [f"gyro.S[{i}][{j}]" for i in range(3) for j in range(3) if fit.identifiable[j]]
    s_values = [fit.S[i, j] for i in range(3) for j in range(3) if fit.identifiable[j]]
    k, nb = len(names), 3
    cov = np.zeros((k + nb + len(s_names),) * 2)
    cov[:k, :k] = scalar.covariance
    cov[k : k + nb, k : k + nb] = np.diag(found.first_bias_sigma**2)
    cov[k + nb :, k + nb :] = fit.covariance
    held = {
        f"gyro.S[{i}][{j}]": f"gravity does not determine S column {AXES[j]}: not identifiable"
        for j in np.flatnonzero(~fit.identifiable)
        for i in range(3)
    }
    record = re_estimated(
        solution.record,
        [*names, *bias_names, *s_names],
        np.concatenate([scalar.params, found.first_bias, s_values]),
        cov,
        held,
    )
    warnings = (
        *solution.warnings,
        *found.notes,
        *fit.notes,
        f"gyro S from {len(found.moves)} moves between still intervals, matched on gravity "
        "(rotations about the vertical unseen); gyro bias from the first still interval",
    )
    undetermined = {**solution.undetermined, **held}
    return replace(solution, record=record, warnings=warnings, undetermined=undetermined), fit
