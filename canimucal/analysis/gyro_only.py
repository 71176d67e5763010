"""Gyro-only recordings: what a file with empty accelerometer columns can still answer.

A gyro logged without its accelerometer (a rate-table log, a unit whose accelerometer PDO was
not captured) has no specific force to calibrate and no pose seen from gravity; its labelled
positions still hold the gyro's bias, and with known angles the Earth rate seen in each pose.
At position i with angles known, the mean of the gyro is modelled (docs/design.md §2) as

    V_i = B + S C_i w_L + n_i,     n_i ~ N(0, Σ_i)                                     (1)

with ``S`` the nominal scale (``I/gyro_lsb``) and ``Σ_i`` the covariance of the mean from the
scatter inside the position. ``solve`` follows the joint fit (:mod:`canimucal.model.joint`):
with a latitude ``w_L`` is the site's (at the header's heading), else a nuisance of prior
``N(0, Ω²/3 I)`` marginalised into the covariance of every mean, the positions' shared
``S C_i (Ω²/3) C_jᵀ Sᵀ``; ``--gyro nav`` adds the diagonal of S from the Earth rate (needs
the latitude). Without angles only the bias is fitted, the Earth rate (``Ω²/3`` per axis,
shared) in the covariance. The angle-setting errors reach the gyro through the Earth rate
alone (``|w_L| δ``, below 1e-5 counts at 0.1°): they are left out.

``analyze`` tests what the gyro shows by itself, as the loop does (docs/design.md §6): the
base model is (1) with the Earth rate's horizontal part always fitted (no heading is
trusted) and its vertical part the latitude's or fitted; combinations the poses cannot tell
from the bias are left to it. The candidates are the registry's gyro effects with
known-pose columns (``gyro_g_sensitivity`` at the poses' specific force ``C_i f_L``,
``temperature_bias``), selected by weighted Holm at a family-wise 1 % with the known noise
(χ² tests), and ``bias_drift`` from the slopes inside the positions
(:mod:`.drift`). Everything of the accelerometer is untestable: the report says so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.calibrate import FitQuality, SiteConditions, Solution, birge
from canimucal.analysis.drift import DriftTest, allan_walk_upper, drift_test, walk_consistent
from canimucal.analysis.settling import fit_settling, trim_mask
from canimucal.analysis.significance import (
    LinearProblem,
    entry_test,
    entry_weights,
    fit_terms,
    forward_select,
    holm_adjust,
)
from canimucal.errors import InputError
from canimucal.io.calibration import Device, Fit, RecordingRef, record_from_estimates
from canimucal.io.grouping import position_rows
from canimucal.io.recording import Recording
from canimucal.model.dcm_stack import dcm_stack
from canimucal.model.frames import EARTH_RATE_RAD_S, earth_rate_level
from canimucal.model.small_linalg import solve_lower
from canimucal.model.vocabulary.effects import EFFECTS, PoseInputs
from canimucal.model.vocabulary.plans import CUSTOM, SCALAR, plan_of_poses

Array = NDArray[np.float64]

MIN_POSITIONS = 2
"""A gyro-only solve needs this many labelled positions (the bias from two is already one)."""
MIN_SAMPLES = 20
"""A position with fewer gyro samples is skipped (as the loop skips them)."""
FAMILY_ALPHA = 0.01
"""The family-wise level of the gyro-only tests (docs/design.md §6)."""
NO_ACCEL = "no accelerometer data in the file"
"""Why every accelerometer effect is untestable on a gyro-only file."""
_MATCH_RAD = float(np.deg2rad(0.05))
"""Recorded angles within this of a built-in plan's are that plan's poses."""
EARTH_NAMES = ("gyro.earth_rate_level[0]", "gyro.earth_rate_level[1]", "gyro.earth_rate_level[2]")


def has_accel(rec: Recording) -> bool:
    """Whether the recording holds any accelerometer sample."""
    return bool(np.isfinite(rec.accel).any())


@dataclass(frozen=True)
class GyroPositions:
    """The static positions of a gyro-only recording: means, their covariance, their poses.

    ``angles`` ``(n, 3)`` rad, NaN where the recording gives none; ``windows`` the kept samples
    ``(t, gyro)`` of each position (the settling after each move trimmed); ``temp_c`` each
    position's mean temperature (NaN: none recorded).
    """

    means: Array
    covariances: Array
    angles: Array
    windows: tuple[tuple[Array, Array], ...]
    temp_c: Array
    counts: NDArray[np.int64]
    temp_rates: Array | None = None
    """°C/s inside each position (the drift test removes that part), None: not recorded."""

    @property
    def known(self) -> bool:
        """Whether every position's angles are known."""
        return bool(np.all(np.isfinite(self.angles)))


def gyro_positions(rec: Recording) -> GyroPositions:
    """Group a gyro-only recording into its labelled positions (InputError when it has none)."""
    rows, labelled = position_rows(rec)
    name = rec.source or "recording"
    if not labelled:
        raise InputError(
            f"{name}: {NO_ACCEL} and no position labels: the static positions cannot be found "
            "from the gyro alone; label them (the position column), or run `allan` on one "
            "static stretch"
        )
    kept = [r[np.all(np.isfinite(rec.gyro[r]), axis=1)] for r in rows]
    kept = [r for r in kept if r.size >= MIN_SAMPLES]
    if not kept:
        raise InputError(f"{name}: {NO_ACCEL} and no position with gyro samples")
    settling = fit_settling([(rec.t[r], rec.gyro[r]) for r in kept])
    means, covs, angles, windows, temps, counts, rates = [], [], [], [], [], [], []
    for r, trim in zip(kept, settling.trim_s, strict=True):
        r = r[trim_mask(rec.t[r], float(trim))]
        x = np.asarray(rec.gyro[r], dtype=np.float64)
        means.append(x.mean(axis=0))
        covs.append(np.cov(x, rowvar=False, ddof=1) / r.size)
        first = r[0]
        angles.append(
            np.deg2rad(
                [float(rec.alpha_deg[first]), float(rec.beta_deg[first]), float(rec.psi_deg[first])]
            )
        )
        windows.append((rec.t[r], x))
        t = np.asarray(rec.temp_c[r], dtype=np.float64)
        ok = np.isfinite(t)
        temps.append(float(np.mean(t[ok])) if ok.any() else np.nan)
        rates.append(float(np.polyfit(rec.t[r][ok], t[ok], 1)[0]) if ok.sum() > 1 else 0.0)
        counts.append(r.size)
    temp_c = np.array(temps)
    return GyroPositions(
        np.array(means), np.array(covs), np.array(angles, dtype=float), tuple(windows),
        temp_c, np.array(counts, dtype=np.int64),
        np.array(rates) if np.isfinite(temp_c).all() and np.any(rates) else None,
    )  # fmt: skip


# --------------------------------------------------------------------------------- solve


@dataclass(frozen=True)
class GyroFit:
    """A generalised least-squares fit of eq. (1): named values, covariance, χ², dof."""

    names: tuple[str, ...]
    values: Array
    covariance: Array
    chi2: float
    dof: int
    residuals: Array


def _gls(y: Array, x: Array, cov: Array, names: Sequence[str]) -> GyroFit:
    """Fit ``y = X θ + e``, ``e ~ N(0, cov)``: values, covariance, χ² on ``N − rank`` dof."""
    chol = np.linalg.cholesky(cov)
    xw = solve_lower(chol, x)
    yw = solve_lower(chol, y)
    info = xw.T @ xw
    values = np.asarray(np.linalg.solve(info, xw.T @ yw), dtype=float)
    resid = yw - xw @ values
    dof = int(y.size - np.linalg.matrix_rank(xw))
    covariance = np.asarray(np.linalg.inv(info), dtype=float)
    return GyroFit(tuple(names), values, covariance, float(resid @ resid), dof, y - x @ values)


def _block(covariances: Array) -> Array:
    n = covariances.shape[0]
    out = np.zeros((3 * n, 3 * n))
    for k in range(n):
        out[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = covariances[k]
    return out


def _rotations(angles: Array) -> Array:
    """``C_i`` (n, 3, 3), body ← level, of poses with known angles (no base tilt)."""
    return dcm_stack(angles, 0.0, 0.0, "rigid")[0]


def fit_gyro_positions(pos: GyroPositions, site: SiteConditions, *, scale: bool = False) -> GyroFit:
    """Fit eq. (1) as ``solve`` does: the bias, and with ``scale`` the diagonal of S (nav).

    The Earth rate: the site's with a latitude (and known angles), else marginalised; with
    unknown angles its ``Ω²/3`` per axis is shared noise of the means.
    """
    n = pos.means.shape[0]
    s_nom = np.eye(3) / site.gyro_lsb
    y = pos.means.reshape(-1)
    cov = _block(pos.covariances)
    columns = [np.tile(np.eye(3), (n, 1))]
    names = [f"gyro.bias[{i}]" for i in range(3)]
    if pos.known:
        c = _rotations(pos.angles)
        if site.latitude is not None:
            w = np.einsum("nij,j->ni", c, earth_rate_level(site.latitude, site.heading))
            if scale:
                columns.append(np.concatenate([np.diag(wi) for wi in w]))
                names += [f"gyro.S[{i}][{i}]" for i in range(3)]
            else:
                y = y - (w @ s_nom.T).reshape(-1)
        else:
            if scale:
                raise InputError(
                    "gyro='nav' needs latitude_deg (the gyro scale comes from Earth rate)",
                    options=("gyro='nav'", "latitude_deg"),
                )
            m = np.concatenate([s_nom @ ci for ci in c])  # (3n, 3): d mean / d w_L
            cov = cov + (EARTH_RATE_RAD_S**2 / 3.0) * (m @ m.T)
    else:
        if scale:
            raise InputError("gyro='nav' needs positions with angles (the Earth rate's direction)")
        m = np.tile(s_nom, (n, 1))
        cov = cov + (EARTH_RATE_RAD_S**2 / 3.0) * (m @ m.T)
    return _gls(y, np.hstack(columns), cov, names)


def solve_gyro_only(
    rec: Recording,
    site: SiteConditions,
    device: Device,
    *,
    gyro: str | None = None,
    plan_name: str | None = None,
    recording: RecordingRef | None = None,
) -> Solution:
    """Solve a gyro-only recording: the gyro's bias (and with ``gyro='nav'`` its diagonal S).

    The record's accelerometer block is ``null`` (nothing was estimated), so acceptance fails
    ("accelerometer parameters determined"): nothing of the accelerometer may be written from
    it. ``gyro='moves'`` is refused: its S comes with the accelerometer's attitude.
    """
    if gyro == "moves":
        raise InputError(
            f"gyro='moves' needs the accelerometer ({NO_ACCEL}): the moves' attitudes come "
            "from gravity",
            options=("gyro='moves'",),
        )
    if gyro == "none":
        raise InputError(f"gyro='none' on a gyro-only file leaves nothing to solve ({NO_ACCEL})")
    pos = gyro_positions(rec)
    if pos.means.shape[0] < MIN_POSITIONS:
        raise InputError(
            f"{rec.source or 'recording'}: need at least {MIN_POSITIONS} positions, "
            f"got {pos.means.shape[0]}"
        )
    fit = fit_gyro_positions(pos, site, scale=gyro == "nav")
    if plan_name is None:
        plan_name = (plan_of_poses(pos.angles, _MATCH_RAD) or CUSTOM) if pos.known else SCALAR
    quality = birge(fit.chi2, fit.dof)
    covariance = fit.covariance * quality.inflation**2
    record = record_from_estimates(
        fit.names, fit.values, covariance, device=device, plan=plan_name,
        conditions=site.as_record_conditions(), fit=Fit(dof=fit.dof), recording=recording,
    )  # fmt: skip
    warnings: tuple[str, ...] = (
        f"{NO_ACCEL}: the accelerometer's bias and K and the base tilt are not estimated "
        f"(null); the gyro's bias comes from {pos.means.shape[0]} positions, and acceptance "
        "cannot pass: nothing of the accelerometer may be written from this file",
    )
    if not pos.known:
        warnings += ("no angles: the Earth rate is noise of the gyro bias (Ω²/3 per axis)",)
    return Solution(record, warnings=warnings, quality=quality)


# ------------------------------------------------------------------------------- analyze


@dataclass(frozen=True)
class GyroFinding:
    """A cause the gyro alone shows: effect, size (largest entry), its units, Holm p."""

    effect: str
    size: float
    units: str
    p_value: float
    evidence: str


@dataclass(frozen=True)
class GyroAnalysis:
    """What a gyro-only recording shows (module doc): base fit, findings, untestable."""

    positions: int
    known: bool
    base: GyroFit
    base_p: float
    findings: tuple[GyroFinding, ...]
    untestable: dict[str, str]
    drift: DriftTest
    earth_rate: str

    @property
    def quality(self) -> FitQuality:
        """The base fit's χ² on its dof."""
        return FitQuality(self.base.chi2, self.base.dof)


def analyse_gyro_only(rec: Recording, site: SiteConditions) -> GyroAnalysis:
    """Run the gyro-only discrepancy tests on ``rec`` (module doc)."""
    pos = gyro_positions(rec)
    n = pos.means.shape[0]
    if n < 3:
        raise InputError(f"{rec.source or 'recording'}: found {n} positions, need 3")
    untestable = {
        e.name: NO_ACCEL for e in EFFECTS.values() if e.sensors == ("accel",) or not e.sensors
    }
    y, base_x, base_names, cov, earth = _base_design(pos, site)
    base = _gls(y, base_x, cov, base_names)
    from scipy.special import chdtrc

    base_p = float(chdtrc(base.dof, base.chi2)) if base.dof > 0 else float("nan")
    columns = _candidate_columns(pos, site, untestable)
    drift = drift_test(list(pos.windows), pos.temp_rates)
    chol = np.linalg.cholesky(cov)

    def whiten(a: Array) -> Array:
        return solve_lower(chol, a)

    problem = LinearProblem(
        residual_w=whiten(base.residuals), base_w=whiten(base_x),
        block=np.repeat(np.arange(n), 3), unwhiten=np.asarray(chol, dtype=np.float64),
        si_scale=np.full(3 * n, site.gyro_lsb),
        sensor=np.full(3 * n, "gyro").astype(np.str_),
    )  # fmt: skip
    white = {k: whiten(c) for k, c in columns.items()}
    weights = {k: float(v) for k, v in entry_weights(problem, white).items()}
    family = sum(weights.values()) + 1.0  # and the drift test
    chosen = forward_select(problem, white, alpha=FAMILY_ALPHA, family_size=family, weights=weights)
    findings = _findings(problem, white, chosen, weights, drift, pos)
    return GyroAnalysis(n, pos.known, base, base_p, tuple(findings), untestable, drift, earth)


def _base_design(
    pos: GyroPositions, site: SiteConditions
) -> tuple[Array, Array, list[str], Array, str]:
    """``y``, the base design (bias, Earth-rate nuisance), its names, cov, and the wording."""
    n = pos.means.shape[0]
    s_nom = np.eye(3) / site.gyro_lsb
    y = pos.means.reshape(-1)
    cov = _block(pos.covariances)
    bias = np.tile(np.eye(3), (n, 1))
    if not pos.known:
        m = np.tile(s_nom, (n, 1))
        cov = cov + (EARTH_RATE_RAD_S**2 / 3.0) * (m @ m.T)
        return (
            y,
            bias,
            [f"gyro.bias[{i}]" for i in range(3)],
            cov,
            ("no angles: the Earth rate is shared noise of the means (Ω²/3 per axis)"),
        )
    c = _rotations(pos.angles)
    free = [0, 2]  # East and North: no heading is trusted
    if site.latitude is None:
        free = [0, 1, 2]
        wording = "no latitude: the Earth rate is fitted as a free vector in the level frame"
    else:
        vertical = np.array([0.0, -EARTH_RATE_RAD_S * np.sin(site.latitude), 0.0])
        y = y - np.einsum("nij,j->ni", c, vertical).reshape(-1) / site.gyro_lsb
        wording = "the Earth rate's horizontal part is fitted, its vertical part the latitude's"
    earth = np.concatenate([s_nom @ ci[:, free] for ci in c])
    earth = _off_the_bias(bias, earth)
    names = [f"gyro.bias[{i}]" for i in range(3)] + [EARTH_NAMES[k] for k in free][: earth.shape[1]]
    return y, np.hstack([bias, earth]), names, cov, wording


def _off_the_bias(bias: Array, earth: Array) -> Array:
    """Keep the Earth-rate directions the poses tell from the bias (the rest is the bias's)."""
    q, _ = np.linalg.qr(bias)
    rest = earth - q @ (q.T @ earth)
    u, s, vt = np.linalg.svd(rest, full_matrices=False)
    keep = s > 1e-6 * max(float(np.max(np.linalg.norm(earth, axis=0))), 1e-300)
    return np.asarray(earth @ vt[keep].T, dtype=float)


def _candidate_columns(
    pos: GyroPositions, site: SiteConditions, untestable: dict[str, str]
) -> dict[str, Array]:
    """Build the registry's gyro effects' known-pose columns, gyro rows only (raw counts)."""
    out: dict[str, Array] = {}
    for effect in EFFECTS.values():
        if "gyro" not in effect.sensors or effect.known is None:
            continue
        if not pos.known:
            untestable[effect.name] = "no angles in a gyro-only file"
            continue
        temps = pos.temp_c - np.nanmean(pos.temp_c) if np.isfinite(pos.temp_c).all() else None
        if "temperature" in effect.name and (temps is None or np.ptp(temps) == 0):
            untestable[effect.name] = "no temperature change recorded"
            continue
        inputs = PoseInputs.at(
            pos.angles, g=site.g, k_matrix=np.eye(3) / site.accel_lsb,
            s_matrix=np.eye(3) / site.gyro_lsb,
            w_level=np.zeros(3) if site.latitude is None else earth_rate_level(site.latitude),
            channels=6, temperatures=temps,
        )  # fmt: skip
        cols = effect.known(inputs, "gyro")
        if cols is None:
            untestable[effect.name] = "no columns at these poses"
            continue
        out[f"gyro.{effect.name}"] = np.asarray(cols[:, 3:, :], dtype=float).reshape(
            -1, cols.shape[2]
        )
    return out


def _findings(
    problem: LinearProblem,
    columns: dict[str, Array],
    chosen: Sequence[str],
    weights: dict[str, float],
    drift: DriftTest,
    pos: GyroPositions,
) -> list[GyroFinding]:
    """Name the chosen terms and ``bias_drift`` (a walk the Allan deviation allows).

    Each term's p is Holm-adjusted, every candidate tested beside the others chosen.
    """
    family = sum(weights.values()) + 1.0
    out = []
    if chosen:
        fit = fit_terms(problem, columns, list(chosen))
        tests = [entry_test(problem, columns, [c for c in chosen if c != k], k) for k in columns]
        held = holm_adjust([t.p_value for t in tests], [weights[k] for k in columns])
        adjusted = dict(zip(columns, held, strict=True))
        for key in chosen:
            name = key.split(".", 1)[1]
            coef, sig = fit.coefficients[key], fit.sigmas[key]
            top = int(np.argmax(np.abs(coef) / np.where(sig > 0, sig, np.inf)))
            labels = EFFECTS[name].labels
            unit = EFFECTS[name].unit
            out.append(
                GyroFinding(
                    name, float(coef[top]), unit, float(adjusted[key]),
                    f"{labels[top]} = {coef[top]:.4g} ± {sig[top]:.2g} {unit}",
                )
            )  # fmt: skip
    p_drift = min(1.0, drift.p_value * family)
    if p_drift < FAMILY_ALPHA and walk_consistent(drift, allan_walk_upper(list(pos.windows))):
        q, s = drift.random_walk, drift.random_walk_sigma
        top = int(np.argmax(q))
        out.append(
            GyroFinding(
                "bias_drift", float(q[top]), EFFECTS["bias_drift"].unit, p_drift,
                f"within-position slopes χ² = {drift.statistic:.1f} on {drift.df} dof; random "
                f"walk q = {np.array2string(q, precision=3)} ± "
                f"{np.array2string(s, precision=2)} counts/√s",
            )
        )  # fmt: skip
    return out


# -------------------------------------------------------------------------------- reports


def gyro_document(a: GyroAnalysis, notes: Sequence[str] = ()) -> dict[str, object]:
    """Build the analysis JSON (docs/design.md §5) of a gyro-only file: no sensor blocks."""
    rejected = bool(a.base.dof > 0 and a.base_p < FAMILY_ALPHA)
    return {
        "schema": "canimucal.analysis/1",
        "sensors": {},
        "findings": [
            {
                "effect": f.effect,
                "sensor": "gyro",
                "size": f.size,
                "units": f.units,
                "p_value": f.p_value,
                "evidence": f.evidence,
            }
            for f in a.findings
        ],  # fmt: skip
        "untestable": [{"effect": k, "reason": v} for k, v in a.untestable.items()],
        "ambiguous": [],
        "base_fit": {
            "chi2": a.base.chi2,
            "dof": a.base.dof,
            "p_value": a.base_p,
            "rejected": rejected,
            "summary": None if a.findings else _summary(a),
        },  # fmt: skip
        "noise": {"warnings": [*notes, NO_ACCEL + ": the gyro alone was analysed"]},
    }


def _summary(a: GyroAnalysis) -> str:
    ratio = a.base.chi2 / a.base.dof if a.base.dof > 0 else float("nan")
    if a.base.dof > 0 and a.base_p < FAMILY_ALPHA:
        return (
            f"no cause named; the base model is rejected, χ²/dof {ratio:.4g}: the misfit is "
            "not one of the candidates"
        )
    return f"no cause named; the base model fits (χ²/dof {ratio:.3g})"


def gyro_report(a: GyroAnalysis, notes: Sequence[str] = ()) -> str:
    """Build the readable report of a gyro-only file: base fit, findings, untestable."""
    kind = "known angles" if a.known else "no angles"
    lines = [
        f"{a.positions} static positions ({kind}); {NO_ACCEL}: the gyro alone is analysed",
        *(f"note: {n}" for n in notes),
        "",
        "Base model (gyro bias and the Earth rate):",
    ]
    sigma = np.sqrt(np.diag(a.base.covariance))
    for name, value, s in zip(a.base.names, a.base.values, sigma, strict=True):
        unit = "rad/s" if "earth_rate" in name else "counts"
        lines.append(f"  {name} = {value:.6g} ± {s:.2g} {unit}")
    lines.append(f"  {a.earth_rate}")
    ratio = a.base.chi2 / a.base.dof if a.base.dof > 0 else float("nan")
    lines += [
        f"  lack of fit: χ² {a.base.chi2:.1f} on {a.base.dof} dof (χ²/dof {ratio:.3g}, "
        f"p = {a.base_p:.2g})",
        "",
        "Findings (Holm-adjusted p, family-wise 1 %):",
    ]
    lines += [f"  {f.effect} (gyro): {f.evidence}; p = {f.p_value:.2g}" for f in a.findings]
    if not a.findings:
        lines.append(f"  {_summary(a)}")
    lines += ["", "Untestable:"]
    lines += [f"  {k}: {v}" for k, v in a.untestable.items()]
    return "\n".join(lines) + "\n"
