"""Gyro S from moves whose rotation is known only through gravity (imu_tk's motion data).

Between two static intervals of unknown orientation the accelerometer gives the direction
of gravity in body axes at each end, ``u_0`` and ``u_1`` (unit vectors of the calibrated
specific force means). The move's rotation is then known in two axes only: a turn about
the vertical leaves gravity where it was. The residual of a move (Tedaldi, Pretto and
Menegatti, ICRA 2014, eq. 13, the fit imu_tk makes) compares the integrated rotation applied
to gravity at the start with gravity at the end:

    r = M(S) u_0 − u_1,    M(S) = ΔR(S)ᵀ,

``ΔR`` the body rotation integrated from ``w = S⁻¹ (V − B)`` as in
:func:`canimucal.model.moves.move_rotation` (coning-corrected trapezoid, quaternions). For
small errors ``r`` is the angle error (rad) perpendicular to ``u_1``; its component along
``u_1`` is of second order. Each component is weighed by ``σ² = σ_u0² + σ_u1² + σ_arw²``
(the two directions' standard errors and the gyro's angle random walk over the move).

**Fit.** Gauss–Newton on the 9 entries of S with a forward-difference Jacobian. The start is
the nominal ``S0`` with a common scale factor chosen first by a search over a log grid
(the datasheet scale of a raw-count unit may be off by a large factor; a scale within tens of
per cent of the truth is needed for the small-error Gauss–Newton to converge). σ come from
``(Jᵀ W J)⁻¹``, multiplied by ``√(χ²/dof)`` when that exceeds 1 (real data carry errors the
noise model does not: hand-held ends, bias drift). A column of S whose relative σ exceeds
``max_relative_sigma`` is reported not identifiable and held at the start value.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError
from canimucal.model.moves import (
    AXES,
    S_NAMES,
    cross,
    move_rotation,
    quat_chain,
    quat_to_matrix,
    rotvec_to_quat,
)

Array = NDArray[np.float64]

DEFAULT_MAX_RELATIVE_SIGMA = 0.02
"""A column of S whose σ would exceed this fraction of its scale is not identifiable."""
SCALE_GRID = np.geomspace(0.1, 10.0, 81)
"""Common scale factors (× the nominal S) searched for the start of the fit."""


@dataclass(frozen=True)
class GravityMove:
    """A move between two static intervals: raw gyro rows, its bias, gravity at both ends.

    ``gyro`` ``(n, 3)`` counts from the last still sample before to the first after;
    ``bias`` counts; ``u_start``/``u_end`` unit gravity directions (body axes) with their
    1σ in rad (``sigma_u``, both ends together).
    """

    gyro: Array
    dt_s: float
    bias: Array
    u_start: Array
    u_end: Array
    sigma_u: float
    label: str = ""


@dataclass(frozen=True)
class GravityMovesFit:
    """S from gravity-only moves (``nan`` in columns not identifiable), σ, residuals."""

    S: Array
    S_sigma: Array
    identifiable: NDArray[np.bool_]
    start: Array
    names: tuple[str, ...]
    covariance: Array
    residuals_rad: Array
    chi2: float
    dof: int
    sigma_inflation: float
    notes: tuple[str, ...] = ()

    def S_used(self) -> Array:
        """S with the start value in the columns the moves did not determine."""
        return np.where(np.isnan(self.S), self.start, self.S)


def gravity_residual(move: GravityMove, S: Array) -> Array:
    """``M(S) u_start − u_end`` (rad, small-angle; module doc)."""
    w = np.linalg.solve(S, (move.gyro - move.bias).T).T
    m = move_rotation(w, move.dt_s)
    return np.asarray(m @ move.u_start - move.u_end, dtype=np.float64)


def gravity_angle_deg(move: GravityMove, S: Array) -> float:
    """Angle (degrees) between gravity carried through the move and gravity measured at its end."""
    w = np.linalg.solve(S, (move.gyro - move.bias).T).T
    v = move_rotation(w, move.dt_s) @ move.u_start
    c = float(np.clip(v @ move.u_end / np.linalg.norm(v), -1.0, 1.0))
    return float(np.rad2deg(np.arccos(c)))


def _sigmas(moves: Sequence[GravityMove], rate_sigma_counts: Array, S: Array) -> Array:
    rate = float(np.mean(np.abs(rate_sigma_counts) / np.abs(np.diag(S))))
    out = []
    for m in moves:
        n = m.gyro.shape[0]
        arw2 = rate**2 * m.dt_s**2 * max(n - 1.5, 0.5)
        out.append(np.sqrt(m.sigma_u**2 + arw2))
    return np.asarray(out)


class _Packed:
    """All moves' bias-free rows in one array, integrated together.

    The result is :func:`gravity_residual` of each move: the increments of the module doc,
    padded with identity rotations to the longest move.
    """

    def __init__(self, moves: Sequence[GravityMove]) -> None:
        self.v = np.concatenate([m.gyro - m.bias for m in moves])
        sizes = np.array([m.gyro.shape[0] for m in moves])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        self.first = np.concatenate(
            [s + np.arange(n - 1) for s, n in zip(starts, sizes, strict=True)]
        )
        self.move = np.repeat(np.arange(len(moves)), sizes - 1)
        self.slot = np.concatenate([np.arange(n - 1) for n in sizes])
        self.shape = (len(moves), int(sizes.max()) - 1)
        self.dt = np.array([m.dt_s for m in moves])[self.move][:, None]
        self.u_start = np.array([m.u_start for m in moves])
        self.u_end = np.array([m.u_end for m in moves])

    def residuals(self, S: Array) -> Array:
        """``(m, 3)`` residuals ``M(S) u_start − u_end``."""
        w = np.linalg.solve(S, self.v.T).T
        a, b = w[self.first], w[self.first + 1]
        phi = np.zeros((*self.shape, 3))
        phi[self.move, self.slot] = 0.5 * (a + b) * self.dt + cross(a, b) * (self.dt**2 / 12.0)
        delta_r = quat_to_matrix(quat_chain(rotvec_to_quat(phi)))
        carried = np.einsum("mji,mj->mi", delta_r, self.u_start)  # ΔRᵀ u_start
        return np.asarray(carried - self.u_end, dtype=np.float64)


def _whitened(packed: _Packed, S: Array, sigmas: Array) -> Array:
    return np.asarray((packed.residuals(S) / sigmas[:, None]).reshape(-1), dtype=np.float64)


def start_scale(moves: Sequence[GravityMove], S0: Array) -> float:
    """Return the common factor ``k`` on ``S0`` whose moves carry gravity best (grid search)."""
    packed = _Packed(moves)
    costs = [float(np.sum(packed.residuals(k * S0) ** 2)) for k in SCALE_GRID]
    best = int(np.argmin(costs))
    lo, hi = max(best - 1, 0), min(best + 1, len(SCALE_GRID) - 1)
    fine = np.geomspace(SCALE_GRID[lo], SCALE_GRID[hi], 21)
    costs = [float(np.sum(packed.residuals(k * S0) ** 2)) for k in fine]
    return float(fine[int(np.argmin(costs))])


def solve_gravity_moves(
    moves: Sequence[GravityMove],
    S0: Array,
    rate_sigma_counts: Array,
    *,
    max_relative_sigma: float = DEFAULT_MAX_RELATIVE_SIGMA,
    max_iterations: int = 30,
) -> GravityMovesFit:
    """Fit S (counts per rad/s) to gravity-only moves (module doc)."""
    if len(moves) < 3:
        raise InputError(f"gyro from gravity moves: {len(moves)} moves (need at least 3)")
    notes: list[str] = []
    s0 = np.asarray(S0, dtype=float).reshape(3, 3)
    k = start_scale(moves, s0)
    if not 0.9 < k < 1.1:
        notes.append(f"the nominal gyro scale was off by a factor {k:.3f}; the fit starts there")
    start = k * s0
    noise = np.asarray(rate_sigma_counts, dtype=float).reshape(3)
    s = start.reshape(9).copy()
    sigmas = _sigmas(moves, noise, start)
    packed = _Packed(moves)
    for _ in range(max_iterations):
        r, jac = _linearise(packed, s, sigmas)
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        s += step
        sd = np.sqrt(np.abs(np.diag(np.linalg.pinv(jac.T @ jac))))
        if np.all(np.abs(step) <= 1e-4 * sd):
            break
    else:
        notes.append(f"gyro from gravity moves: Gauss–Newton stopped after {max_iterations} steps")
    r, jac = _linearise(packed, s, sigmas)
    chi2, dof, inflation = _chi2(r, len(moves), 9)
    cov = np.linalg.pinv(jac.T @ jac) * inflation**2
    scale = np.abs(np.diag(s.reshape(3, 3)))
    sd = np.sqrt(np.abs(np.diag(cov))).reshape(3, 3)
    cols = np.all(sd / scale[None, :] <= max_relative_sigma, axis=0)
    for j in np.flatnonzero(~cols):
        worst = float(np.max(sd[:, j]) / scale[j])
        notes.append(
            f"S column {AXES[j]} not identifiable from gravity alone: σ {worst:.3g} of its "
            f"scale (limit {max_relative_sigma:g}); held at the start value"
        )
    keep = np.repeat(cols[None, :], 3, axis=0).reshape(9)
    if not keep.any():
        raise InputError("gyro from gravity moves: the moves determine no column of S")
    if not keep.all():  # refit with the unseen columns held at the start
        s = np.where(keep, s, start.reshape(9))
        for _ in range(max_iterations):
            r, jac = _linearise(packed, s, sigmas)
            step = np.linalg.lstsq(jac[:, keep], -r, rcond=None)[0]
            s[keep] += step
            if np.all(np.abs(step) <= 1e-6 * scale.mean()):
                break
        r, jac = _linearise(packed, s, sigmas)
        chi2, dof, inflation = _chi2(r, len(moves), int(keep.sum()))
        cov = np.linalg.pinv(jac[:, keep].T @ jac[:, keep]) * inflation**2
    out = np.where(keep, s, np.nan).reshape(3, 3)
    sig = np.full(9, np.nan)
    sig[keep] = np.sqrt(np.abs(np.diag(cov)))
    if inflation > 1.0:
        notes.append(
            f"gravity moves: χ²/dof {chi2 / max(dof, 1):.3g}; σ of S scaled by {inflation:.3g}"
        )
    return GravityMovesFit(
        S=out,
        S_sigma=sig.reshape(3, 3),
        identifiable=cols,
        start=start,
        names=tuple(n for n, f in zip(S_NAMES, keep, strict=True) if f),
        covariance=np.asarray(cov, dtype=np.float64),
        residuals_rad=(r.reshape(-1, 3) * sigmas[:, None]),
        chi2=chi2,
        dof=dof,
        sigma_inflation=inflation,
        notes=tuple(notes),
    )


def _chi2(r: Array, n_moves: int, n_free: int) -> tuple[float, int, float]:
    """χ², dof (two informative components per move) and the σ inflation ``√(χ²/dof)`` ≥ 1."""
    chi2 = float(r @ r)
    dof = 2 * n_moves - n_free
    inflation = max(1.0, float(np.sqrt(chi2 / dof))) if dof > 0 else 1.0
    return chi2, dof, inflation


def _linearise(moves: _Packed, s: Array, sigmas: Array) -> tuple[Array, Array]:
    """Whitened residuals at ``s`` (9,) and their forward-difference Jacobian."""
    r = _whitened(moves, s.reshape(3, 3), sigmas)
    h = 1e-6 * float(np.mean(np.abs(s.reshape(3, 3).diagonal())))
    jac = np.empty((r.size, 9))
    for k in range(9):
        sp = s.copy()
        sp[k] += h
        jac[:, k] = (_whitened(moves, sp.reshape(3, 3), sigmas) - r) / h
    return r, jac
