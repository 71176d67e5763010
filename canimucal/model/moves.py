"""Gyro scale and misalignment from moves: quaternion integration and the joint fit of S.

A *move* is a stretch of raw gyro samples during which the unit turns from one attitude to
another that is known: from one labelled position to the next (the plan's direction cosine
matrices give ``M = C_end C_startᵀ``), or a turn of known angle about a known body axis
(imucal's 360° turns: ``M = I`` after a full turn, the angle itself from the axis and the
sign). ``M`` maps body-frame coordinates of a fixed world vector at the start to those at the
end: ``f_end = M f_start``.

**Integration.** The rate samples ``w_k = S⁻¹ (V_k − B − G f_k)`` (rad/s) are combined into
increments ``φ_k = ½ (w_k + w_{k+1}) Δt + (1/12) (w_k × w_{k+1}) Δt²`` (trapezoid plus the
two-sample coning term: exact to third order for a rate linear in time), then into the
body-to-start quaternion ``q = q_0 ⊗ exp(φ_0/2) ⊗ … ⊗ exp(φ_{n-2}/2)`` (Savage, Strapdown
Analytics §7). The product is associative, so it is formed by pairwise reduction, all moves
at once. The gyro senses the rate against inertial space; the level frame itself turns with
the Earth at ``w_E`` (start body frame), so the known ``M`` corresponds to
``M = ΔRᵀ exp([w_E]× T)`` with ``ΔR`` the integrated body rotation (exact for a constant
Earth rate; ``T`` the move's duration).

**Fit.** The residual of move ``k`` is the rotation vector ``e_k = log(M_pred(S) M_kᵀ)``
(rad). Its errors are of three kinds, and the fit is generalised least squares over their
full covariance ``R`` (``3m × 3m``):

- the angle random walk of the gyro's white noise over the move, independent per move,
  ``σ_arw² = σ_rate² Δt² (n − 1.5)`` per axis for the trapezoid weights;
- the known attitude change's own error, independent per move, ``sigma_rad`` per axis
  (a known turn's angle; zero for a move between positions whose errors are shared);
- errors shared between moves that touch the same still position ``p`` (:class:`Shared`):
  the attitude the unit really had there, ``C_p' = exp([ε_p]×) C_p`` with ``ε_p`` of
  covariance ``Σ_p`` (:func:`attitude_covariance`), and the error ``δm_p`` of that position's
  mean gyro (covariance ``Π_p``, counts²). The move from ``a`` to ``b`` really makes
  ``M' = exp([ε_b]×) M exp(−[ε_a]×)``, and its bias is ``(m_a + m_b)/2``, so to first order

      ``e_k = ε_b − M_k ε_a + ½ J_B,k (δm_a + δm_b)``, ``J_B,k = ∂e_k/∂B``       (F1)

  and ``R_kl = Σ_p D_kp Σ_p D_lpᵀ + ¼ Σ_p J_B,k Π_p J_B,lᵀ`` over the positions ``p`` both
  moves touch (``D_kp = I`` at the end, ``−M_k`` at the start).                    (F2)

``S`` (3×3, counts per rad/s) minimises ``r(S)ᵀ R⁻¹ r(S)`` (Gauss–Newton on the residuals
whitened by the Cholesky factor ``R = L Lᵀ``; Jacobian in :func:`move_residual`); its
covariance is ``(Jᵀ R⁻¹ J)⁻¹`` at the solution (Aitken's GLS).

**Identifiability.** Column ``j`` of ``S`` is the response to a rate about body axis ``j``:
only moves that turn about axis ``j`` see it. A column is not identifiable when the moves
turn less than ``min_turn_deg`` about its axis along the way (:func:`path_turn`), or when
its σ would exceed ``max_relative_sigma`` of its scale (moves that cancel each other's
view of it). It is held at its prior and reported as such (``None``), never as a number;
the prior's own 1σ (:data:`PRIOR_SCALE_SIGMA`) enters the covariance of the entries
fitted beside it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError
from canimucal.model.frames import position_dcm

Array = NDArray[np.float64]

PositionKey = int | tuple[int, int]
"""A still position's key: its label, or ``(trial, label)`` in a recording of several trials."""

AXES = "xyz"
S_NAMES = tuple(f"S_{AXES[i]}{AXES[j]}" for i in range(3) for j in range(3))
"""Names of S's entries in row-major order: ``S_xy`` is axis x's response to a rate about y."""

DEFAULT_MAX_RELATIVE_SIGMA = 0.02
"""A column of S whose σ would exceed this fraction of its scale factor is not identifiable."""

PRIOR_SCALE_SIGMA = 0.03
PRIOR_CROSS_SIGMA = 0.01
"""1σ of a held column of S about its prior, as fractions of the scale factor: a scale
error (diagonal) and a cross-axis term (off-diagonal) of a MEMS gyro's data sheet."""

DEFAULT_MIN_TURN_DEG = 20.0
"""Total turn about a body axis below which that column of S is not identifiable."""


# ----------------------------------------------------------------------------- quaternions


def cross(a: Array, b: Array) -> Array:
    """Return ``a × b`` along the last axis (numpy's ``cross`` without its call overhead)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def quat_multiply(p: Array, q: Array) -> Array:
    """Hamilton product ``p ⊗ q`` of ``(..., 4)`` arrays ``[w, x, y, z]``."""
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def rotvec_to_quat(phi: Array) -> Array:
    """``exp(φ/2)`` as ``(..., 4)`` quaternions for rotation vectors ``φ`` ``(..., 3)``."""
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a, with its series near 0 (error < 1e-17 for a < 1e-4)
    k = np.where(
        angle > 1e-4, np.sin(half) / np.where(angle > 1e-4, angle, 1.0), 0.5 - angle**2 / 48
    )
    return np.concatenate([np.cos(half), k * phi], axis=-1)


def quat_to_matrix(q: Array) -> Array:
    """Rotation matrix ``R`` (body → start frame) of unit quaternions ``(..., 4)``."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def rotvec_to_matrix(phi: ArrayLike) -> Array:
    """``exp([φ]×)`` for rotation vectors ``(..., 3)``."""
    return quat_to_matrix(rotvec_to_quat(np.asarray(phi, dtype=float)))


def matrix_to_rotvec(r: Array) -> Array:
    """Return the rotation vector ``log(R)`` of rotation matrices ``(..., 3, 3)`` (angle < π)."""
    cos = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    v = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    sin = np.sin(angle)[..., None]
    k = np.where(sin > 1e-8, angle[..., None] / np.where(sin > 1e-8, 2.0 * sin, 1.0), 0.5)
    out = k * v
    near_pi = angle > np.pi - 1e-3  # the antisymmetric part vanishes: axis from R + I
    if np.any(near_pi):
        c = cos[near_pi][:, None, None]
        rn = r[near_pi]
        sym = (0.5 * (rn + np.swapaxes(rn, -1, -2)) - c * np.eye(3)) / (1.0 - c)  # u uᵀ
        col = np.argmax(np.diagonal(sym, axis1=-2, axis2=-1), axis=-1)
        u = np.take_along_axis(sym, col[:, None, None], axis=-1)[..., 0]
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        sign = np.where(np.sum(u * v[near_pi], axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
        out[near_pi] = sign * u * angle[near_pi][:, None]
    return np.asarray(out, dtype=np.float64)


def quat_chain(q: Array) -> Array:
    """Ordered product ``q_0 ⊗ q_1 ⊗ …`` along axis -2 of ``(..., n, 4)`` (pairwise)."""
    while q.shape[-2] > 1:
        if q.shape[-2] % 2:
            identity = np.zeros((*q.shape[:-2], 1, 4))
            identity[..., 0] = 1.0
            q = np.concatenate([q, identity], axis=-2)
        q = quat_multiply(q[..., 0::2, :], q[..., 1::2, :])
    return q[..., 0, :]


def integrate_rates(rates: ArrayLike, dt_s: float) -> Array:
    """Body rotation ``ΔR`` (body at the end → body at the start) from rate samples (rad/s).

    ``rates`` is ``(n, 3)`` or ``(m, n, 3)`` (m moves of equal length), sampled every
    ``dt_s``; the increments are the coning-corrected trapezoid of the module doc. A world-
    fixed vector with body coordinates ``v`` at the start has ``ΔRᵀ v`` at the end.
    """
    w = np.asarray(rates, dtype=float)
    if w.ndim < 2 or w.shape[-1] != 3 or w.shape[-2] < 2:
        raise InputError("integrate_rates: need at least two (n, 3) rate samples")
    a, b = w[..., :-1, :], w[..., 1:, :]
    phi = 0.5 * (a + b) * dt_s + cross(a, b) * (dt_s * dt_s / 12.0)
    return quat_to_matrix(quat_chain(rotvec_to_quat(phi)))


def move_rotation(rates: ArrayLike, dt_s: float, earth_rate_body: ArrayLike | None = None) -> Array:
    """``M = ΔRᵀ exp([w_E]× T)``: the change of body coordinates of a fixed level-frame vector.

    ``rates`` are the sensed (inertial) body rates, bias removed; ``earth_rate_body`` the
    Earth rate in the start body frame (rad/s), or ``None`` when the caller removed it with
    the bias.
    """
    w = np.asarray(rates, dtype=float)
    m = np.swapaxes(integrate_rates(w, dt_s), -1, -2)
    if earth_rate_body is not None:
        duration = (w.shape[-2] - 1) * dt_s
        m = m @ rotvec_to_matrix(np.asarray(earth_rate_body, dtype=float) * duration)
    return m


def axis_turn(axis: int, angle_rad: float) -> Array:
    """``M`` of a turn of the body by ``angle_rad`` about its own axis (right hand)."""
    phi = np.zeros(3)
    phi[axis] = angle_rad
    return np.asarray(rotvec_to_matrix(phi).T, dtype=np.float64)


# ----------------------------------------------------------------------------------- moves


@dataclass(frozen=True)
class Move:
    """One move: raw gyro samples spanning it and the attitude change it is known to make.

    ``gyro`` ``(n, 3)`` counts, from the last still sample before to the first after;
    ``rotation`` the known ``M`` (``f_end = M f_start``); ``turn_rad`` the rotation vector
    the move is known to turn through (body axes; a 360° turn has ``M = I`` but
    ``turn_rad = ±2π e_j``); ``sigma_rad`` the 1σ per axis of the known attitude change;
    ``earth_rate_body`` the Earth rate in the start body
    frame (rad/s), ``None`` when it stays in the bias; ``specific_force`` ``(n, 3)`` m/s² for
    the G term, ``None`` to skip it. ``fixed_axis``: the body turns about one fixed axis
    throughout, so the integral of the rate vector itself is known (``turn_rad``); the
    residual is then that integral's error (see :func:`move_residual`). ``positions``: the
    keys of the still positions the move starts and ends at, when their attitude errors and
    mean gyro errors are shared with other moves (:class:`Shared`); the move's bias is then
    the mean of those two positions' means.
    """

    gyro: Array
    dt_s: float
    rotation: Array
    turn_rad: Array
    sigma_rad: float
    label: str = ""
    earth_rate_body: Array | None = None
    specific_force: Array | None = None
    fixed_axis: bool = False
    positions: tuple[PositionKey, PositionKey] | None = None

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample."""
        return float((self.gyro.shape[0] - 1) * self.dt_s)


def pose_move(
    gyro: ArrayLike,
    dt_s: float,
    c_start: ArrayLike,
    c_end: ArrayLike,
    sigma_rad: float,
    label: str = "",
    earth_rate_body: ArrayLike | None = None,
    positions: tuple[PositionKey, PositionKey] | None = None,
) -> Move:
    """Build the move between two positions with direction cosine matrices body ← L.

    ``M = C_end C_startᵀ``; the turn is ``log(M)`` (a move between positions is shorter than
    180°, so the rotation vector is the turn made). ``positions``: see :class:`Move`.
    """
    m = np.asarray(c_end, float) @ np.asarray(c_start, float).T
    turn = -matrix_to_rotvec(m)  # the body turns by the inverse of the frame change
    return Move(
        gyro=np.asarray(gyro, dtype=float),
        dt_s=float(dt_s),
        rotation=m,
        turn_rad=turn,
        sigma_rad=float(sigma_rad),
        label=label,
        earth_rate_body=None if earth_rate_body is None else np.asarray(earth_rate_body, float),
        positions=positions,
    )


@dataclass(frozen=True)
class Shared:
    """Errors shared by the moves that touch one still position (module doc, F1–F2).

    ``attitude`` maps a position's key to the covariance (rad², 3×3, in that position's body
    axes) of the error ``ε_p`` of the attitude the unit really had there; ``mean_gyro`` to
    the covariance (counts²) of that position's mean gyro, half of each adjacent move's bias.
    A key missing from either map contributes nothing.
    """

    attitude: Mapping[PositionKey, Array]
    mean_gyro: Mapping[PositionKey, Array]


def attitude_covariance(angles: ArrayLike, tolerances: ArrayLike) -> Array:
    """Covariance (rad²) of the attitude error ``ε`` of a pose set to within ``tolerances``.

    The pose ``(alpha, beta, psi)`` (rad) is set with independent 1σ errors ``tolerances``
    (rad); ``C' = exp([ε]×) C`` with ``ε = Σ_i a_i δ_i``, ``a_i = log(∂C/∂angle_i Cᵀ)`` the
    axis (body frame) each angle turns about (``position_dcm``, docs/design.md §2), so
    ``Σ = A diag(tolerance²) Aᵀ``. At ``beta = ±90°`` the axes of alpha and psi coincide
    and ``Σ`` is singular in the unturned direction: the pose's errors are not isotropic.
    """
    a0 = np.asarray(angles, dtype=float).reshape(3)
    tol = np.broadcast_to(np.asarray(tolerances, dtype=float), (3,))
    c = position_dcm(*a0)
    h = 1e-6
    steps = np.concatenate([np.eye(3), -np.eye(3)]) * h
    turned = np.stack([position_dcm(*(a0 + step)) @ c.T for step in steps])
    eps = matrix_to_rotvec(turned)  # central differences of ε over each angle
    a = ((eps[:3] - eps[3:]) / (2 * h)).T
    return np.asarray(a @ np.diag(tol**2) @ a.T, dtype=np.float64)


def turn_move(
    gyro: ArrayLike,
    dt_s: float,
    axis: int,
    angle_rad: float,
    sigma_rad: float,
    label: str = "",
    earth_rate_body: ArrayLike | None = None,
) -> Move:
    """Build a turn of known angle about the fixed body axis ``axis`` (0, 1, 2).

    The rate vector stays along the axis, so its integral is ``angle_rad e_axis``: this sees
    the axis's misalignment, which the attitude after a full turn (``M = I`` whatever the
    axis) does not.
    """
    turn = np.zeros(3)
    turn[axis] = angle_rad
    return Move(
        gyro=np.asarray(gyro, dtype=float),
        dt_s=float(dt_s),
        rotation=axis_turn(axis, angle_rad),
        turn_rad=turn,
        sigma_rad=float(sigma_rad),
        label=label,
        earth_rate_body=None if earth_rate_body is None else np.asarray(earth_rate_body, float),
        fixed_axis=True,
    )


def corrected_rates(move: Move, S: Array, bias: Array, G: Array | None = None) -> Array:
    """``S⁻¹ (V − B − G f)`` of the move's samples (rad/s)."""
    v = move.gyro - bias
    if G is not None and move.specific_force is not None:
        v = v - move.specific_force @ G.T
    return np.asarray(np.linalg.solve(S, v.T).T, dtype=np.float64)


def predicted_rotation(move: Move, S: Array, bias: Array, G: Array | None = None) -> Array:
    """``M`` the move makes according to the gyro corrected with ``S``, ``bias`` and ``G``."""
    w = corrected_rates(move, S, bias, G)
    return move_rotation(w, move.dt_s, move.earth_rate_body)


def path_turn(move: Move, S: Array, bias: Array, G: Array | None = None) -> Array:
    """Angle (rad) turned about each body axis along the way: ``∫ |w_j| dt``.

    What a column of S is seen through: a move that tilts about z and back turns 0° net
    but still excites column z.
    """
    w = np.abs(corrected_rates(move, S, bias, G))
    return _rate_integral(w, move.dt_s)


def integrated_turn(move: Move, S: Array, bias: Array, G: Array | None = None) -> Array:
    """Return the turn (rotation vector, rad, body axes) the corrected gyro integrates to.

    For a turn beyond 180° (a full turn) the rotation vector of ``M`` wraps; this is the
    known turn plus the rotation vector of ``ΔR`` relative to the known one.
    """
    if move.fixed_axis:
        return _rate_integral(corrected_rates(move, S, bias, G), move.dt_s)
    error = matrix_to_rotvec(predicted_rotation(move, S, bias, G) @ move.rotation.T)
    return np.asarray(move.turn_rad - error, dtype=np.float64)


def _rate_integral(w: Array, dt_s: float) -> Array:
    """Trapezoid integral of the rate vector (rad)."""
    return np.asarray((w.sum(axis=0) - 0.5 * (w[0] + w[-1])) * dt_s, dtype=np.float64)


# ------------------------------------------------------------------------------------- fit


@dataclass(frozen=True)
class MovesFit:
    """S from moves: values, σ, and what the moves could not determine.

    ``S`` and ``S_sigma`` are 3×3 with ``nan`` in columns that are not identifiable
    (``identifiable[j]`` false; ``prior`` holds the value used for them while fitting).
    ``covariance`` is over :attr:`names` (the free entries, row-major), and includes the
    error the held columns' prior (:data:`PRIOR_SCALE_SIGMA`) can leave in them;
    ``residuals_rad`` the ``(m, 3)`` rotation-vector residuals, ``sigmas_rad`` each move's
    own (unshared) 1σ per axis and ``residual_covariance`` the full ``3m × 3m`` covariance
    ``R`` of the residuals (F2); ``chi2`` (``rᵀ R⁻¹ r``) and ``dof`` of the fit.
    """

    S: Array
    S_sigma: Array
    identifiable: NDArray[np.bool_]
    prior: Array
    names: tuple[str, ...]
    covariance: Array
    residuals_rad: Array
    sigmas_rad: Array
    chi2: float
    dof: int
    turned_deg: Array
    notes: tuple[str, ...] = field(default=())
    residual_covariance: Array = field(default_factory=lambda: np.zeros((0, 0)))

    def S_used(self) -> Array:
        """S with the prior in the columns the moves did not determine."""
        return np.where(np.isnan(self.S), self.prior, self.S)


def move_sigma(move: Move, rate_sigma_counts: Array, S: Array) -> float:
    """1σ per axis (rad) of the move's own residual error: its ``sigma_rad`` and the ARW."""
    rate_sigma = float(np.mean(np.abs(rate_sigma_counts) / np.abs(np.diag(S))))
    n = move.gyro.shape[0]
    arw2 = rate_sigma**2 * move.dt_s**2 * max(n - 1.5, 0.5)
    return float(np.sqrt(move.sigma_rad**2 + arw2))


@dataclass(frozen=True)
class _Weights:
    """What the whitening needs besides the moves: their own σ and the shared errors."""

    sigmas: Array
    shared: Shared | None


def solve_moves(
    moves: Sequence[Move],
    bias: ArrayLike,
    S0: ArrayLike,
    rate_sigma_counts: ArrayLike,
    *,
    G: ArrayLike | None = None,
    shared: Shared | None = None,
    min_turn_deg: float = DEFAULT_MIN_TURN_DEG,
    max_relative_sigma: float = DEFAULT_MAX_RELATIVE_SIGMA,
    max_iterations: int = 20,
) -> MovesFit:
    """Fit S (counts per rad/s) to the moves by Gauss–Newton on the GLS residuals (module doc).

    ``bias`` (counts) and ``G`` are held; ``S0`` is the start and the prior of columns the
    moves cannot see; ``rate_sigma_counts`` the per-sample white noise σ of each gyro axis;
    ``shared`` the errors moves share through their positions (F1–F2), None for none.
    """
    if not moves:
        raise InputError("gyro from moves: no moves")
    b = np.asarray(bias, dtype=float).reshape(3)
    s0 = np.asarray(S0, dtype=float).reshape(3, 3)
    g = None if G is None else np.asarray(G, dtype=float).reshape(3, 3)
    noise = np.asarray(rate_sigma_counts, dtype=float).reshape(3)
    turned = np.rad2deg(np.sum([path_turn(m, s0, b, g) for m in moves], axis=0))
    free_cols = turned >= min_turn_deg
    notes = [
        f"S column {AXES[j]} not identifiable: the moves turn {turned[j]:.1f}° about body "
        f"{AXES[j]} (need {min_turn_deg:g}°); held at its prior"
        for j in range(3)
        if not free_cols[j]
    ]
    weights = _Weights(np.array([move_sigma(m, noise, s0) for m in moves]), shared)
    r, jac, chol = _whitened(moves, s0, b, g, weights)
    free_cols = _precise_columns(jac, s0, free_cols, max_relative_sigma, notes)
    if not free_cols.any():
        return _unidentified(s0, turned, notes)
    free = np.repeat(free_cols[None, :], 3, axis=0).reshape(9)
    s = s0.reshape(9).copy()
    for _ in range(max_iterations):  # Gauss–Newton on the whitened residuals
        step = np.linalg.lstsq(jac[:, free], -r, rcond=None)[0]
        s[free] += step
        info = jac[:, free].T @ jac[:, free]
        sigma = np.sqrt(np.abs(np.diag(np.linalg.pinv(info))))
        r, jac, chol = _whitened(moves, s.reshape(3, 3), b, g, weights)
        if np.all(np.abs(step) <= 1e-4 * sigma):  # converged far below the noise
            break
    else:
        notes.append(f"gyro from moves: Gauss–Newton stopped after {max_iterations} steps")
    try:
        cov = _free_covariance(jac, free, s0)
    except np.linalg.LinAlgError:
        raise InputError("gyro from moves: the moves do not determine S (singular)") from None
    out = np.where(free, s, np.nan)
    sig = np.full(9, np.nan)
    sig[free] = np.sqrt(np.diag(cov))
    return MovesFit(
        S=out.reshape(3, 3),
        S_sigma=sig.reshape(3, 3),
        identifiable=free_cols,
        prior=s0,
        names=tuple(n for n, f in zip(S_NAMES, free, strict=True) if f),
        covariance=cov,
        residuals_rad=(chol @ r).reshape(-1, 3),
        sigmas_rad=weights.sigmas,
        chi2=float(r @ r),
        dof=3 * len(moves) - int(free.sum()),
        turned_deg=turned,
        notes=tuple(notes),
        residual_covariance=chol @ chol.T,
    )


def _prior_covariance(s0: Array, held: NDArray[np.bool_]) -> Array:
    """Diagonal covariance of the held entries (row-major) of S about the prior ``s0``."""
    rel = np.full((3, 3), PRIOR_CROSS_SIGMA)
    np.fill_diagonal(rel, PRIOR_SCALE_SIGMA)
    sd = (rel * np.abs(np.diag(s0))[None, :]).reshape(9)[held]
    return np.diag(sd**2)


def _free_covariance(jac: Array, free: NDArray[np.bool_], s0: Array) -> Array:
    """Covariance of the free entries: noise, plus the held entries' prior through the fit.

    ``Σ = A⁻¹ + K Σ_h Kᵀ`` with ``A = J_fᵀ J_f`` and ``K = A⁻¹ J_fᵀ J_h`` (``J`` whitened,
    so ``A = J_fᵀ R⁻¹ J_f``): the error a held column's prior leaves in the free ones (a
    tilt move that also turns about z carries S's z column into the estimate of its x
    column).
    """
    jf, jh = jac[:, free], jac[:, ~free]
    a_inv = np.linalg.inv(jf.T @ jf)
    if not (~free).any():
        return np.asarray(a_inv, dtype=np.float64)
    k = a_inv @ jf.T @ jh
    return np.asarray(a_inv + k @ _prior_covariance(s0, ~free) @ k.T, dtype=np.float64)


def _precise_columns(
    jac: Array,
    s0: Array,
    cols: NDArray[np.bool_],
    max_relative_sigma: float,
    notes: list[str],
) -> NDArray[np.bool_]:
    """Drop, worst first, columns whose predicted σ exceeds ``max_relative_sigma`` · scale.

    The σ are those of the linearised fit at ``s0`` (whitened Jacobian ``jac`` there) over
    the columns still free, with the held columns' prior (:func:`_free_covariance`); a
    column the moves see only through a cancelling path (a turn about y during a tilt
    about x) has a σ too large to be a calibration.
    """
    cols = cols.copy()
    scale = np.abs(np.diag(s0))
    while cols.any():
        free = np.repeat(cols[None, :], 3, axis=0).reshape(9)
        info = jac[:, free].T @ jac[:, free]
        if np.linalg.matrix_rank(info) < info.shape[0]:
            var = np.full(info.shape[0], np.inf)
        else:
            var = np.diag(_free_covariance(jac, free, s0))
        col_sigma = np.full(3, -np.inf)
        col_sigma[cols] = np.sqrt(var).reshape(3, -1).max(axis=0) / scale[cols]
        worst = int(np.argmax(col_sigma))
        if col_sigma[worst] <= max_relative_sigma:
            break
        cols[worst] = False
        notes.append(
            f"S column {AXES[worst]} not identifiable: the moves would give it a σ of "
            f"{col_sigma[worst]:.2g} of its scale (limit {max_relative_sigma:g}); held at its prior"
        )
    return cols


def _unidentified(s0: Array, turned: Array, notes: list[str]) -> MovesFit:
    nan = np.full((3, 3), np.nan)
    return MovesFit(
        S=nan,
        S_sigma=nan.copy(),
        identifiable=np.zeros(3, dtype=bool),
        prior=s0,
        names=(),
        covariance=np.zeros((0, 0)),
        residuals_rad=np.zeros((0, 3)),
        sigmas_rad=np.zeros(0),
        chi2=0.0,
        dof=0,
        turned_deg=turned,
        notes=tuple(notes),
    )


def _prefix_products(q: Array) -> Array:
    """Inclusive prefix products ``q_0 ⊗ … ⊗ q_k`` of ``(n, 4)`` (Hillis–Steele scan)."""
    q = q.copy()
    d = 1
    while d < q.shape[0]:
        q[d:] = quat_multiply(q[:-d], q[d:])
        d *= 2
    return q


def move_residual(move: Move, S: Array, bias: Array, G: Array | None = None) -> tuple[Array, Array]:
    """Residual ``e = log(M_pred M_knownᵀ)`` (rad) and its Jacobian ``(3, 9)`` over ``S``.

    With ``P_k`` the body rotation from the start to sample ``k``, a change ``δS`` changes
    the rates by ``δw_k = −S⁻¹ δS w_k`` and the end attitude by
    ``δθ = Σ_k c_k Δt (ΔRᵀ P_k) δw_k`` (trapezoid weights ``c_k``), so ``e`` changes by
    ``−δθ`` to first order in the (small) residual.

    A fixed-axis move's residual is ``e = ∫ w dt − turn`` (trapezoid), linear in ``S⁻¹``:
    ``∂e/∂S_ij = −(S⁻¹)_ai (∫ w dt)_j`` (imucal's eq. 13–15 in rotation-vector form).
    """
    e, jac, _ = _residual_parts(move, S, bias, G)
    return e, jac


def _residual_parts(
    move: Move, S: Array, bias: Array, G: Array | None
) -> tuple[Array, Array, Array]:
    """:func:`move_residual` and the Jacobian ``(3, 3)`` of ``e`` over the bias (counts).

    A bias change ``δB`` changes every rate by ``δw_k = −S⁻¹ δB``, so
    ``∂e/∂B = Σ_k c_k Δt ΔRᵀ P_k S⁻¹`` (``−S⁻¹ T`` for a fixed-axis move).
    """
    w = corrected_rates(move, S, bias, G)
    dt = move.dt_s
    s_inv = np.linalg.inv(S)
    if move.fixed_axis:
        integral = _rate_integral(w, dt)
        jac_axis = -np.einsum("ai,j->aij", s_inv, integral).reshape(3, 9)
        return (
            integral - move.turn_rad,
            np.asarray(jac_axis, dtype=np.float64),
            np.asarray(-s_inv * move.duration_s, dtype=np.float64),
        )
    a, b = w[:-1], w[1:]
    phi = 0.5 * (a + b) * dt + cross(a, b) * (dt * dt / 12.0)
    prefix = quat_to_matrix(_prefix_products(rotvec_to_quat(phi)))
    delta_r = prefix[-1]
    m = delta_r.T
    if move.earth_rate_body is not None:
        m = m @ rotvec_to_matrix(move.earth_rate_body * move.duration_s)
    e = matrix_to_rotvec(m @ move.rotation.T)
    p = np.concatenate([np.eye(3)[None], prefix], axis=0)  # P_0 = I, …, P_{n-1} = ΔR
    weights = np.full(w.shape[0], dt)
    weights[[0, -1]] = 0.5 * dt
    a_k = delta_r.T @ p @ s_inv  # (n, 3, 3): ΔRᵀ P_k S⁻¹
    jac = np.einsum("k,kai,kj->aij", weights, a_k, w).reshape(3, 9)
    jac_bias = np.einsum("k,kai->ai", weights, a_k)
    return (
        np.asarray(e, dtype=np.float64),
        np.asarray(jac, dtype=np.float64),
        np.asarray(jac_bias, dtype=np.float64),
    )


def residual_covariance(
    moves: Sequence[Move], bias_jacobians: Sequence[Array], sigmas: Array, shared: Shared | None
) -> Array:
    """Covariance ``R`` (``3m × 3m``, rad²) of the moves' residuals: eq. (F2) of the module doc.

    ``bias_jacobians`` are the ``∂e_k/∂B`` of :func:`_residual_parts`; ``sigmas`` each move's
    own 1σ per axis (:func:`move_sigma`).
    """
    m = len(moves)
    cov = np.asarray(np.kron(np.diag(np.asarray(sigmas, dtype=float) ** 2), np.eye(3)), float)
    if shared is None:
        return cov
    touches: dict[PositionKey, list[tuple[int, Array, Array]]] = {}
    for k, (move, jb) in enumerate(zip(moves, bias_jacobians, strict=True)):
        if move.positions is None:
            continue
        start, end = move.positions
        touches.setdefault(start, []).append((k, -move.rotation, 0.5 * jb))
        touches.setdefault(end, []).append((k, np.eye(3), 0.5 * jb))
    for key, rows in touches.items():
        att = shared.attitude.get(key)
        mean = shared.mean_gyro.get(key)
        d = np.zeros((3 * m, 3))
        h = np.zeros((3 * m, 3))
        for k, dk, hk in rows:
            d[3 * k : 3 * k + 3] += dk
            h[3 * k : 3 * k + 3] += hk
        if att is not None:
            cov += d @ np.asarray(att, dtype=float) @ d.T
        if mean is not None:
            cov += h @ np.asarray(mean, dtype=float) @ h.T
    return np.asarray(cov, dtype=np.float64)


def moves_covariance(
    moves: Sequence[Move],
    biases: Sequence[Array],
    S: Array,
    rate_sigma_counts: ArrayLike,
    shared: Shared | None = None,
) -> Array:
    """Covariance ``R`` (F2) of the residuals of ``moves``, each with its own bias, at ``S``.

    For moves not used in a fit (held out): with the fit's covariance ``C`` of S and the
    residuals' Jacobian ``J``, the residuals of calibrated moves have ``J C Jᵀ + R``.
    """
    noise = np.asarray(rate_sigma_counts, dtype=float).reshape(3)
    jb = [_residual_parts(m, S, b, None)[2] for m, b in zip(moves, biases, strict=True)]
    sigmas = np.array([move_sigma(m, noise, S) for m in moves])
    return residual_covariance(moves, jb, sigmas, shared)


def _whitened(
    moves: Sequence[Move], S: Array, bias: Array, G: Array | None, weights: _Weights
) -> tuple[Array, Array, Array]:
    """Whitened residuals ``L⁻¹ r`` ``(3m,)``, Jacobian ``L⁻¹ J`` ``(3m, 9)`` and ``L``.

    ``R = L Lᵀ`` is the residuals' covariance (:func:`residual_covariance`) at ``S``.
    """
    parts = [_residual_parts(move, S, bias, G) for move in moves]
    r = np.concatenate([e for e, _, _ in parts])
    jac = np.concatenate([j for _, j, _ in parts])
    cov = residual_covariance(moves, [jb for _, _, jb in parts], weights.sigmas, weights.shared)
    try:
        chol = np.asarray(np.linalg.cholesky(cov), dtype=np.float64)
    except np.linalg.LinAlgError:
        raise InputError(
            "gyro from moves: the moves' errors have a singular covariance (a gyro without "
            "noise and poses set exactly?)"
        ) from None
    white = np.asarray(np.linalg.solve(chol, np.column_stack([r, jac])), dtype=np.float64)
    return white[:, 0], white[:, 1:], chol  # L is small: 3m ≤ a few hundred rows


def crlb(
    moves: Sequence[Move],
    bias: ArrayLike,
    S: ArrayLike,
    sigmas_rad: ArrayLike,
    shared: Shared | None = None,
) -> Array:
    """Cramér–Rao bound (covariance, 9×9 over :data:`S_NAMES`) of S at ``S`` for the moves.

    The inverse Fisher information ``(Jᵀ R⁻¹ J)⁻¹`` of the residuals at ``S``, with ``R``
    from the moves' own ``sigmas_rad`` and the ``shared`` errors (F2).
    """
    s = np.asarray(S, dtype=float).reshape(3, 3)
    weights = _Weights(np.asarray(sigmas_rad, dtype=float), shared)
    _, jac, _ = _whitened(moves, s, np.asarray(bias, float), None, weights)
    return np.asarray(np.linalg.inv(jac.T @ jac), dtype=np.float64)
