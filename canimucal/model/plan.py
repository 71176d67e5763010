"""Position plans: Fisher information, Cramér–Rao bounds and identifiability (docs/design.md §3).

The bounds are evaluated at the nominal model: ``K = k·I`` (k from the nominal LSB), zero
tilt, white noise of density N counts/√Hz per axis, so a position averaged T seconds has a
mean of variance N²/T counts²; optionally plus each position's angle tolerance. The Jacobian
is the joint estimator's own (:func:`canimucal.model.layout.predict`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import ModelError
from canimucal.model.layout import (
    GyroSpec,
    JointSpec,
    ModelContext,
    ModelParams,
    ParameterLayout,
    angle_error_moments,
    predict,
)
from canimucal.model.positions import Plan
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, STANDARD_GRAVITY
from canimucal.model.small_linalg import pivoted_qr
from canimucal.model.vocabulary.plans import DEFAULT_PLAN, builtin_plan
from canimucal.model.vocabulary.units import quantity_of

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

NOT_IDENTIFIABLE_RATIO = 1e-10
"""An eigenvalue of the normalised Fisher information below this × the largest: rank loss."""
POORLY_SEPARABLE_RATIO = 1e-4
"""An eigenvalue below this × the largest: poorly separable (docs/design.md §3)."""
CORRELATION_LIMIT = 0.999
"""A correlation above this in magnitude: poorly separable (docs/design.md §3)."""
CARRIER_WEIGHT = 0.9
"""Name the parameters that carry this share of an eigenvector's squared weight."""
_NULL_WEIGHT = 1e-6  # a parameter with more weight than this in the null space is undetermined


@dataclass(frozen=True)
class Finding:
    """One identifiability problem: ``not_identifiable`` or ``poorly_separable``."""

    kind: Literal["not_identifiable", "poorly_separable"]
    parameters: tuple[str, ...]
    message: str
    eigenvalue_ratio: float | None = None
    correlation: float | None = None


@dataclass(frozen=True)
class Separability:
    """Eigen-analysis of the Fisher information, normalised by each parameter's effect at 1 g.

    ``covariance`` is the (pseudo-)inverse of the information in the parameters' own units,
    NaN for undetermined parameters; ``eigenvalue_ratios`` ascending, over the largest.
    """

    names: tuple[str, ...]
    findings: tuple[Finding, ...]
    undetermined: Mapping[str, str]
    eigenvalue_ratios: Array
    eigenvectors: Array
    covariance: Array
    correlation: Array

    @property
    def identifiable(self) -> bool:
        """True when the information has full rank."""
        return not self.undetermined

    @property
    def separable(self) -> bool:
        """True when every parameter is identifiable and none is poorly separable."""
        return not self.findings


def analyse_information(fisher: Array, names: Sequence[str], scales: Array) -> Separability:
    """Analyse identifiability and separability of the parameters from their information.

    Each parameter is scaled by ``scales`` (its effect at 1 g in counts: bias 1, K and G
    entries g, tilt angles k·g) before the eigen-analysis, so that units do not dominate.
    Not identifiable: eigenvalue < 1e-10 × the largest; poorly separable: < 1e-4 × the
    largest, or a correlation above 0.999 in magnitude (docs/design.md §3).
    """
    names = tuple(names)
    d = np.asarray(scales, dtype=float)
    lam, vec = np.linalg.eigh(fisher / np.outer(d, d))
    lmax = float(lam[-1]) if lam.size and lam[-1] > 0 else 1.0
    ratio = lam / lmax
    null = ratio < NOT_IDENTIFIABLE_RATIO
    vec[:, null] = canonical_basis(vec[:, null])
    cov_n = (vec[:, ~null] / lam[~null]) @ vec[:, ~null].T
    null_weight = np.sum(vec[:, null] ** 2, axis=1)
    undetermined_mask = null_weight > _NULL_WEIGHT
    cov = cov_n / np.outer(d, d)
    cov[undetermined_mask, :] = np.nan
    cov[:, undetermined_mask] = np.nan
    sd = np.sqrt(np.abs(np.diag(cov)))
    corr = cov / np.outer(sd, sd)
    findings = _eigen_findings(names, ratio, vec)
    findings += _correlation_findings(names, corr)
    undetermined = {
        names[j]: _undetermined_reason(names, vec, null, int(j))
        for j in np.flatnonzero(undetermined_mask)
    }
    return Separability(names, tuple(findings), undetermined, ratio, vec, cov, corr)


def canonical_basis(basis: Array) -> Array:
    """Return a sparse basis of the span of ``basis``'s columns.

    An eigenspace with several (near-)zero eigenvalues has no preferred eigenvectors: LAPACK
    may return any rotation of them, and naming the parameters each one carries would then
    depend on the build. The reduced row-echelon form from a column-pivoted QR is fixed by the
    subspace alone: each vector has one pivot parameter at 1 and the other pivots at 0, so a
    pure trade-off such as bias z against beta0 comes out as its own vector. Columns are
    normalised to unit length.
    """
    m = basis.shape[1]
    if m < 2:
        return basis
    r, perm = pivoted_qr(basis.T)
    echelon = np.linalg.solve(r[:, :m], r)
    out = np.zeros_like(basis.T)
    out[:, perm] = echelon
    return np.asarray((out / np.linalg.norm(out, axis=1, keepdims=True)).T)


def _carriers(names: Sequence[str], v: Array) -> tuple[str, ...]:
    order = np.argsort(-(v**2))
    share = np.cumsum(v[order] ** 2) / np.sum(v**2)
    count = int(np.searchsorted(share, CARRIER_WEIGHT) + 1)
    return tuple(names[k] for k in order[:count])


def _eigen_findings(names: Sequence[str], ratio: Array, vec: Array) -> list[Finding]:
    out = []
    for k in np.flatnonzero(ratio < POORLY_SEPARABLE_RATIO):
        who = _carriers(names, vec[:, k])
        if ratio[k] < NOT_IDENTIFIABLE_RATIO:
            kind: Literal["not_identifiable", "poorly_separable"] = "not_identifiable"
            text = f"not identifiable: {', '.join(who)} (eigenvalue ratio {ratio[k]:.1e})"
        else:
            kind = "poorly_separable"
            text = f"poorly separable: {', '.join(who)} (eigenvalue ratio {ratio[k]:.1e})"
        out.append(Finding(kind, who, text, eigenvalue_ratio=float(ratio[k])))
    return out


def _correlation_findings(names: Sequence[str], corr: Array) -> list[Finding]:
    out = []
    rows, cols = np.nonzero(np.triu(np.abs(np.nan_to_num(corr)) > CORRELATION_LIMIT, k=1))
    for i, j in zip(rows.tolist(), cols.tolist(), strict=True):
        r = float(corr[i, j])
        text = f"poorly separable: {names[i]} and {names[j]} (correlation {r:+.4f})"
        out.append(Finding("poorly_separable", (names[i], names[j]), text, correlation=r))
    return out


def _undetermined_reason(names: Sequence[str], vec: Array, null: NDArray[np.bool_], j: int) -> str:
    k = int(np.flatnonzero(null)[np.argmax(vec[j, null] ** 2)])
    who = ", ".join(_carriers(names, vec[:, k]))
    return f"not identifiable from these positions (null direction carried by {who})"


def plan_prior(
    plan: Plan,
    spec: JointSpec,
    accel_lsb: float,
    factory_k: Array | None = None,
    k_sigma: float | None = None,
) -> dict[str, tuple[float, float]]:
    """Return the prior ``{name: (mean, σ)}`` a plan relies on, for the K entries of ``spec``.

    Mean: ``factory_k`` (counts per m/s², entered or read from the device), else the nominal
    ``I/accel_lsb``; σ: ``k_sigma`` (else the plan's ``prior_k_sigma``) × the nominal scale.
    Empty when the plan needs no prior and none was asked for.
    """
    rel = plan.prior_k_sigma if k_sigma is None else k_sigma
    if rel is None:
        return {}
    if not (np.isfinite(rel) and rel > 0):
        raise ModelError(f"the prior σ of K must be a positive fraction, got {rel}")
    k_nominal = 1.0 / abs(accel_lsb)
    mean = np.eye(3) / accel_lsb if factory_k is None else np.asarray(factory_k, dtype=float)
    if mean.shape != (3, 3) or not np.all(np.isfinite(mean)):
        raise ModelError("factory K must be a finite 3×3 matrix")
    layout = ParameterLayout.of(spec)
    return {f"accel.K[{i}][{j}]": (float(mean[i, j]), rel * k_nominal) for i, j in layout.k_entries}


@dataclass(frozen=True)
class KPrior:
    """Where a plan's prior on K comes from: its mean and its relative σ, each with a source.

    ``mean`` None is the nominal ``I/accel_lsb``; ``rel_sigma`` None is the plan's own
    ``prior_k_sigma`` (its documented default). The sources are stated in the calibration's
    ``priors`` and warnings, so the certificate says which prior was held and why.
    """

    mean: Array | None = None
    mean_source: str = "nominal K = I/LSB"
    rel_sigma: float | None = None
    sigma_source: str | None = None

    def needed(self, plan: Plan) -> bool:
        """Tell whether ``plan`` (or the σ asked for) holds K at a prior at all."""
        return self.rel_sigma is not None or plan.prior_k_sigma is not None

    def prior(
        self, plan: Plan, spec: JointSpec, accel_lsb: float
    ) -> dict[str, tuple[float, float]]:
        """Return :func:`plan_prior` of this mean and σ."""
        return plan_prior(plan, spec, accel_lsb, factory_k=self.mean, k_sigma=self.rel_sigma)

    def resolved(self, plan: Plan, accel_lsb: float) -> KPrior:
        """Return this prior with its defaults filled in: nominal mean, the plan's σ, why."""
        rel = self.rel_sigma if self.rel_sigma is not None else plan.prior_k_sigma
        whence = self.sigma_source
        if whence is None and rel is not None and self.rel_sigma is not None:
            whence = "given"
        elif whence is None and rel is not None:
            whence = (
                f"the {plan.name} plan's default, a datasheet's scale-factor tolerance "
                "(the device holds no σ)"
            )
        mean = np.eye(3) / accel_lsb if self.mean is None else self.mean
        return KPrior(mean, self.mean_source, rel, whence)

    def describe(self, plan: Plan) -> str:
        """One line: the mean's source and the σ's (relative to the nominal scale)."""
        full = self.resolved(plan, 1.0)
        if full.rel_sigma is None:
            return self.mean_source
        rel = f"{100 * full.rel_sigma:.3g} %"
        return f"{self.mean_source}; σ {rel} of the nominal scale: {full.sigma_source}"


def nominal_params(k_counts_per_ms2: float, gyro_lsb: float = DEFAULT_GYRO_LSB) -> ModelParams:
    """Return the point where bounds are evaluated: zero biases and tilt, K = k·I, nominal S."""
    zero = np.zeros(3)
    return ModelParams(
        zero, np.eye(3) * k_counts_per_ms2, 0.0, 0.0, zero, np.eye(3) / gyro_lsb, np.zeros((3, 3))
    )


def fisher_information(
    plan: Plan,
    spec: JointSpec,
    *,
    k_nominal_counts_per_ms2: float,
    g: float,
    noise_density: float = 1.0,
    gyro_noise_density: float | None = None,
    latitude: float | None = None,
    heading: float = 0.0,
    gyro_lsb: float = DEFAULT_GYRO_LSB,
    include_tolerance: bool = False,
    at: ModelParams | None = None,
    prior_sigma: Mapping[str, float] | None = None,
    trials: Sequence[int | None] | None = None,
) -> Array:
    """Fisher information of ``plan`` for the parameters of ``spec`` (in their own units).

    White noise ``noise_density`` counts/√Hz per accelerometer axis (``gyro_noise_density``,
    default the same, per gyro axis): a position of T seconds has a mean of covariance
    ``N²/T · I``. With ``include_tolerance`` each position's angle tolerance is added (errors
    in variables). Latitude and heading in radians. ``at`` moves the point of evaluation away
    from docs/design.md §3's nominal one (K = k·I, zero tilt, nominal S, zero biases and G).
    ``prior_sigma`` adds a Gaussian prior's information ``1/σ²`` to the parameters it names
    (the pseudo-observations of :func:`canimucal.model.joint.solve_joint`). ``trials`` (one
    per position, None: no trial) gives each trial its own biases as the joint fit does:
    the trials' ``T − 1`` bias offsets (:func:`offset_contrast`) are marginalised, so the
    biases are the trials' mean and K, the tilt and the gyro terms what the positions tell
    beside every trial's own biases.
    """
    if not plan.positions:
        raise ModelError("the plan has no positions")
    if spec.gyro == "nav" and latitude is None:
        raise ModelError("gyro model 'nav' needs a latitude (its scale comes from Earth rate)")
    layout = ParameterLayout.of(spec)
    theta = layout.pack(at or nominal_params(k_nominal_counts_per_ms2, gyro_lsb))
    ctx = ModelContext.build(g, latitude, heading, gyro_lsb)
    angles = np.array([p.angles for p in plan.positions])
    pred = predict(layout, theta, angles, ctx)
    seconds = np.array([p.seconds for p in plan.positions], dtype=float)
    if np.any(~np.isfinite(seconds) | (seconds <= 0)):
        raise ModelError("every position needs a positive averaging time (seconds)")
    density = np.full(spec.channels, float(noise_density))
    density[3:] = noise_density if gyro_noise_density is None else gyro_noise_density
    base = np.einsum("n,ij->nij", 1.0 / seconds, np.diag(density**2))
    if include_tolerance:
        tol = np.array([p.tolerances for p in plan.positions], dtype=float)
        base = base + angle_error_moments(layout, theta, angles, ctx, tol).covariance
    if trials is not None and len(trials) != len(angles):
        raise ModelError(f"{len(trials)} trials given for {len(angles)} positions")
    design = pred.d_theta
    _ids, contrast = offset_contrast(list(trials) if trials is not None else [None] * len(angles))
    if contrast.shape[1]:
        m = spec.channels
        offsets = np.einsum("nj,cd->ncjd", contrast, np.eye(m)).reshape(len(angles), m, -1)
        design = np.concatenate([design, offsets], axis=2)
    weighted = np.linalg.solve(base, design)
    fisher = np.einsum("nip,niq->pq", design, weighted)
    p = layout.size
    if fisher.shape[0] > p:  # the trials' offsets marginalised (Schur complement)
        own, cross = fisher[:p, :p], fisher[:p, p:]
        fisher = own - cross @ np.linalg.pinv(fisher[p:, p:], hermitian=True) @ cross.T
    for name, sigma in (prior_sigma or {}).items():
        if not (np.isfinite(sigma) and sigma > 0):
            raise ModelError(f"prior σ of {name} must be finite and > 0, got {sigma}")
        j = layout.index(name)
        fisher[j, j] += 1.0 / sigma**2
    return np.asarray(fisher)


def offset_contrast(keys: Sequence[int | None]) -> tuple[tuple[int, ...], Array]:
    """Return the trials of ``keys`` (one per position) and the contrast of their offsets.

    Trials ascending (None and negative are trial -1); the ``(n, T − 1)`` contrast maps the
    offsets ``δ_t`` of the first ``T − 1`` trials to the positions, the last trial's being
    ``−Σ δ_t`` (offsets summing to zero: the biases are the trials' mean). ``((), (n, 0))``
    with fewer than two trials.
    """
    keyed = [-1 if k is None or int(k) < 0 else int(k) for k in keys]
    ids = tuple(sorted(set(keyed)))
    if len(ids) < 2:
        return (), np.zeros((len(keyed), 0))
    contrast = np.zeros((len(keyed), len(ids) - 1))
    for k, key in enumerate(keyed):
        t = ids.index(key)
        contrast[k] = -1.0 if t == len(ids) - 1 else np.eye(len(ids) - 1)[t]
    return ids, contrast


@dataclass(frozen=True)
class Bound:
    """Cramér–Rao σ of one parameter in its own units and as its effect at 1 g in counts.

    ``sigma`` and ``effect_counts`` are None when the plan cannot determine the parameter
    (``reason`` says why). ``prior_sigma`` is the σ of the prior the bound assumed for this
    parameter (None: the data alone).
    """

    name: str
    unit: str
    sigma: float | None
    effect_counts: float | None
    reason: str | None = None
    prior_sigma: float | None = None


@dataclass(frozen=True)
class BoundTable:
    """What ``canimucal plan`` prints: per-parameter bounds, worst case, identifiability."""

    plan: str
    spec: JointSpec
    rows: tuple[Bound, ...]
    separability: Separability

    @property
    def worst_case_counts(self) -> float:
        """Largest effect at 1 g over the parameters (inf when one is not identifiable)."""
        effects = [r.effect_counts for r in self.rows]
        return float("inf") if None in effects else max(e for e in effects if e is not None)

    @property
    def worst_parameter(self) -> str:
        """The parameter whose effect is the worst case."""
        effects = [np.inf if r.effect_counts is None else r.effect_counts for r in self.rows]
        return self.rows[int(np.argmax(effects))].name

    def bound(self, name: str) -> Bound:
        """Return the row of parameter ``name``."""
        for row in self.rows:
            if row.name == name:
                return row
        raise ModelError(f"no parameter {name!r} in this bound table")


def cramer_rao(
    plan: Plan,
    spec: JointSpec | None = None,
    *,
    k_nominal_counts_per_ms2: float = 1.0 / DEFAULT_ACCEL_LSB,
    g: float = STANDARD_GRAVITY,
    noise_density: float = 1.0,
    latitude: float | None = None,
    include_tolerance: bool = False,
    at: ModelParams | None = None,
    prior_sigma: Mapping[str, float] | None = None,
    trials: Sequence[int | None] | None = None,
    **kwargs: float,
) -> BoundTable:
    """Cramér–Rao bounds of ``plan`` for ``spec`` (default: bias + diagonal K + rigid tilt).

    Each parameter's σ and its effect at 1 g in counts (σ_b, g·σ_Kij, |k|·g·σ_angle); the
    identifiability analysis of :func:`analyse_information`. ``prior_sigma``: the σ of a
    Gaussian prior per parameter name (default: the plan's own prior, :func:`plan_prior`,
    at ``k_nominal``). ``at``, ``trials`` (each position's, :func:`fisher_information`) and
    the extra keywords go to :func:`fisher_information` (``gyro_noise_density``, ``heading``,
    ``gyro_lsb``).
    """
    spec = spec or JointSpec()
    layout = ParameterLayout.of(spec)
    if prior_sigma is None:
        prior = plan_prior(plan, spec, 1.0 / k_nominal_counts_per_ms2)
        prior_sigma = {name: sigma for name, (_mean, sigma) in prior.items()}
    fisher = fisher_information(
        plan,
        spec,
        k_nominal_counts_per_ms2=k_nominal_counts_per_ms2,
        g=g,
        noise_density=noise_density,
        latitude=latitude,
        include_tolerance=include_tolerance,
        at=at,
        prior_sigma=prior_sigma,
        trials=trials,
        **kwargs,
    )
    scales = layout.effect_scales(g, k_nominal_counts_per_ms2)
    sep = analyse_information(fisher, layout.names, scales)
    rows = []
    for j, name in enumerate(layout.names):
        unit = quantity_of(name).unit
        if name in sep.undetermined:
            rows.append(Bound(name, unit, None, None, sep.undetermined[name]))
            continue
        sigma = float(np.sqrt(sep.covariance[j, j]))
        effect = sigma * float(scales[j])
        rows.append(Bound(name, unit, sigma, effect, None, prior_sigma.get(name)))
    return BoundTable(plan.name, spec, tuple(rows), sep)


def plan_bounds(
    plan: Plan | str = DEFAULT_PLAN,
    *,
    model: Literal["diag", "full"] = "diag",
    tilt: bool = True,
    gyro: GyroSpec = "none",
    latitude_deg: float | None = None,
    with_tolerance: bool = False,
) -> BoundTable:
    """Cramér–Rao bounds of a plan (or a built-in plan's name) as ``canimucal plan`` gives them.

    White noise of 1 count/√Hz, K = I/LSB, standard gravity; the same defaults as the command.
    """
    chosen = builtin_plan(plan) if isinstance(plan, str) else plan
    spec = JointSpec(accel_k=model, tilt="rigid" if tilt else "none", gyro=gyro, gyro_s=model)
    return cramer_rao(
        chosen,
        spec,
        k_nominal_counts_per_ms2=1.0 / DEFAULT_ACCEL_LSB,
        g=STANDARD_GRAVITY,
        latitude=None if latitude_deg is None else float(np.deg2rad(latitude_deg)),
        include_tolerance=with_tolerance,
    )
