"""Acceptance limits checked before a write is offered: σ of the estimates and the residual.

- worst accelerometer bias σ (mg: counts × |LSB| / g × 1000);
- worst relative σ of a scale factor (ppm of |K_ii|);
- the fit's rms residual (m/s², after correction);
- the χ² lack-of-fit p-value (too small: the model does not explain the data).

Parameters the plan cannot determine (held at nominal) are not checked; the report names them.
The library judges against the built-in :class:`AcceptanceLimits` unless it is given others;
it never reads the user's file on its own (docs/design.md §1, §3). The shells do: they read
``acceptance.toml`` in the user's config directory (:func:`acceptance_config_path`) into an
:class:`AcceptanceConfig` and pass it in. Its keys are those of :class:`AcceptanceLimits`, each
optional; a table ``[plan.NAME]`` with the same keys overrides them for the sessions and
recordings of plan NAME: the vehicle plan holds K at a 1 % prior, so its bias σ cannot go
below ~10 mg and a quality department that accepts that for vehicles says so there, not by
lowering the limit for every bench calibration.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from canimucal.analysis.calibrate import SiteConditions, Solution
from canimucal.errors import InputError
from canimucal.io.calibration import Acceptance
from canimucal.model.chi2_tail import chi2_sf
from canimucal.model.vocabulary.plans import PLANS
from canimucal.schema import parse_toml
from canimucal.user_dirs import config_dir


@dataclass(frozen=True)
class AcceptanceLimits:
    """Limits a calibration must meet before it is offered for writing."""

    max_bias_sigma_mg: float = 5.0
    max_scale_sigma_ppm: float = 3000.0
    max_rms_ms2: float = 0.05
    min_fit_p: float = 1e-4
    max_verify_norm_error_mg: float = 5.0
    """Verification: |f| − g of the calibrated re-read at each verification pose, mg."""
    max_verify_tilt_error_deg: float = 2.0
    """Verification: the calibrated direction of f against the pose's (with the fitted base
    tilt), degrees: above the pose-setting error of a vehicle tilt (0.5° 1σ: beyond 2° at
    3e-4), below what a wrong sign, a swapped axis or a bias of ~35 mg would show."""

    def as_dict(self) -> dict[str, float]:
        """Return the limits by key, as ``acceptance.toml`` and the calibration JSON name them."""
        return {f.name: float(getattr(self, f.name)) for f in dataclasses.fields(self)}


@dataclass(frozen=True)
class AcceptanceConfig:
    """The contents of an ``acceptance.toml``: limits for every plan and per-plan tables.

    Empty (the built-in limits for every plan) when there is no file.
    """

    common: Mapping[str, float] = field(default_factory=dict)
    plans: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    def limits(self, plan: str | None = None) -> AcceptanceLimits:
        """Return the limits for ``plan``: its own table over the top level over its defaults.

        The defaults are the built-in limits with the plan registry's entry for ``plan``
        (``PlanEntry.acceptance``) over them.
        """
        own = self.plans.get(plan or "", {})
        return AcceptanceLimits(**{**plan_limits(plan).as_dict(), **self.common, **own})


Limits = AcceptanceLimits | AcceptanceConfig
"""What a caller may give: the limits themselves, or a config that picks them per plan."""


def limits_for(limits: Limits | None, plan: str | None) -> AcceptanceLimits:
    """Resolve what a caller gave into the limits of ``plan`` (None: its built-in ones)."""
    if limits is None:
        return plan_limits(plan)
    if isinstance(limits, AcceptanceConfig):
        return limits.limits(plan)
    return limits


def acceptance_config_path() -> Path:
    """Return where the user keeps acceptance limits: ``acceptance.toml`` in the config dir."""
    return config_dir() / "acceptance.toml"


def read_acceptance_config(path: Path) -> AcceptanceConfig:
    """Read an ``acceptance.toml`` (an absent file: the empty config, built-in limits).

    An unreadable file, an unknown key or a value that is not a positive number is an
    :class:`InputError` naming the file: a quality limit is never silently dropped. Every
    ``[plan.NAME]`` table is checked, not only the one a run will use.
    """
    if not path.is_file():
        return AcceptanceConfig()
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the acceptance limits ({exc})") from None
    document = parse_toml(text, f"{path}: cannot read the acceptance limits")
    plans = document.pop("plan", {})
    if not isinstance(plans, dict) or not all(isinstance(t, dict) for t in plans.values()):
        raise InputError(f"{path}: 'plan' must hold tables [plan.NAME] of limits")
    common = _limit_values(document, path, "")
    own = {name: _limit_values(table, path, f"plan.{name}.") for name, table in plans.items()}
    return AcceptanceConfig(common, own)


def plan_limits(plan: str | None) -> AcceptanceLimits:
    """Return the built-in limits with the plan registry's defaults for ``plan``."""
    entry = None if plan is None else PLANS.get(plan)
    return AcceptanceLimits(**({} if entry is None else dict(entry.acceptance)))


def _limit_values(table: Mapping[str, object], path: Path, prefix: str) -> dict[str, float]:
    known = AcceptanceLimits().as_dict()
    values = {}
    for key, value in table.items():
        if key not in known:
            raise InputError(f"{path}: unknown key '{prefix}{key}' (known: {', '.join(known)})")
        if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
            raise InputError(f"{path}: {prefix}{key} must be a positive number, got {value!r}")
        if not np.isfinite(value):
            raise InputError(f"{path}: {prefix}{key} must be finite, got {value!r}")
        values[key] = float(value)
    return values


@dataclass(frozen=True)
class Check:
    """One limit: the measured value against the limit (``passed`` when within it)."""

    name: str
    value: float
    limit: float
    unit: str
    passed: bool
    key: str = ""
    """The limit's key in :class:`AcceptanceLimits` (``max_bias_sigma_mg``, …)."""

    def line(self) -> str:
        """``name: value unit (limit …) ok/FAILED``."""
        verdict = "ok" if self.passed else "FAILED"
        limit = f"{self.limit:g} {self.unit}".rstrip()  # the limit in the value's unit too
        return f"{self.name}: {self.value:.4g} {self.unit} (limit {limit}) {verdict}"


@dataclass(frozen=True)
class AcceptanceReport:
    """Every check of one node's result, and the parameters left at nominal."""

    checks: tuple[Check, ...]
    held_nominal: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        """Whether every check passed."""
        return all(c.passed for c in self.checks)


def _relative_sigmas(
    solution: Solution, accel_lsb: float, g: float
) -> tuple[list[float], list[float]]:
    """σ of each estimated accel bias (mg) and diagonal scale factor (ppm of its value)."""
    joint = solution.joint
    if joint is None:  # the scalar |f| = g fit: every bias and diagonal K is a parameter
        assert solution.scalar is not None
        fit = solution.scalar
        bias = [float(s) * abs(accel_lsb) / g * 1000.0 for s in fit.bias_sigma]
        k_sigma = np.diag(fit.K_sigma)
        scale = [float(s / abs(k)) * 1e6 for s, k in zip(k_sigma, np.diag(fit.K), strict=True)]
        return bias, scale
    sigma = np.sqrt(np.clip(np.diag(joint.covariance), 0.0, None))
    diag = [f"accel.K[{i}][{i}]" for i in range(3)]
    bias_mg, scale_ppm = [], []
    for k, name in enumerate(joint.names):
        if name in joint.undetermined:
            continue
        if name.startswith("accel.bias["):
            bias_mg.append(float(sigma[k]) * abs(accel_lsb) / g * 1000.0)
        if name in diag and joint.values[k] != 0.0:
            scale_ppm.append(float(sigma[k]) / abs(float(joint.values[k])) * 1e6)
    return bias_mg, scale_ppm


def check_acceptance(
    solution: Solution, limits: AcceptanceLimits, accel_lsb: float, g: float
) -> AcceptanceReport:
    """Check one node's solution against ``limits``.

    A calibration that determined no accelerometer parameter (every one held at nominal, or
    no accelerometer fit at all: a gyro-only file) fails; a fit whose χ² p-value is below
    ``min_fit_p`` fails with the reason ("model does not fit: χ²/dof N"). The scalar
    ``|f| = g`` fit is checked as the joint one.
    """
    joint = solution.joint
    if joint is None and solution.scalar is None:  # no accelerometer fit (a gyro-only file)
        return AcceptanceReport((Check("accelerometer parameters determined", 0, 1, "", False),))
    bias_mg, scale_ppm = _relative_sigmas(solution, accel_lsb, g)
    checks = []
    if not bias_mg and not scale_ppm:
        checks.append(Check("accelerometer parameters determined", 0, 1, "", False))
    if bias_mg:
        worst = max(bias_mg)
        checks.append(
            Check(
                "worst bias σ",
                worst,
                limits.max_bias_sigma_mg,
                "mg",
                worst <= limits.max_bias_sigma_mg,
                "max_bias_sigma_mg",
            )
        )
    if scale_ppm:
        worst = max(scale_ppm)
        checks.append(
            Check(
                "worst scale σ",
                worst,
                limits.max_scale_sigma_ppm,
                "ppm",
                worst <= limits.max_scale_sigma_ppm,
                "max_scale_sigma_ppm",
            )
        )
    if joint is not None:
        rms, chi2, dof = float(joint.rms_accel_ms2), float(joint.chi2), joint.dof
    else:
        assert solution.scalar is not None
        fit = solution.scalar
        rms, chi2, dof = fit.rms_mps2, fit.reduced_chi2 * fit.dof, fit.dof
    passed = rms <= limits.max_rms_ms2
    checks.append(Check("fit rms", rms, limits.max_rms_ms2, "m/s²", passed, "max_rms_ms2"))
    if dof > 0:
        p = chi2_sf(dof, chi2)
        passed = p >= limits.min_fit_p
        name = "fit p-value" if passed else f"model does not fit: χ²/dof {chi2 / dof:.4g}, p"
        checks.append(Check(name, p, limits.min_fit_p, "", passed, "min_fit_p"))
    held = () if joint is None else tuple(sorted(joint.undetermined))
    return AcceptanceReport(tuple(checks), held)


def acceptance_block(report: AcceptanceReport, limits: AcceptanceLimits) -> Acceptance:
    """Return the calibration JSON's ``acceptance``: verdict, every limit, the values."""
    return Acceptance(
        passed=report.passed,
        limits=limits.as_dict(),
        values={c.key: float(c.value) for c in report.checks if c.key},
    )


@dataclass(frozen=True)
class Verdict:
    """One solution judged: the JSON block and the lines a person reads."""

    report: AcceptanceReport
    block: Acceptance
    text: str


def judge(
    solution: Solution, site: SiteConditions, limits: AcceptanceLimits | None = None
) -> Verdict:
    """Check ``solution`` against ``limits`` (default: the built-in ones) and say so."""
    limits = AcceptanceLimits() if limits is None else limits
    report = check_acceptance(solution, limits, site.accel_lsb, site.g)
    lines = [f"acceptance: {'PASSED' if report.passed else 'FAILED'}"]
    lines += [f"  {c.line()}" for c in report.checks]
    if report.held_nominal:
        lines.append(f"  not checked (held at nominal): {', '.join(report.held_nominal)}")
    return Verdict(report, acceptance_block(report, limits), "\n".join(lines) + "\n")
