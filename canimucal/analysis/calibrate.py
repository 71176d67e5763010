"""From position averages to a calibration record.

The solve step shared by `canimucal solve`, the guided procedure and the demo.

Known angles: the joint estimator (model/joint.py). No angles: the scalar |f| = g fit
(model/scalar.py). Parameters the plan cannot determine are held at nominal and come out
``null`` with the reason; poorly separable ones keep their (large) σ and a warning.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import ModelError
from canimucal.io.calibration import (
    Calibration,
    Conditions,
    Device,
    Fit,
    Prior,
    RecordingRef,
    TrialSummary,
    record_from_estimates,
    summarize_position,
)
from canimucal.model.chi2_tail import chi2_sf
from canimucal.model.joint import JointResult, solve_joint
from canimucal.model.layout import JointSpec
from canimucal.model.plan import cramer_rao
from canimucal.model.positions import Plan, PlannedPosition, PositionAverage
from canimucal.model.scalar import ScalarFit, fit_scalar_averages
from canimucal.model.vocabulary.plans import CUSTOM, SCALAR, plan_of_poses

LACK_OF_FIT_P = 1e-3
"""A fit whose χ² has a p-value below this gets a lack-of-fit warning."""
MISFIT_P = 0.01
"""Below this p-value of the fit's χ² the model is rejected and its σ are inflated by the
Birge factor √(χ²/dof) (docs/design.md §10, σ under misfit)."""


@dataclass(frozen=True)
class FitQuality:
    """The fit's χ² against the noise it was weighted with, and the σ inflation applied."""

    chi2: float
    dof: int
    inflation: float = 1.0

    @property
    def p_value(self) -> float:
        """χ² tail probability (NaN without residual dof)."""
        if self.dof <= 0:
            return float("nan")
        return chi2_sf(self.dof, self.chi2)

    @property
    def rejected(self) -> bool:
        """Whether the model is rejected (p below :data:`MISFIT_P`)."""
        return self.dof > 0 and self.p_value < MISFIT_P

    def line(self, against: str = "the within-position noise") -> str:
        """One line: χ²/dof ``against`` the noise the fit used, p, what was done with σ."""
        ratio = self.chi2 / self.dof if self.dof > 0 else float("nan")
        text = (
            f"fit χ²/dof {ratio:.4g} on {self.dof} dof against {against} (p = {self.p_value:.2g})"
        )
        if self.inflation > 1.0:
            text += (
                f": the model does not fit, σ inflated ×{self.inflation:.3g} "
                "(Birge factor √(χ²/dof))"
            )
        return text


def birge(chi2: float, dof: int) -> FitQuality:
    """Return the fit's quality and, when the model is rejected, its Birge factor √(χ²/dof)."""
    quality = FitQuality(chi2, dof)
    if quality.rejected and chi2 > dof:
        return FitQuality(chi2, dof, float(np.sqrt(chi2 / dof)))
    return quality


_ANGLE_MATCH_RAD = float(np.deg2rad(0.05))


@dataclass(frozen=True)
class SiteConditions:
    """g (m/s²), latitude and heading (radians or None), nominal LSBs, temperature."""

    g: float
    latitude: float | None = None
    heading: float = 0.0
    height_m: float | None = None
    accel_lsb: float = 9.80665 / 2048.0
    gyro_lsb: float = float(np.pi / (180.0 * 16.4))
    temp_c: float | None = None

    def as_record_conditions(self) -> Conditions:
        """Return the ``conditions`` block of the calibration JSON (degrees)."""
        return Conditions(
            g=self.g,
            latitude_deg=None if self.latitude is None else float(np.rad2deg(self.latitude)),
            height_m=self.height_m,
            heading_deg=float(np.rad2deg(self.heading)),
            temp_c=self.temp_c,
        )


@dataclass(frozen=True)
class Solution:
    """A solved calibration: the record to save/write, the fit behind it, and its warnings."""

    record: Calibration
    joint: JointResult | None = None
    scalar: ScalarFit | None = None
    undetermined: dict[str, str] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    quality: FitQuality | None = None
    """χ²/dof against the within-position noise (and pose scatter) the fit used, and the
    Birge inflation of every σ when the model is rejected."""


def plan_name_of(averages: Sequence[PositionAverage]) -> str:
    """Name the built-in plan whose poses these are (the plan registry's), else ``custom``."""
    angles = np.array([a.pose.angles for a in averages])
    return plan_of_poses(angles, _ANGLE_MATCH_RAD) or CUSTOM


def solve_positions(
    averages: Sequence[PositionAverage],
    spec: JointSpec,
    site: SiteConditions,
    device: Device,
    *,
    recording: RecordingRef | None = None,
    plan_name: str | None = None,
    prior: Mapping[str, tuple[float, float]] | None = None,
    prior_source: str = "factory K",
) -> Solution:
    """Joint least squares over labelled positions with known angles.

    ``prior`` (``{name: (mean, σ)}``, e.g. :func:`canimucal.model.plan.plan_prior`) holds
    what the plan cannot separate at a stated prior; the record lists it under ``priors``.
    ModelError (exit 2) for fewer than two positions or a plan whose poses are all the same.
    """
    _check_positions(averages)
    result = solve_joint(
        averages,
        spec,
        g=site.g,
        latitude=site.latitude,
        heading=site.heading,
        accel_lsb=site.accel_lsb,
        gyro_lsb=site.gyro_lsb,
        allow_undetermined=True,
        prior=prior,
        unknown_earth_rate=True,
    )
    quality = birge(result.chi2, result.dof)
    if quality.inflation > 1.0:
        trial_cov = result.trial_bias_cov
        result = replace(
            result,
            covariance=result.covariance * quality.inflation**2,
            trial_bias_cov=None if trial_cov is None else trial_cov * quality.inflation**2,
        )
    keep = [i for i, n in enumerate(result.names) if n not in result.undetermined]
    names = [result.names[i] for i in keep]
    record = record_from_estimates(
        names,
        result.values[keep],
        result.covariance[np.ix_(keep, keep)],
        device=device,
        held_fixed=dict(result.undetermined),
        plan=plan_name or plan_name_of(first_trial(averages)),
        conditions=site.as_record_conditions(),
        positions=[summarize_position(a) for a in averages],
        fit=Fit(rms=result.rms_accel_ms2, dof=result.dof),
        recording=recording,
        priors=[
            Prior(name=n, mean=m, sigma=s, source=prior_source)
            for n, (m, s) in (prior or {}).items()
        ],
    )
    if result.trials:
        record = replace(record, trials=trial_summaries(result, averages))
    warnings = _prior_warnings(prior, prior_source) + _correlation_warnings(result)
    warnings += _plan_warnings(averages, spec, site, warnings) + _lack_of_fit_warning(result)
    if not result.converged:
        warnings += (f"the least-squares fit did not converge: {result.message}",)
    return Solution(
        record,
        joint=result,
        undetermined=dict(result.undetermined),
        warnings=warnings,
        quality=quality,
    )


def first_trial(averages: Sequence[PositionAverage]) -> list[PositionAverage]:
    """Return the first trial's positions (all of them without trials): the plan's poses."""
    first = averages[0].trial if averages else None
    return [a for a in averages if a.trial == first]


def trial_summaries(
    result: JointResult, averages: Sequence[PositionAverage]
) -> tuple[TrialSummary, ...]:
    """Return the record's ``trials``: each trial's biases with σ (accelerometer, then gyro)."""
    assert result.trial_bias is not None and result.trial_bias_cov is not None
    out = []
    for k, trial in enumerate(result.trials):
        bias = result.trial_bias[k]
        sigma = np.sqrt(np.clip(np.diagonal(result.trial_bias_cov[k]), 0.0, None))

        def vec(x: NDArray[np.float64]) -> tuple[float | None, ...]:
            return tuple(None if not np.isfinite(v) else float(v) for v in x)

        gyro = bias.size == 6
        out.append(
            TrialSummary(
                trial=int(trial),
                positions=sum((a.trial if a.trial is not None else -1) == trial for a in averages),
                accel_bias=vec(bias[:3]),
                accel_bias_sigma=vec(sigma[:3]),
                gyro_bias=vec(bias[3:]) if gyro else None,
                gyro_bias_sigma=vec(sigma[3:]) if gyro else None,
            )
        )
    return tuple(out)


def trials_line(record: Calibration) -> str | None:
    """``4 trials: one bias each, K shared`` and each trial's accelerometer bias, or None."""
    if not record.trials:
        return None

    def counts(v: Sequence[float | None] | None) -> str:
        return "[" + ", ".join("—" if x is None else f"{x:.3f}" for x in (v or ())) + "]"

    parts = [
        f"trial {t.trial}: {counts(t.accel_bias)} ± {counts(t.accel_bias_sigma)}"
        for t in record.trials
    ]
    shared = "K and S shared" if record.gyro is not None else "K shared"
    return (
        f"{len(record.trials)} trials: one bias each, {shared}; accelerometer bias (counts) "
        + "; ".join(parts)
    )


def _prior_warnings(
    prior: Mapping[str, tuple[float, float]] | None, source: str
) -> tuple[str, ...]:
    """State the prior: its σ bounds what these positions cannot separate."""
    if not prior:
        return ()
    sigmas = sorted({s for _m, s in prior.values()})
    text = ", ".join(f"{s:.4g}" for s in sigmas)
    return (
        f"{', '.join(prior)} held at the stated prior ({source}, σ {text} counts/(m/s²)); "
        "these positions cannot separate them from the biases, and the σ include the prior",
    )


def _check_positions(averages: Sequence[PositionAverage]) -> None:
    """Refuse data no calibration can come from: one position, or one pose repeated."""
    if len(averages) < 2:
        raise ModelError(f"need at least 2 positions, got {len(averages)}")
    poses = {tuple(np.round(np.rad2deg(a.pose.angles), 6).tolist()) for a in averages}
    if len(poses) < 2:
        alpha, beta, psi = next(iter(poses))
        raise ModelError(
            f"degenerate plan: all {len(averages)} positions have the same angles "
            f"({alpha:g}, {beta:g}, {psi:g}) deg; a calibration needs different poses"
        )


def _plan_warnings(
    averages: Sequence[PositionAverage],
    spec: JointSpec,
    site: SiteConditions,
    already: tuple[str, ...],
) -> tuple[str, ...]:
    """Correlations above 0.999 of the positions as a plan at docs/design.md §3's reference noise.

    The fit's own correlations include the angle tolerances, which can mask a combination
    the plan itself barely separates (bias z against beta0 in the paper's five positions,
    -0.9996 in ``canimucal plan``); this names it too. With trials the plan's information
    gives each trial its own biases (their offsets marginalised, as the fit does), so what
    is named is what these positions separate beside every trial's biases.
    """
    plan = Plan(
        "recorded",
        tuple(
            PlannedPosition(
                a.pose.alpha,
                a.pose.beta,
                a.pose.psi,
                a.pose.tolerance,
                a.seconds if a.seconds > 0 else 1.0,
            )
            for a in averages
        ),
    )
    latitude = site.latitude if spec.gyro == "nav" else None
    table = cramer_rao(
        plan,
        spec,
        k_nominal_counts_per_ms2=1.0 / site.accel_lsb,
        g=site.g,
        latitude=latitude,
        gyro_lsb=site.gyro_lsb,
        trials=[a.trial for a in averages] if any(a.trial is not None for a in averages) else None,
    )
    out = []
    for f in table.separability.findings:
        if f.correlation is None or any(all(n in w for n in f.parameters) for w in already):
            continue
        out.append(
            f"{f.message} in this plan: the positions barely tell them apart; their σ says how much"
        )
    return tuple(out)


def _lack_of_fit_warning(result: JointResult) -> tuple[str, ...]:
    """Warn when the residuals exceed the predicted noise and angle errors (χ² test)."""
    if result.dof <= 0:
        return ()
    p = chi2_sf(result.dof, result.chi2)
    if p >= LACK_OF_FIT_P:
        return ()
    return (
        f"the model does not fit the data: chi2 {result.chi2:.1f} on {result.dof} dof "
        f"(p = {p:.1e}); a term is missing (try --tilt, --model full) or a position moved",
    )


def _correlation_warnings(result: JointResult) -> tuple[str, ...]:
    """Warnings for parameter pairs correlated beyond 0.999 in the fit (docs/design.md §3).

    Only the correlation criterion is used here: in a real fit the channels' precisions differ
    by orders of magnitude (level channels see no angle error, tilted ones do), so the
    eigenvalue ratios of the whitened information measure precision, not separability. The
    plan table (`canimucal plan`) applies both criteria at docs/design.md §3's reference noise.
    """
    seen: set[frozenset[str]] = set()
    out = []
    for f in result.separability.findings:
        key = frozenset(f.parameters)
        if f.correlation is None or key in seen:
            continue
        seen.add(key)
        out.append(f"{f.message}: the data barely tell them apart; their σ says how much")
    return tuple(out)


def solve_scalar(
    averages: Sequence[PositionAverage],
    site: SiteConditions,
    device: Device,
    *,
    full: bool,
    recording: RecordingRef | None = None,
) -> Solution:
    """Fit |f| = g (6 or 9 parameters) to static means of unknown orientation.

    Averages of several trials (the unit re-mounted: docs/design.md §10 *Trials*) give each
    trial its own bias and share K, as with known angles; the record's ``accel.bias`` is the
    trials' mean and ``trials`` lists each one's.
    """
    by_trial = len({a.trial for a in averages}) > 1
    fit = fit_scalar_averages(
        averages, site.g, model="9" if full else "6", accel_lsb=site.accel_lsb, by_trial=by_trial
    )
    quality = birge(fit.reduced_chi2 * fit.dof, fit.dof)
    if quality.inflation > 1.0:
        fit = replace(fit, covariance=fit.covariance * quality.inflation**2)
    core = [k for k, n in enumerate(fit.param_names) if not n.startswith("trial_offset")]
    names = [f"accel.{fit.param_names[k]}" for k in core]
    record = record_from_estimates(
        names,
        fit.params[core],
        fit.covariance[np.ix_(core, core)],
        device=device,
        plan=SCALAR,
        conditions=site.as_record_conditions(),
        positions=[summarize_position(a) for a in averages],
        fit=Fit(rms=fit.rms_mps2, dof=fit.dof),
        recording=recording,
    )
    if fit.trials:
        record = replace(record, trials=scalar_trial_summaries(fit, averages))
    warnings: tuple[str, ...] = ()
    if not fit.converged:
        warnings = (f"the scalar fit did not converge: {fit.message}",)
    return Solution(record, scalar=fit, warnings=warnings, quality=quality)


def scalar_trial_summaries(
    fit: ScalarFit, averages: Sequence[PositionAverage]
) -> tuple[TrialSummary, ...]:
    """Return the record's ``trials`` of a |f| = g fit: each trial's accelerometer bias and σ."""
    assert fit.trial_bias is not None and fit.trial_bias_sigma is not None
    return tuple(
        TrialSummary(
            trial=int(trial),
            positions=sum((a.trial if a.trial is not None else -1) == trial for a in averages),
            accel_bias=tuple(float(v) for v in fit.trial_bias[k]),
            accel_bias_sigma=tuple(float(v) for v in fit.trial_bias_sigma[k]),
        )
        for k, trial in enumerate(fit.trials)
    )
