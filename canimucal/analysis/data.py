"""Inputs and results of the discrepancy analysis (pure data, no statistics)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.noise_model import ScatterEstimate
from canimucal.analysis.settling import Settling
from canimucal.model.joint import trial_contrast
from canimucal.model.positions import PositionAverage
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB

Array = NDArray[np.float64]
Samples = NDArray[np.floating[Any]]
"""A window's samples: float32 or float64 (:class:`Window`)."""

FAMILY_ALPHA = 0.01
"""Family-wise error rate of the candidate tests (Holm)."""

AXIS_SIGN_SIGMAS = 5.0
"""A scale factor whose sign differs from the nominal LSB's by more than this many σ."""


@dataclass(frozen=True)
class Window:
    """The samples of one static position: times (s), counts ``(n, 3)``, temperature (°C).

    The sample arrays keep the recording's column type (float32 while its values fit it
    exactly, docs/performance.md) and are views of its columns when the position is one run
    of rows, so the windows of a long session cost no memory of their own. Readers convert
    one window at a time to float64 *before* reducing it (numpy's buffered float32 → float64
    reductions sum in another order: the figures would move in the 12th digit).
    """

    t_s: Array
    accel: Samples
    gyro: Samples | None = None
    temp_c: Samples | None = None


@dataclass(frozen=True)
class SessionData:
    """One measured session, grouped into positions, with its conditions.

    ``latitude``/``heading`` radians (None: no Earth-rate term); ``known_positions`` says
    whether the averages carry real angles (else only the scalar ``|f| = g`` fit applies).
    ``scatter_source`` says where the pose-setting scatter comes from: ``"estimated"`` (from
    the data; the poses' tolerances are then ignored), ``"header"`` or ``"flag"`` (the poses'
    tolerances hold it), ``"plan"`` (the poses' tolerances, as a simulation drew them).
    ``settling`` holds each sensor's settling fit (:mod:`.settling`):
    the windows and averages are already trimmed by it.
    ``tilt_limit_deg`` is the largest |alpha| and |beta| of the plan that produced the
    recording (None: no built-in plan named; a separating position then uses the default).
    ``gyro_lsb_known`` is false when ``gyro_lsb`` is a stand-in (a file without one): the
    Earth rate's size in counts is then unknown.
    """

    averages: tuple[PositionAverage, ...]
    windows: tuple[Window, ...]
    g: float
    latitude: float | None = None
    heading: float = 0.0
    accel_lsb: float = DEFAULT_ACCEL_LSB
    gyro_lsb: float = DEFAULT_GYRO_LSB
    known_positions: bool = True
    scatter_source: str = "plan"
    settling: Mapping[str, Settling] = field(default_factory=dict)
    tilt_limit_deg: float | None = None
    gyro_lsb_known: bool = True

    @property
    def has_gyro(self) -> bool:
        """Every position has gyro data."""
        return all(a.mean_gyro is not None and a.cov_gyro is not None for a in self.averages)

    @property
    def trials(self) -> tuple[int, ...]:
        """The trials the positions belong to, ascending (empty: one trial, or none)."""
        return trial_contrast(self.averages)[0]


@dataclass(frozen=True)
class Finding:
    """One named cause (analysis JSON ``findings``)."""

    effect: str
    sensor: str
    size: float
    units: str
    p_value: float
    evidence: str
    sigma: float | None = None
    """σ of ``size`` where the loop estimates one (a bias random walk's q)."""


@dataclass(frozen=True)
class TestRecord:
    """One candidate test: raw and Holm-adjusted p-value, statistic, chosen or not.

    ``entries`` > 1: a per-entry test, ``statistic`` (on ``df`` dof) that of the largest of
    that many single-entry tests and ``p_value`` already Bonferroni-corrected for them.
    """

    effect: str
    sensor: str
    kind: str
    statistic: float
    df: int
    p_value: float
    p_adjusted: float
    chosen: bool
    entries: int = 1


@dataclass(frozen=True)
class SensorScore:
    """rms and cv_rms of the base and extended model of one sensor (SI units)."""

    base_terms: tuple[str, ...]
    extended_terms: tuple[str, ...]
    base_rms: float
    base_cv_rms: float
    extended_rms: float
    extended_cv_rms: float
    cv_rms_ratio_ci95: tuple[float, float] = (1.0, 1.0)
    claimed: bool = False

    @property
    def rms_ratio(self) -> float:
        """Base over extended rms (1.0 when nothing was added)."""
        return _ratio(self.base_rms, self.extended_rms, self.extended_terms == self.base_terms)

    @property
    def cv_rms_ratio(self) -> float:
        """Base over extended cv_rms (1.0 when nothing was added)."""
        same = self.extended_terms == self.base_terms
        return _ratio(self.base_cv_rms, self.extended_cv_rms, same)


def _ratio(a: float, b: float, same: bool) -> float:
    if same or not (np.isfinite(a) and np.isfinite(b)) or b <= 0:
        return 1.0
    return float(a / b)


@dataclass(frozen=True)
class ExtendedParams:
    """The extended model's parameters (counts, counts per m/s², radians), for a truth file."""

    accel_bias: Array
    K: Array
    alpha0: float = 0.0
    beta0: float = 0.0
    quadratic: Array = field(default_factory=lambda: np.zeros(3))
    accel_temp_coeff: Array = field(default_factory=lambda: np.zeros(3))
    accel_random_walk: Array = field(default_factory=lambda: np.zeros(3))
    gyro_bias: Array | None = None
    G: Array = field(default_factory=lambda: np.zeros((3, 3)))
    gyro_temp_coeff: Array = field(default_factory=lambda: np.zeros(3))
    gyro_random_walk: Array = field(default_factory=lambda: np.zeros(3))
    effects: Mapping[str, Array] = field(default_factory=dict)
    """Chosen effects the simulator applies through their columns, by ``sensor.effect``
    (the truth JSON's ``effects``; :mod:`canimucal.model.vocabulary.effects`)."""
    trials: tuple[int, ...] = ()
    """The trials the base model gave their own biases (empty: one trial, or none)."""
    trial_accel_bias: Array | None = None
    """``(T, 3)`` each trial's accelerometer bias (counts; ``accel_bias`` is their mean)."""
    trial_gyro_bias: Array | None = None
    """``(T, 3)`` each trial's gyro bias (counts; ``gyro_bias`` is their mean)."""


@dataclass(frozen=True)
class Ambiguity:
    """Two candidates the data cannot tell apart (analysis JSON ``ambiguous``).

    ``correlation`` is that of their estimates in the model holding both: the largest
    canonical correlation of the two coefficient blocks (0–1; for one entry each, the
    magnitude of their correlation; :mod:`.separation` eq. 2); ``separating`` the position
    that would separate them best (known positions only).
    """

    sensor: str
    candidates: tuple[str, str]
    correlation: float
    separating: SeparatingPosition | None = None


@dataclass(frozen=True)
class SeparatingPosition:
    """The one added pose that would best tell an ambiguous pair apart (degrees).

    The pose minimises ``correlation_after``, the pair's correlation as
    :attr:`Ambiguity.correlation` (the same quantity) with that pose added. ``noncentrality``
    is the smaller of the two head-to-head tests' non-centralities with the pose added (each at
    its candidate's size fitted without the rival), ``before`` the same without it.
    """

    alpha_deg: float
    beta_deg: float
    psi_deg: float
    correlation_after: float
    noncentrality: float
    before: float
    tilt_limit_deg: float


@dataclass(frozen=True)
class NoiseSummary:
    """The noise model the tests used: pose-setting scatter, and the chosen model's fit.

    ``chi2``/``dof`` are the extended model's whitened residuals under that noise model
    (χ²/dof near 1 when the model holds).
    """

    pose_scatter: ScatterEstimate
    chi2: float
    dof: int


@dataclass(frozen=True)
class DiscrepancyResult:
    """What the base model gets wrong, the named causes and the gain of the extension.

    ``residuals`` the base fit's per-position residuals (counts; the scalar fit's accel column
    is ``|f| − g`` in m/s²); ``lack_of_fit`` χ², dof and p of the base fit against the noise
    predicted from the within-position scatter (and the angle tolerances).
    """

    method: str
    residuals: Array
    residual_labels: tuple[str, ...]
    lack_of_fit: tuple[float, int, float]
    findings: tuple[Finding, ...]
    untestable: Mapping[str, str]
    tests: tuple[TestRecord, ...]
    scores: Mapping[str, SensorScore]
    params: ExtendedParams
    base_values: Mapping[str, float]
    base_sigmas: Mapping[str, float]
    drift_found: bool
    noise: NoiseSummary | None = None
    warnings: tuple[str, ...] = ()
    ambiguous: tuple[Ambiguity, ...] = ()
    earth_rate_horizontal: ScatterEstimate | None = None
    trials: int = 0
    """How many trials the base model gave their own biases (0: one trial, or none)."""
    """Scalar fits of a gyro of unknown scale: the horizontal Earth rate (counts) estimated as
    a variance component (REML, 95 % interval); None where the model sizes it or leaves it."""
