"""What a plan promises before the first position: its times, its bounds, its acceptance.

The one source of a plan's figures (docs/design.md §3): the TUI's plan screen, ``canimucal
plan``, the certificate and the field guide read them here, from the plan registry and the
session's averaging rule.

- :func:`schedule` — each position's seconds, the total and the operator's minutes, as the
  session will average them (:func:`~canimucal.procedure.averaging.plan_schedule`).
- :func:`plan_bounds` — the Cramér–Rao table at those seconds, for the model the plan's
  session fits (:func:`session_spec`) and its prior on K.
- :func:`forecast` — each acceptance limit in force beside the σ the same bound predicts at
  the nominal noise of the built-in node with each position's angle tolerance, and which
  limits this plan cannot meet, so the operator learns it before the jacking starts.
  Limits that depend on the data (fit rms, χ² p, the re-read after the write) are listed
  as checked on the data.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, replace

import numpy as np

from canimucal.analysis.acceptance import AcceptanceConfig, AcceptanceLimits
from canimucal.model.layout import TRIM_NAMES, GyroSpec, JointSpec
from canimucal.model.plan import BoundTable, cramer_rao, plan_prior
from canimucal.model.positions import Plan
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, STANDARD_GRAVITY
from canimucal.model.vocabulary.plans import CUSTOM, PLANS, builtin_names, builtin_plan
from canimucal.procedure.averaging import (
    AveragingPolicy,
    PlanSchedule,
    plan_schedule,
    scheduled_plan,
)
from canimucal.procedure.config import ProcedureConfig
from canimucal.procedure.pose_picture import field_guide
from canimucal.sim.truth import DEFAULT_ACCEL_NOISE_DENSITY

NOISE_DENSITY_MS2 = DEFAULT_ACCEL_NOISE_DENSITY
"""The accelerometer noise the forecast assumes (m/s²/√Hz): the built-in node's."""


@dataclass(frozen=True)
class LimitForecast:
    """One acceptance limit beside what the plan predicts for it (None: data decide)."""

    key: str
    what: str
    limit: float
    unit: str
    predicted: float | None
    upper: bool = True
    """True for a maximum (σ ≤ limit), False for a minimum (p ≥ limit)."""

    @property
    def meets(self) -> bool | None:
        """Whether the predicted value meets the limit (None when the data decide)."""
        if self.predicted is None:
            return None
        return self.predicted <= self.limit if self.upper else self.predicted >= self.limit

    def line(self) -> str:
        """One line: the limit, the prediction and the verdict."""
        sign = "≤" if self.upper else "≥"
        unit = f" {self.unit}" if self.unit else ""
        head = f"{self.what} {sign} {self.limit:g}{unit}"
        if self.predicted is None:
            return f"{head}: checked on the data"
        verdict = "can meet it" if self.meets else "CANNOT meet it"
        value = f"{self.predicted:.3g}" if self.predicted < 100 else f"{self.predicted:.0f}"
        return f"{head}: plan predicts {value}{unit}, {verdict}"


def schedule(plan: Plan, policy: AveragingPolicy | None = None) -> PlanSchedule:
    """Each position's seconds and the operator's minutes under ``policy`` (module doc)."""
    return plan_schedule(plan, policy)


def session_spec(plan_name: str, gyro: GyroSpec = "none") -> JointSpec:
    """Return the accelerometer model the session of ``plan_name`` fits (its registry entry).

    A name the registry does not hold is fitted as ``custom`` is (full K and base tilt).
    """
    entry = PLANS.get(plan_name) or PLANS[CUSTOM]
    return JointSpec(accel_k=entry.accel_k, tilt=entry.tilt, gyro=gyro, trim=entry.trim)


def plan_bounds(
    plan: Plan,
    spec: JointSpec,
    *,
    policy: AveragingPolicy | None = None,
    accel_lsb: float = DEFAULT_ACCEL_LSB,
    g: float = STANDARD_GRAVITY,
    noise_density_counts: float = 1.0,
    include_tolerance: bool = False,
    prior_k_sigma: float | None = None,
    latitude: float | None = None,
) -> BoundTable:
    """Return the Cramér–Rao table of ``plan`` at the seconds its session averages.

    White noise ``noise_density_counts`` counts/√Hz (1 for the plan's table), K = I/LSB, zero
    tilt, the plan's prior on K (``prior_k_sigma`` overrides its relative σ).
    """
    timed = scheduled_plan(plan, schedule(plan, policy))
    prior = plan_prior(timed, spec, accel_lsb, k_sigma=prior_k_sigma)
    return cramer_rao(
        timed,
        spec,
        k_nominal_counts_per_ms2=1.0 / abs(accel_lsb),
        g=g,
        noise_density=noise_density_counts,
        latitude=latitude,
        include_tolerance=include_tolerance,
        prior_sigma={name: sigma for name, (_mean, sigma) in prior.items()},
    )


def table_cells(table: BoundTable) -> list[tuple[str, str, str, str]]:
    """Return the bound table as the plan screen and ``plan`` print it: name, σ, unit, effect.

    σ in the parameter's own unit (the tilt in degrees), the effect at 1 g in counts;
    "—" and "undetermined" for what the plan cannot determine.
    """
    rows = []
    for r in table.rows:
        name = r.name.replace("base_tilt.", "tilt.")
        if r.sigma is None or r.effect_counts is None:
            rows.append((name, "—", r.unit, "undetermined"))
            continue
        sigma = float(np.rad2deg(r.sigma)) if r.unit == "rad" else float(r.sigma)
        unit = "deg" if r.unit == "rad" else r.unit
        rows.append((name, f"{sigma:.4g}", unit, f"{r.effect_counts:.4g}"))
    return rows


def forecast(
    plan: Plan,
    limits: AcceptanceLimits,
    spec: JointSpec,
    *,
    policy: AveragingPolicy | None = None,
    accel_lsb: float = DEFAULT_ACCEL_LSB,
    g: float = STANDARD_GRAVITY,
    prior_k_sigma: float | None = None,
) -> list[LimitForecast]:
    """Each acceptance limit beside the σ ``plan`` predicts for it (docs/design.md §3).

    The bound of :func:`plan_bounds` at the built-in node's noise with each position's angle
    tolerance, at the seconds ``policy`` gives the positions.
    """
    k = 1.0 / abs(accel_lsb)
    table = plan_bounds(
        plan,
        spec,
        policy=policy,
        accel_lsb=accel_lsb,
        g=g,
        noise_density_counts=NOISE_DENSITY_MS2 * k,
        include_tolerance=True,
        prior_k_sigma=prior_k_sigma,
    )
    bias_mg, scale_ppm = _predicted(table, accel_lsb, g, k)
    return [
        LimitForecast("max_bias_sigma_mg", "worst bias σ", limits.max_bias_sigma_mg, "mg", bias_mg),
        LimitForecast(
            "max_scale_sigma_ppm", "worst scale σ", limits.max_scale_sigma_ppm, "ppm", scale_ppm
        ),
        LimitForecast("max_rms_ms2", "fit rms", limits.max_rms_ms2, "m/s²", None),
        LimitForecast("min_fit_p", "fit χ² p", limits.min_fit_p, "", None, upper=False),
        LimitForecast(
            "max_verify_norm_error_mg",
            "|f| − g after the write",
            limits.max_verify_norm_error_mg,
            "mg",
            None,
        ),
        LimitForecast(
            "max_verify_tilt_error_deg",
            "tilt error after the write",
            limits.max_verify_tilt_error_deg,
            "°",
            None,
        ),
    ]


def session_forecast(config: ProcedureConfig, node_id: int) -> list[LimitForecast]:
    """Return the forecast of a session's plan for one node, as its plan screen showed it.

    The session's limits, averaging rule, accelerometer model, site (LSB, g) and the prior
    on K it holds for ``node_id``.
    """
    prior = config.k_priors.get(node_id)
    return forecast(
        config.plan,
        config.limits,
        JointSpec(accel_k=config.spec.accel_k, tilt=config.spec.tilt, trim=config.spec.trim),
        policy=config.averaging,
        accel_lsb=config.site.accel_lsb,
        g=config.site.g,
        prior_k_sigma=None if prior is None else prior.rel_sigma,
    )


def _predicted(
    table: BoundTable, accel_lsb: float, g: float, k: float
) -> tuple[float | None, float | None]:
    """Worst predicted accel bias σ (mg) and diagonal scale σ (ppm), as acceptance reads them."""
    diag = {f"accel.K[{i}][{i}]" for i in range(3)}
    bias, scale = [], []
    for row in table.rows:
        if row.sigma is None:
            continue  # undetermined: not checked (docs/design.md §3)
        if row.name.startswith("accel.bias["):
            bias.append(float(row.sigma) * abs(accel_lsb) / g * 1000.0)
        elif row.name in diag:
            scale.append(float(row.sigma) / k * 1e6)
    return (max(bias) if bias else None), (max(scale) if scale else None)


def trim_forecast(
    plan: Plan,
    spec: JointSpec,
    *,
    policy: AveragingPolicy | None = None,
    accel_lsb: float = DEFAULT_ACCEL_LSB,
    g: float = STANDARD_GRAVITY,
    prior_k_sigma: float | None = None,
) -> tuple[float, float, float] | None:
    """Return the mounting trim's predicted σ (alpha, beta, psi; degrees); None: not fitted.

    The same bound as :func:`forecast` (the session's seconds, angle tolerances, the built-in
    node's noise, the plan's prior on K): only a plan that fits the trim (``spec.trim``)
    determines it.
    """
    if not spec.trim:
        return None
    k = 1.0 / abs(accel_lsb)
    table = plan_bounds(
        plan,
        replace(spec, gyro="none", gyro_g=False),
        policy=policy,
        accel_lsb=accel_lsb,
        g=g,
        noise_density_counts=NOISE_DENSITY_MS2 * k,
        include_tolerance=True,
        prior_k_sigma=prior_k_sigma,
    )
    sigmas = [table.bound(name).sigma for name in TRIM_NAMES]
    if any(s is None for s in sigmas):
        return None
    alpha, beta, psi = (float(np.rad2deg(s)) for s in sigmas if s is not None)
    return alpha, beta, psi


def forecast_lines(
    rows: list[LimitForecast],
    plan_name: str,
    width: int = 78,
    trim: tuple[float, float, float] | None = None,
) -> list[str]:
    """Word the forecast for the plan screen and ``plan``: head, one line a limit, summary.

    ``trim``: the mounting trim's predicted σ (:func:`trim_forecast`), said after the limits
    (no acceptance limit holds it).
    """
    lines = [
        "acceptance limits in force, and the σ this plan predicts (each position's angle "
        f"tolerance, noise {NOISE_DENSITY_MS2:g} m/s²/√Hz):",
        *[f"  {r.line()}" for r in rows],
    ]
    if trim is not None:
        lines.append(
            f"  mounting trim (no limit): plan predicts σ {trim[0]:.2g}° alpha, "
            f"{trim[1]:.2g}° beta, {trim[2]:.2g}° psi"
        )
    cannot = [r.key for r in rows if r.meets is False]
    if cannot:
        lines.append(
            f"this plan cannot meet {', '.join(cannot)}: it fails acceptance however well "
            f"the positions are set (loosen the limit for it with [plan.{plan_name}] in "
            "acceptance.toml, or choose another plan)"
        )
    else:
        lines.append("this plan can meet the limits known before the data")
    out: list[str] = []
    for line in lines:
        indent = " " * (len(line) - len(line.lstrip()))
        out += textwrap.wrap(line, width, subsequent_indent=indent + "  ") or [""]
    return out


def forecast_document(rows: list[LimitForecast]) -> list[dict[str, object]]:
    """Return the JSON form (``plan --json``'s ``acceptance``)."""
    return [
        {
            "key": r.key,
            "limit": r.limit,
            "unit": r.unit,
            "predicted": r.predicted,
            "meets": r.meets,
        }
        for r in rows
    ]


def guide_notes(plan_name: str, plan: Plan) -> list[str]:
    """Return the field guide's line of what ``plan`` predicts against its built-in limits.

    The forecast of :func:`forecast` with the limits the plan holds to by default (its
    registry entry over the built-in ones; ``canimucal plan`` shows the user's).
    """
    limits = AcceptanceConfig().limits(plan_name)
    rows = forecast(plan, limits, session_spec(plan_name))
    known = [r for r in rows if r.predicted is not None]
    parts = [r.line() for r in known]
    return [
        "Predicted before the first position (built-in acceptance limits; `canimucal plan` "
        f"shows the limits in force): {'; '.join(parts)}."
    ]


def field_guide_pages() -> tuple[str, dict[str, str]]:
    """Return docs/field-guide.md and its pictures: every built-in plan, timed and forecast."""
    plans = {name: builtin_plan(name) for name in builtin_names()}
    notes = {name: guide_notes(name, plan) for name, plan in plans.items()}
    return field_guide(list(plans.values()), notes)
