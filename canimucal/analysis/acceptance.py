"""Acceptance limits checked before a write is offered: σ of the estimates and the residual.

- worst accelerometer bias σ (mg: counts × |LSB| / g × 1000);
- worst relative σ of a scale factor (ppm of |K_ii|);
- the fit's rms residual (m/s², after correction);
- the χ² lack-of-fit p-value (too small: the model does not explain the data).

Parameters the plan cannot determine (held at nominal) are not checked; the report names them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2 as chi2_distribution

from canimucal.analysis.calibrate import Solution
from canimucal.io.calibration import Acceptance


@dataclass(frozen=True)
class AcceptanceLimits:
    """Limits a calibration must meet before it is offered for writing."""

    max_bias_sigma_mg: float = 5.0
    max_scale_sigma_ppm: float = 3000.0
    max_rms_ms2: float = 0.05
    min_fit_p: float = 1e-4


@dataclass(frozen=True)
class Check:
    """One limit: the measured value against the limit (``passed`` when within it).

    ``key`` is the limit's field name in :class:`AcceptanceLimits` (and in the JSON block).
    """

    key: str
    name: str
    value: float
    limit: float
    unit: str
    passed: bool

    def line(self) -> str:
        """``name: value unit (limit …) ok/FAILED``."""
        verdict = "ok" if self.passed else "FAILED"
        return f"{self.name}: {self.value:.4g} {self.unit} (limit {self.limit:g}) {verdict}"


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
    assert joint is not None
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
    """Check one node's solution against ``limits``."""
    joint = solution.joint
    if joint is None:
        return AcceptanceReport(())
    bias_mg, scale_ppm = _relative_sigmas(solution, accel_lsb, g)
    checks = []
    if bias_mg:
        worst = max(bias_mg)
        checks.append(
            Check(
                "max_bias_sigma_mg",
                "worst bias σ",
                worst,
                limits.max_bias_sigma_mg,
                "mg",
                worst <= limits.max_bias_sigma_mg,
            )
        )
    if scale_ppm:
        worst = max(scale_ppm)
        checks.append(
            Check(
                "max_scale_sigma_ppm",
                "worst scale σ",
                worst,
                limits.max_scale_sigma_ppm,
                "ppm",
                worst <= limits.max_scale_sigma_ppm,
            )
        )
    rms = float(joint.rms_accel_ms2)
    checks.append(
        Check("max_rms_ms2", "fit rms", rms, limits.max_rms_ms2, "m/s²", rms <= limits.max_rms_ms2)
    )
    if joint.dof > 0:
        p = float(chi2_distribution.sf(joint.chi2, joint.dof))
        checks.append(
            Check("min_fit_p", "fit p-value", p, limits.min_fit_p, "", p >= limits.min_fit_p)
        )
    return AcceptanceReport(tuple(checks), tuple(sorted(joint.undetermined)))


def acceptance_block(report: AcceptanceReport, limits: AcceptanceLimits) -> Acceptance:
    """Build the calibration JSON's ``acceptance`` block: limits, values checked, verdict."""
    return Acceptance(
        passed=report.passed,
        limits={k: float(v) for k, v in dataclasses.asdict(limits).items()},
        values={c.key: float(c.value) for c in report.checks},
    )
