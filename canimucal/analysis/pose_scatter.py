"""The pose-setting scatter of a calibration fit, estimated from its own positions.

``solve`` (and :func:`canimucal.analysis.calibrate.solve_positions`' callers) weight each
position by its within-position scatter plus the angle-setting scatter (errors in
variables, :mod:`canimucal.model.joint`). When no recording header gives that scatter, it is
estimated here with the same noise model as ``analyze`` (:mod:`.noise_model`, eq. 1): the
joint fit's residuals, its Jacobian as the design, ``C`` from the within-position scatter
and ``A`` from the angle derivatives of the predicted means, τ by REML. The fit is then
repeated with every pose's tolerance set to τ̂ (twice: τ̂ moves the estimate only slightly).
With few accelerometer residuals the σ rest on τ's one-sided 84 % upper bound, or on the
plan's tolerance where that is larger (:func:`fit_scatter`; docs/design.md §10).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.base_fit import UNIT_PROBE_RAD
from canimucal.analysis.noise_model import ScatterEstimate, ScatterModel, estimate_scatter
from canimucal.errors import InputError
from canimucal.io.recording import Recording
from canimucal.model.joint import JointResult, solve_joint, trial_contrast
from canimucal.model.layout import (
    JointSpec,
    ModelContext,
    ParameterLayout,
    angle_error_moments,
    nominal_theta,
    predict,
)
from canimucal.model.positions import DEFAULT_TOLERANCE_RAD, PositionAverage

Array = NDArray[np.float64]

PASSES = 2
"""Fit → estimate τ → refit rounds."""

MIN_SCATTER_DOF = 10
"""With fewer accelerometer residual dof the σ use the scatter's one-sided 84 % upper bound."""

ScatterBasis = Literal["estimated", "upper bound", "plan tolerance", "assumed"]
"""What the σ rest on: the REML estimate (enough dof), its one-sided 84 % upper bound (few
dof), the plan's tolerance (few dof, and above that bound), or the plans' default 0.1° (no
accelerometer residual at all); the calibration JSON's ``fit.pose_scatter_basis``."""


@dataclass(frozen=True)
class PoseScatter:
    """The pose scatter a solve used for its σ, the estimate behind it and why this value."""

    used: float
    """Radians: the angle-setting 1σ every pose carries in the fit (at least its plan's)."""
    basis: ScatterBasis
    estimate: ScatterEstimate | None
    """The REML estimate with its 95 % interval; None without accelerometer residuals."""
    dof: int
    """Accelerometer residual dof the estimate rests on."""

    @property
    def used_deg(self) -> float:
        """The scatter used, in degrees."""
        return float(np.rad2deg(self.used))

    def note(self) -> str:
        """One line for ``solve``'s notes: the value, what it rests on and which was used."""
        head = f"pose-setting scatter {self.used_deg:.3g}°"
        if self.estimate is None and self.basis == "plan tolerance":
            return (
                f"{head}, the plan's tolerance: no accelerometer residual dof to estimate it "
                "from; no tolerance_deg header"
            )
        if self.estimate is None:
            return (
                f"{head} assumed (the plans' default tolerance): no accelerometer residual "
                "dof to estimate it from; no tolerance_deg header"
            )
        assert self.estimate is not None
        low, high = self.estimate.ci95_deg
        reml = f"REML {self.estimate.value_deg:.3g}°, 95 % {low:.3g}–{high:.3g}°"
        if self.basis == "estimated":
            return (
                f"{head} estimated from the data ({reml}, {self.dof} accelerometer residual "
                f"dof; τ̂² ×{precision_factor(self.estimate.dof):.3g} for its own uncertainty, "
                f"ν = {self.estimate.dof:.3g}); no tolerance_deg header"
            )
        few = f"only {self.dof} accelerometer residual dof ({reml})"
        if self.basis == "upper bound":
            return (
                f"{head} used for the σ: its one-sided 84 % upper bound, {few}; "
                "no tolerance_deg header"
            )
        return (
            f"{head} used for the σ: the plan's tolerance, above the data's 84 % upper bound "
            f"with {few}; no tolerance_deg header"
        )


def header_tolerance_deg(rec: Recording) -> float | None:
    """Return the recording's ``tolerance_deg`` header (angle-setting 1σ), None without one."""
    value = rec.header.get("tolerance_deg")
    if value is None:
        return None
    try:
        tol = float(value)
    except (TypeError, ValueError):
        tol = float("nan")
    if not (np.isfinite(tol) and tol >= 0):
        raise InputError(f"header tolerance_deg must be a finite number >= 0, got {value!r}")
    return tol


def with_tolerance(averages: Sequence[PositionAverage], tol_rad: float) -> list[PositionAverage]:
    """Copy ``averages`` with every pose's tolerance set to ``tol_rad``."""
    return [
        dataclasses.replace(a, pose=dataclasses.replace(a.pose, tolerance=tol_rad))
        for a in averages
    ]


def fit_scatter(
    averages: Sequence[PositionAverage],
    spec: JointSpec,
    *,
    g: float,
    latitude: float | None = None,
    heading: float = 0.0,
    accel_lsb: float,
    gyro_lsb: float,
    planned: Sequence[float] | None = None,
) -> tuple[list[PositionAverage], PoseScatter]:
    """Estimate the pose scatter under ``spec``; return the averages carrying the σ's scatter.

    Only the accelerometer's residuals carry the poses (the gyro's see them through the
    Earth rate alone, far below its noise), so the dof are theirs (:func:`accel_dof`). With
    :data:`MIN_SCATTER_DOF` or more the REML estimate τ̂ is used, its square scaled by
    :func:`precision_factor` for its own uncertainty. With fewer, τ̂ is too uncertain to
    carry the σ: plugged in, the five-position plan's errors (7 dof) spread 1.62× their σ at
    0.1° (largest |z| 6.1; issue 21 item 6), so an upper confidence bound is used, or the
    plan's tolerance (``planned``, one 1σ per position, when the recording's header names the
    plan) where that is larger. The bound is the one-sided 84 % one, the end of τ's 1σ
    profile interval (:func:`~canimucal.analysis.noise_model.estimate_scatter`): the σ are
    to be right on average, and over 40 seeds of the five plan at 0.1° the errors spread
    0.88–1.07 times their σ with it (0.75–0.87 with the one-sided 95 % bound, 0.82–0.98 with
    90 %). Without any accelerometer residual the plan's tolerance, else the plans' default
    0.1°, is assumed.
    """
    dof = accel_dof(len(averages), spec, trials=max(1, len(trial_contrast(averages)[0])))
    floor = np.zeros(len(averages)) if planned is None else np.asarray(planned, dtype=float)
    if dof <= 0:
        if planned is None:
            tol = DEFAULT_TOLERANCE_RAD
            return with_tolerance(averages, tol), PoseScatter(tol, "assumed", None, dof)
        return _at_least(averages, floor, 0.0), PoseScatter(max(floor), "plan tolerance", None, dof)
    current = with_tolerance(averages, 0.0)
    estimate = ScatterEstimate(0.0, (0.0, 0.0), "estimated", float("nan"))
    for _ in range(PASSES):
        res = solve_joint(
            current, spec, g=g, latitude=latitude, heading=heading,
            accel_lsb=accel_lsb, gyro_lsb=gyro_lsb, allow_undetermined=True,
        )  # fmt: skip
        estimate = scatter_of(res, current, ModelContext.build(g, latitude, heading, gyro_lsb))
        current = with_tolerance(averages, estimate.value)
    if dof >= MIN_SCATTER_DOF:
        used = estimate.value * np.sqrt(precision_factor(estimate.dof))
        return with_tolerance(averages, used), PoseScatter(used, "estimated", estimate, dof)
    bound = estimate.upper84
    basis: ScatterBasis = "plan tolerance" if np.any(floor > bound) else "upper bound"
    used = max(bound, float(np.max(floor)))
    return _at_least(averages, floor, bound), PoseScatter(used, basis, estimate, dof)


def precision_factor(nu: float) -> float:
    """``ν/(ν − 2)``: what τ̂² is multiplied by so that the σ it gives are right on average.

    With ``θ̂ = τ̂²`` distributed as ``θ χ²_ν/ν`` (Satterthwaite's ν,
    :func:`~canimucal.analysis.noise_model.scatter_dof`), ``E[θ/θ̂] = ν/(ν − 2)``: plugged in
    as it is, τ̂ gives errors that spread ``√(ν/(ν − 2))`` times their σ where the scatter
    dominates (1.18 at the recommended plan's ν ≈ 8, 0.1° poses). Capped at 2 (ν ≤ 4: a
    scatter that hardly shows beside the noise, so the factor hardly matters).
    """
    if not np.isfinite(nu) or nu <= 4.0:
        return 2.0
    return float(nu / (nu - 2.0))


def _at_least(
    averages: Sequence[PositionAverage], floor: Array, tol: float
) -> list[PositionAverage]:
    """Copy ``averages`` with each pose's tolerance the larger of ``tol`` and its ``floor``."""
    return [
        dataclasses.replace(a, pose=dataclasses.replace(a.pose, tolerance=max(tol, float(f))))
        for a, f in zip(averages, floor, strict=True)
    ]


def accel_dof(n_positions: int, spec: JointSpec, trials: int = 1) -> int:
    """Residual dof of the accelerometer: 3 per position less its parameters (and tilt).

    Less 3 per trial beyond the first: each trial's own biases.
    """
    own = [n for n in ParameterLayout.of(spec).names if not n.startswith("gyro.")]
    return 3 * n_positions - len(own) - 3 * (trials - 1)


def scatter_of(
    res: JointResult, averages: Sequence[PositionAverage], ctx: ModelContext
) -> ScatterEstimate:
    """REML pose scatter of one joint fit (noise_model eq. 1, design = the fit's Jacobian)."""
    layout = ParameterLayout.of(res.spec)
    nominal = nominal_theta(layout, res.accel_lsb, res.gyro_lsb)
    theta = np.where(np.isnan(res.values), nominal, res.values)
    angles = np.array([a.pose.angles for a in averages])
    n, m = res.residuals.shape
    _ids, contrast = trial_contrast(averages)
    columns = np.einsum("nj,cd->ncjd", contrast, np.eye(m)).reshape(n, m, -1)
    d_theta = np.concatenate([predict(layout, theta, angles, ctx).d_theta, columns], axis=2)
    design = d_theta.reshape(n * m, -1)  # the trials' own biases, where any, beside theta
    probe = np.full(n, UNIT_PROBE_RAD)
    unit_blocks = angle_error_moments(layout, theta, angles, ctx, probe).covariance
    unit_blocks = unit_blocks / UNIT_PROBE_RAD**2
    within = np.zeros((n, m, m))
    for k, a in enumerate(averages):
        within[k, :3, :3] = a.cov_accel
        if m == 6 and a.cov_gyro is not None:
            within[k, 3:, 3:] = a.cov_gyro
    model = ScatterModel(_block_diag(within), _block_diag(unit_blocks), "estimated")
    # residuals are observed − predicted; the angle mean shift is zero at τ = 0 and small
    # beside the noise for the τ that exact poses give
    return estimate_scatter(model, res.residuals.ravel(), design)


def _block_diag(blocks: Array) -> Array:
    n, m = blocks.shape[:2]
    out = np.zeros((n * m, n * m))
    for k in range(n):
        out[k * m : (k + 1) * m, k * m : (k + 1) * m] = blocks[k]
    return out
