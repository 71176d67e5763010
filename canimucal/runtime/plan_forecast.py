"""What a plan can promise against the acceptance limits, before the first position.

The plan screen and ``canimucal plan`` show each limit in force beside the σ the plan's
Cramér–Rao bound predicts (docs/design.md §3: the same bound as the plan's table, here at
the nominal noise of the built-in node and the plan's prior on K), and say which limits
this plan cannot meet, so the operator learns it before the jacking starts, not after.
Limits that depend on the data (fit rms, χ² p, the re-read after the write) are listed as
checked on the data.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, replace

import numpy as np

from canimucal.analysis.acceptance import AcceptanceLimits
from canimucal.model.layout import TRIM_NAMES, JointSpec
from canimucal.model.plan import BoundTable, cramer_rao, plan_prior
from canimucal.model.positions import Plan
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, STANDARD_GRAVITY
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


def forecast(
    plan: Plan,
    limits: AcceptanceLimits,
    spec: JointSpec,
    *,
    accel_lsb: float = DEFAULT_ACCEL_LSB,
    g: float = STANDARD_GRAVITY,
    prior_k_sigma: float | None = None,
) -> list[LimitForecast]:
    """Each acceptance limit beside the σ ``plan`` predicts for it (docs/design.md §3)."""
    k = 1.0 / abs(accel_lsb)
    prior = plan_prior(plan, spec, accel_lsb, k_sigma=prior_k_sigma)
    table = cramer_rao(
        plan,
        spec,
        k_nominal_counts_per_ms2=k,
        g=g,
        noise_density=NOISE_DENSITY_MS2 * k,
        include_tolerance=True,
        prior_sigma={name: sigma for name, (_mean, sigma) in prior.items()},
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
    ]


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
    accel_lsb: float = DEFAULT_ACCEL_LSB,
    g: float = STANDARD_GRAVITY,
    prior_k_sigma: float | None = None,
) -> tuple[float, float, float] | None:
    """Return the mounting trim's predicted σ (alpha, beta, psi; degrees); None: not fitted.

    The same bound as :func:`forecast` (angle tolerances, the built-in node's noise, the
    plan's prior on K): only a plan that fits the trim (``spec.trim``) determines it.
    """
    if not spec.trim:
        return None
    k = 1.0 / abs(accel_lsb)
    prior = plan_prior(plan, spec, accel_lsb, k_sigma=prior_k_sigma)
    table = cramer_rao(
        plan,
        replace(spec, gyro="none", gyro_g=False),
        k_nominal_counts_per_ms2=k,
        g=g,
        noise_density=NOISE_DENSITY_MS2 * k,
        include_tolerance=True,
        prior_sigma={name: sigma for name, (_mean, sigma) in prior.items()},
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
