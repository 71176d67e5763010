"""The model-discrepancy loop on measured data (docs/design.md §6): test, name, extend, score.

:func:`analyse_discrepancy` fits the base model (bias + diagonal scale + white noise; the
known-position joint model when angles are labelled, the scalar ``|f| = g`` fit otherwise),
then

1. recognises drift inside the positions first (:mod:`.drift`), on windows already trimmed of
   the settling after each move (:mod:`.settling`). Trends are named ``bias_drift`` only when
   their random walk is one the Allan deviation of the same windows allows; then the walk's
   covariance joins that of the position means. Other accelerometer trends are read for
   motion: positions whose direction turned while ``|f|`` stayed steady are said so, "the
   unit moved 0.3° during position 3" (:mod:`.motion`). With trends of any kind the later
   tests become F tests, so a wandering bias or motion is not mistaken for temperature or
   scale terms;
2. tests every candidate of the vocabulary entry by entry (nested-model LR or F tests of
   each entry, Bonferroni within the candidate), adding terms in the step-down order of
   Holm's procedure weighted by each candidate's number of entries, at a family-wise
   ``alpha`` (:mod:`.significance`);
3. keeps a chosen term only if leave-one-position-out cross-validation agrees, and names it
   when it is significant beside each rival in the model holding both (both named when both
   are; the pair ambiguous, the term dropped, when neither is: docs/design.md §6);
4. refits with the chosen terms and reports rms/cv_rms before and after, per sensor, the
   held-out cv_rms by refitting without each position, selection included
   (:mod:`.holdout`); a sensor with under 10 residual dof whose extension predicts the
   left-out positions significantly worse (the ratio's 95 % interval below 1) names none
   of its terms.

``axis_sign`` is a sign check of the base fit's diagonal K against the nominal LSB (> 5σ).
Candidates the data cannot test are returned in ``untestable`` with the reason.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.base_fit import (
    PreparedBase,
    earth_rate_visible,
    fit_known,
    fit_scalar_base,
    named_values,
    temperature_status,
    trial_biases,
)
from canimucal.analysis.candidates import Candidate
from canimucal.analysis.data import (
    AXIS_SIGN_SIGMAS,
    FAMILY_ALPHA,
    Ambiguity,
    DiscrepancyResult,
    ExtendedParams,
    Finding,
    NoiseSummary,
    Samples,
    SensorScore,
    SessionData,
    TestRecord,
)
from canimucal.analysis.drift import (
    DriftTest,
    allan_walk_upper,
    drift_test,
    random_walk_covariance,
    walk_consistent,
)
from canimucal.analysis.exact_fit import exact_fit
from canimucal.analysis.holdout import MIN_GAIN_DOF, Holdout, Selector, refit_holdout
from canimucal.analysis.motion import PositionMotion, moved_alone
from canimucal.analysis.noise_model import (
    ScatterEstimate,
    ScatterModel,
    block_labels,
    estimate_scatter,
)
from canimucal.analysis.separation import separating_position
from canimucal.analysis.significance import (
    LinearProblem,
    TermFit,
    confirm_by_cv,
    effective_rank,
    entry_test,
    entry_weights,
    fit_terms,
    forward_select,
    holm_adjust,
    pair_correlation,
    score_model,
    significant_columns,
    significant_masks,
)
from canimucal.errors import ModelError
from canimucal.model.joint import JointResult
from canimucal.model.vocabulary.effects import EFFECTS, column_effects

log = logging.getLogger(__name__)

Array = NDArray[np.float64]


def analyse_discrepancy(data: SessionData, *, alpha: float = FAMILY_ALPHA) -> DiscrepancyResult:
    """Run the discrepancy loop on one session (module doc); ``alpha`` family-wise."""
    if len(data.averages) != len(data.windows):
        raise ModelError(f"{len(data.averages)} averages but {len(data.windows)} windows")
    if not 0.0 < alpha < 1.0:
        raise ModelError(f"alpha must be within (0, 1), got {alpha}")
    joint = fit_known(data) if data.known_positions else None
    prepared = joint[0] if joint is not None else fit_scalar_base(data)[0]
    untestable = _untestable(data)
    temps, temp_reason = temperature_status(data)
    candidates = [c for c in prepared.candidates if not (temp_reason and "temperature" in c.key)]
    if temp_reason:
        untestable["temperature_bias"] = temp_reason
    drifts = _drift_tests(data, temps)
    weights = _weights(prepared, candidates)
    # the family: every entry of every candidate, each drift test, the axis-sign test
    family = sum(weights.values()) + len(drifts) + (1 if data.known_positions else 0)
    trending = {s for s, d in drifts.items() if d.p_value < alpha / family}
    moved = _motion(data, temps, alpha / family) if "accel" in trending else ()
    drifting = {s for s in trending if _walk_like(drifts[s], data, s)} - (
        {"accel"} if moved else set()
    )
    raw_columns = {c.key: c.columns for c in candidates}
    scatter = _scatter_model(prepared, drifts, drifting, data)
    tau = _scatter_in(scatter, prepared, raw_columns, list(raw_columns))
    problem = _whitened(prepared, scatter, tau.value)
    columns = {k: problem.whiten @ col for k, col in raw_columns.items()}
    for key in [k for k, col in columns.items() if effective_rank(problem.linear, col) == 0]:
        untestable.setdefault(key.split(".", 1)[1], "not identifiable from these positions")
        del columns[key]
        del raw_columns[key]
        del weights[key]
    tau_bound = scatter.tau_max
    if joint is not None and scatter.fixed is None:
        full = _full_model_scatter(data, prepared, scatter, list(raw_columns))
        if full is not None:
            tau = full
            scatter = dataclasses.replace(scatter, tau_max=max(tau.ci95[1], MIN_TAU_CAP_RAD))
            problem = _whitened(prepared, scatter, tau.value)
            columns = {k: problem.whiten @ col for k, col in raw_columns.items()}
    use_f = bool(trending)  # trends of any kind: the residual scale comes from the fit
    chosen = forward_select(
        problem.linear, columns, alpha=alpha, family_size=family, use_f=use_f, weights=weights
    )
    if scatter.fixed is None:
        tau = _scatter_in(scatter, prepared, raw_columns, chosen)
        problem = _whitened(prepared, scatter, tau.value)
        columns = {k: problem.whiten @ col for k, col in raw_columns.items()}
    base_problem, base_columns, base_prepared = problem, columns, prepared
    if joint is not None:
        # tests against the exactly fitted chosen model, not the tilt-free linearisation
        prepared, chosen, tau = _exact_selection(
            data, prepared, scatter, tau, list(raw_columns), chosen,
            lambda p, c: forward_select(
                p, c, alpha=alpha, family_size=family, use_f=use_f, weights=weights
            ),
        )  # fmt: skip
        raw_columns = {c.key: c.columns for c in prepared.candidates if c.key in raw_columns}
        problem = _whitened(prepared, scatter_at(scatter, base_prepared, prepared), tau.value)
        columns = {k: problem.whiten @ col for k, col in raw_columns.items()}
    chosen = confirm_by_cv(problem.linear, columns, chosen)
    tangent = None
    if joint is not None:
        tangent = _tangent(data, base_prepared, scatter, tau.value, list(raw_columns))
    duel, also, dropped = _head_to_head(
        problem.linear, columns, chosen, alpha, (weights, family), use_f, tangent
    )
    if joint is not None:
        nuisance = prepared.names[len(joint[1].names) :]
        enough = separated_noncentrality(alpha / family)
        duel = [
            _separate(
                x, data, joint[1], problem.linear, columns, chosen, tau.value, nuisance, enough
            )
            for x in duel
        ]
    unresolved = {f"{a.sensor}.{a.candidates[0]}" for a in duel} | set(dropped)
    # an ambiguous term is neither named nor kept in the extended model; a rival significant
    # beside its term (and the term beside it) is named with it
    chosen = [c for c in chosen if c not in unresolved] + [r for r in also if r not in chosen]
    tests = _final_tests(
        problem.linear, columns, chosen, use_f, weights, drifts, drifting, prepared, data
    )
    fit = fit_terms(problem.linear, columns, chosen)
    if use_f:
        fit = _on_residual_scale(fit)
    findings = _findings(tests, fit, {c.key: c for c in candidates}, drifts, prepared, data, alpha)
    select = _selector(alpha, family, use_f, weights)
    held = refit_holdout(_uncapped(problem.linear, tau_bound), columns, select, extended=chosen)
    refuted = _refuted(chosen, held)
    findings = [f for f in findings if f"{f.sensor}.{f.effect}" not in refuted]
    kept = [c for c in chosen if c not in refuted]
    sparse = significant_columns(problem.linear, columns, chosen)
    if prepared.earth_unit_covariance is not None:
        untestable["earth_rate"] += (
            f"; the gyro's scale unknown, its size is estimated from the data: "
            f"{tau.value:.3g} counts (REML, 95 % {tau.ci95[0]:.3g}–{tau.ci95[1]:.3g}), which "
            "also holds any other rate misfit of that kind"
        )
    values, sigmas = named_values(base_prepared)
    base = fit_terms(base_problem.linear, base_columns, [])
    lack = (base_prepared.chi2, base_prepared.dof)
    if base_prepared.method == "joint":
        lack = (base.chi2, base.dof)
        values, sigmas = _base_under(base_problem.linear, base_prepared, base)
    return DiscrepancyResult(
        method=prepared.method,
        residuals=prepared.residual_table,
        residual_labels=prepared.residual_labels,
        lack_of_fit=(lack[0], lack[1], _chi2_sf(*lack)),
        findings=tuple(findings),
        untestable=untestable,
        tests=tuple(tests),
        scores=_scores(problem.linear, sparse, kept, held, _earth_rate_in_base(data)),
        params=_extended(prepared, fit_terms(problem.linear, sparse, kept), drifts, drifting, data),
        base_values=values,
        base_sigmas=sigmas,
        drift_found=bool(drifting),
        noise=NoiseSummary(tau, fit.chi2, fit.dof) if data.known_positions else None,
        warnings=_warnings(chosen, held, refuted)
        + _drift_warnings(drifts, drifting, data, alpha / family, moved),
        ambiguous=tuple(duel),
        earth_rate_horizontal=tau if prepared.earth_unit_covariance is not None else None,
        trials=len(data.trials),
    )


Tangent = Callable[[Sequence[str]], tuple[LinearProblem, dict[str, Array]]]
"""The linear problem and whitened columns at the exact fit of a set of terms."""


def _tangent(
    data: SessionData, base: PreparedBase, scatter: ScatterModel, tau: float, keys: Sequence[str]
) -> Tangent:
    """Return the tangent of the exact fit of any set of terms under the noise model ``τ``."""

    def linearise(p: PreparedBase) -> tuple[LinearProblem, dict[str, Array]]:
        w = _whitened(p, scatter_at(scatter, base, p), tau)
        return w.linear, {c.key: w.whiten @ c.columns for c in p.candidates if c.key in keys}

    def at(terms: Sequence[str]) -> tuple[LinearProblem, dict[str, Array]]:
        return linearise(exact_fit(data, base, terms, linearise))

    return at


def _exact_selection(
    data: SessionData,
    base: PreparedBase,
    scatter: ScatterModel,
    tau: ScatterEstimate,
    keys: Sequence[str],
    chosen: Sequence[str],
    select: Callable[[LinearProblem, Mapping[str, Array]], list[str]],
) -> tuple[PreparedBase, list[str], ScatterEstimate]:
    """Select the terms again at the exact fit of the chosen model (:mod:`.exact_fit`).

    The selection at the base fit's linearisation proposes terms; the model holding them is
    fitted to convergence and every candidate is tested again on its tangent there, until
    the chosen set repeats (at most :data:`EXACT_ROUNDS` rounds). With an estimated scatter
    τ is re-estimated at the exact fit. Returns the exact fit linearised at its estimate.
    A set that never repeats (on seed 2 of tests/analysis/test_separation_rule.py, means
    pushed ±3 counts at random, it cycles between base_tilt and cross_axis beside
    scale_nonlinearity) is a misfit none of the candidates is: the base fit's selection
    and linearisation stand, as before.
    """

    def linearise(p: PreparedBase, t: float) -> tuple[LinearProblem, dict[str, Array]]:
        w = _whitened(p, scatter_at(scatter, base, p), t)
        return w.linear, {c.key: w.whiten @ c.columns for c in p.candidates if c.key in keys}

    def fitted(terms: Sequence[str], t: float) -> PreparedBase:
        return exact_fit(data, base, terms, functools.partial(linearise, t=t))

    terms, start = list(chosen), tau
    exact = base
    for _ in range(EXACT_ROUNDS):
        exact = fitted(terms, tau.value)
        if scatter.fixed is None:
            raw = {c.key: c.columns for c in exact.candidates if c.key in keys}
            tau = _scatter_in(scatter_at(scatter, base, exact), exact, raw, terms)
            exact = fitted(terms, tau.value)
        again = select(*linearise(exact, tau.value))
        if set(again) == set(terms):
            break
        terms = again
    else:  # the set cycles: a misfit that is none of the candidates; the base's selection
        return base, list(chosen), start
    return exact, terms, tau


def _full_model_scatter(
    data: SessionData,
    base: PreparedBase,
    scatter: ScatterModel,
    keys: Sequence[str],
) -> ScatterEstimate | None:
    """REML pose scatter in the model holding every candidate, fitted exactly (:mod:`.exact_fit`).

    The caller caps every later estimate at this one's 95 % upper end (docs/design.md §6,
    *Noise model*), so that no term is judged against a scatter that another, missing term's
    misfit has inflated. Estimated at the tilt-free base fit's linearisation, even the
    largest model keeps the linearisation's leftover (0.2–0.7 counts a position at a 1°
    tilt), and where the means are precise (417 s positions of the recommended plan) REML put
    it into the scatter, at its 10° bound; fitted from that τ, the exact fit hardly moved.
    So the exact fit starts from τ = 0 and τ is re-estimated after each of
    :data:`FULL_MODEL_PASSES` fits: 0.08–0.16° on those files, whose poses were set with the
    plan's tolerances (`benchmarks/long_positions.py`).

    None (no cap: each model's own REML, as before) when the estimate does not settle: its
    last two passes differ by more than :data:`SETTLED` of the larger, or it sits at the
    bound. A misfit that is none of the candidates does that (tests/analysis/
    test_separation_rule.py, seed 2, every mean pushed ±3 counts: 10°, then 0° with an
    empty interval), and a cap taken from it made phantoms of three candidates.
    """
    if not keys:
        return None

    def linearise(p: PreparedBase, t: float) -> tuple[LinearProblem, dict[str, Array]]:
        w = _whitened(p, scatter_at(scatter, base, p), t)
        return w.linear, {c.key: w.whiten @ c.columns for c in p.candidates if c.key in keys}

    values = [0.0]  # not the linearisation's τ: whitened at 10°, the fit hardly moves from it
    for _ in range(FULL_MODEL_PASSES):
        exact = exact_fit(data, base, keys, functools.partial(linearise, t=values[-1]))
        raw = {c.key: c.columns for c in exact.candidates if c.key in keys}
        tau = _scatter_in(scatter_at(scatter, base, exact), exact, raw, keys)
        values.append(tau.value)
    last, before = values[-1], values[-2]
    if last >= scatter.tau_max * (1.0 - 1e-6) or abs(last - before) > SETTLED * max(last, before):
        return None
    return tau


MIN_TAU_CAP_RAD = float(np.deg2rad(0.01))
"""The least cap on the pose scatter: a largest model whose 95 % interval ends below this
(exact poses) still lets a smaller model's REML reach 0.01°."""


def _uncapped(linear: LinearProblem, tau_max: float) -> LinearProblem:
    """``linear`` with its scatter's bound put back: a held-out fold estimates its own τ.

    The cap of :func:`_full_model_scatter` is the whole session's; a fold leaves a position
    out, and capped there imucal's six-position session predicted its held-out pose 17×
    worse (cv_rms 0.080 → 1.36 m/s², against 0.082 uncapped).
    """
    if linear.scatter is None or linear.scatter.tau_max == tau_max:
        return linear
    return dataclasses.replace(linear, scatter=dataclasses.replace(linear.scatter, tau_max=tau_max))


FULL_MODEL_PASSES = 3
"""Exact fit of the largest model at τ = 0 → τ → exact fit again → τ → again → τ."""
SETTLED = 0.25
"""The largest model's τ is taken when its last two passes agree within this fraction."""

EXACT_ROUNDS = 3
"""Rounds of selection at the exact fit (the chosen set settles in one or two)."""


def scatter_at(scatter: ScatterModel, base: PreparedBase, exact: PreparedBase) -> ScatterModel:
    """Move the noise family ``V(τ)``'s angle-error parts to those of ``exact`` (eq. 3).

    ``scatter`` was built on the tilt-free ``base``: its ``unit`` (the covariance per rad² of
    angle scatter) is replaced by ``exact``'s, and a held scatter's angle part in ``base``
    (the poses' own tolerances) by ``exact``'s. The within-position part and a random walk's
    stay. ``base`` itself (or a fit without angle covariances) returns ``scatter`` as it is.
    """
    if exact is base or exact.angle_unit_covariance is None or base.angle_unit_covariance is None:
        return scatter
    unit = exact.angle_unit_covariance
    if scatter.source == "none":
        return scatter
    if scatter.fixed is None:  # estimated: V = within (+ walk) + τ² A
        return dataclasses.replace(scatter, unit=unit)
    held = scatter.base - base.covariance + exact.covariance  # the tolerances' part moves
    return dataclasses.replace(scatter, base=held, unit=unit)


def separated_noncentrality(level: float, power: float = 0.9) -> float:
    """Non-centrality at which a one-entry χ² test at ``level`` has ``power``.

    A pair whose head-to-head non-centrality (:mod:`.separation` eq. 3) already reaches it
    is separated by the recording's own positions: no position is proposed for it.
    """
    from scipy import special  # lazy (issue 23); chi2.isf, norm.ppf are chdtri, ndtri

    critical = float(special.chdtri(1, level))
    z = float(special.ndtri(power))
    return (np.sqrt(critical) + z) ** 2


def _head_to_head(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    chosen: Sequence[str],
    alpha: float,
    family: tuple[Mapping[str, float], float],
    use_f: bool,
    tangent: Tangent | None = None,
) -> tuple[list[Ambiguity], list[str], list[str]]:
    """Pit each chosen term against each rival that could stand in for it (docs/design.md §6).

    ``family`` holds each term's weight ``w`` and the family's total weight ``W``. Every
    p-value here is that of the per-entry test (:func:`~.significance.entry_test`: the
    largest single-entry test, Bonferroni over the candidate's entries), the test that chose
    the term, and "significant" is at the family-wise level: ``p / w · W < alpha`` (weighted
    Holm's first step). A rival is a candidate of the same sensor, not chosen, significant in
    place of the term. In the model holding both:

    - the term significant beside the rival: the term is named (whatever the rival does;
      the evidence for it grows with its size, so a large true effect is never held back by
      a look-alike's leftover);
    - both significant beside each other: both are named (the rival is returned in the
      second list, to join the model);
    - only the rival significant beside the term: the rival is named in its place (second
      list), the term dropped (third list);
    - neither significant beside the other: the pair is ambiguous, the term not named.

    The term is tested beside the rival as the rival stood in for it: the one entry whose
    test made it significant, or all its entries when its group test did. A rival's other
    entries explain nothing the term leaves (they did not stand out in its place) and only
    take power from the term's test.

    ``tangent`` (known positions) gives the linear problem and columns at the exact fit of a
    set of terms (:mod:`.exact_fit`): the model holding the term and its rival is fitted to
    convergence and both tests are made on its tangent; without it, on ``problem``.
    """
    weights, total = family

    def level(p: float, term: str) -> float:
        return p / weights[term] * total if weights[term] > 0 else float("inf")

    out: list[Ambiguity] = []
    also: list[str] = []
    dropped: list[str] = []
    for term in chosen:
        sensor = term.split(".", 1)[0]
        others = [c for c in chosen if c != term]
        stood = {
            r: entry_test(problem, columns, others, r, use_f=use_f)
            for r in columns
            if r not in chosen and r.startswith(sensor + ".")
        }
        rivals = [r for r, t in stood.items() if level(t.p_value, r) < alpha]
        for rival in rivals:
            k = stood[rival].column
            both, cols = (problem, columns) if tangent is None else tangent([*others, term, rival])
            held = cols if k is None else {**cols, rival: cols[rival][:, k : k + 1]}
            p_term = entry_test(both, held, [*others, rival], term, use_f=use_f).p_value
            p_rival = entry_test(both, cols, [*others, term], rival, use_f=use_f).p_value
            term_stands, rival_stands = level(p_term, term) < alpha, level(p_rival, rival) < alpha
            if term_stands:
                if rival_stands and rival not in also:
                    also.append(rival)
                continue
            if rival_stands:  # the rival explains it, the term nothing beside it: the rival
                dropped.append(term)
                if rival not in also:
                    also.append(rival)
                continue
            r = pair_correlation(problem, columns, [*others, term, rival], term, rival)
            pair = (term.split(".", 1)[1], rival.split(".", 1)[1])
            out.append(Ambiguity(sensor, pair, r))
    return out, also, dropped


def _separate(
    pair: Ambiguity,
    data: SessionData,
    joint: JointResult,
    problem: LinearProblem,
    columns: Mapping[str, Array],
    chosen: Sequence[str],
    tau: float,
    nuisance: Sequence[str],
    enough: float,
) -> Ambiguity:
    """Add the position that would separate an ambiguous pair best (:mod:`.separation`).

    None when the recording's own head-to-head non-centrality is ``enough`` already.
    """
    term, rival = (f"{pair.sensor}.{c}" for c in pair.candidates)
    others = [c for c in chosen if c != term]
    where = separating_position(
        data, joint, problem, columns, others, (term, rival), tau, nuisance, enough
    )
    return dataclasses.replace(pair, separating=where)


def _base_under(
    problem: LinearProblem, prepared: PreparedBase, base: TermFit
) -> tuple[dict[str, float], dict[str, float]]:
    """Return the base estimates and σ under the noise model used (one Gauss–Newton step)."""
    cov = np.linalg.pinv(problem.base_w.T @ problem.base_w)
    values = prepared.values + base.base_delta
    sig = np.sqrt(np.abs(np.diag(cov)))
    return (
        dict(zip(prepared.names, map(float, values), strict=True)),
        dict(zip(prepared.names, map(float, sig), strict=True)),
    )


def _chi2_sf(chi2: float, dof: int) -> float:
    from scipy import special  # lazy (issue 23); chi2.sf is chdtrc

    return float(special.chdtrc(dof, chi2)) if dof > 0 else float("nan")


def _earth_rate_in_base(data: SessionData) -> bool:
    """Whether the gyro's base model holds the Earth rate (from the latitude, or fitted)."""
    known = data.known_positions and data.latitude is not None
    return data.has_gyro and (known or earth_rate_visible(data))


def _untestable(data: SessionData) -> dict[str, str]:
    out: dict[str, str] = {}
    for effect in column_effects():  # what the registry's columns cannot show here
        if not data.known_positions and effect.scalar is None:
            out[effect.name] = "no angles: only the scalar |f| = g fit applies"
        if not data.has_gyro and effect.sensors == ("gyro",):
            out[effect.name] = "no gyro data"
    if not data.known_positions:
        out["axis_sign"] = "the sign of an axis is invisible to |f| = g fits"
    if data.has_gyro:
        out["earth_rate"] = _earth_rate_reason(data)
    return out


def _earth_rate_reason(data: SessionData) -> str:
    """Say how the gyro's base model holds the Earth rate, or why it leaves it out."""
    if not earth_rate_visible(data):
        return (
            "below the gyro's noise here (less than 1 unit of non-centrality over all "
            "positions at the nominal scale): left out of the model"
        )
    if not data.known_positions:
        return (
            "no orientation: the Earth rate's vertical part is fitted along f/|f| (a G "
            "proportional to I cannot be told from it) and its horizontal part is taken as "
            "noise of an unknown heading"
        )
    if data.latitude is None:
        return (
            "no latitude: the Earth rate is fitted as a free vector in the level frame (its "
            "part along gravity cannot be told from a G proportional to I)"
        )
    return (
        "the heading is not trusted: the Earth rate's horizontal part is fitted in the "
        "level frame, its vertical part is the latitude's"
    )


def _drift_tests(data: SessionData, temps: Array | None) -> dict[str, DriftTest]:
    rates = None
    if temps is not None:
        rates = np.array([_temp_rate(w.t_s, w.temp_c) for w in data.windows])
    out = {"accel": drift_test([(w.t_s, w.accel) for w in data.windows], rates)}
    if data.has_gyro and all(w.gyro is not None for w in data.windows):
        gyro = [(w.t_s, np.asarray(w.gyro)) for w in data.windows]
        out["gyro"] = drift_test(gyro, rates)
    return out


def _walk_like(drift: DriftTest, data: SessionData, sensor: str) -> bool:
    """Whether the slopes' random walk is one the Allan deviation of the same windows allows.

    The slope test sees any within-position trend; only one whose size ``q`` stays within
    :data:`~.drift.WALK_FACTOR` of the Allan deviation's 95 % random-walk bound
    (:func:`~.drift.allan_walk_upper`) is a wandering bias. Larger trends are motion or a
    settling the exponential does not describe, and are reported as such, not as drift.
    """
    bound = allan_walk_upper(_sensor_windows(data, sensor))
    return walk_consistent(drift, bound)


def _sensor_windows(data: SessionData, sensor: str) -> list[tuple[Array, Samples]]:
    if sensor == "accel":
        return [(w.t_s, w.accel) for w in data.windows]
    return [(w.t_s, np.asarray(w.gyro)) for w in data.windows if w.gyro is not None]


def _motion(data: SessionData, temps: Array | None, level: float) -> tuple[PositionMotion, ...]:
    """Return the positions that moved, when they alone carry the trends (:func:`moved_alone`)."""
    rates = None
    if temps is not None:
        rates = np.array([_temp_rate(w.t_s, w.temp_c) for w in data.windows])
    return moved_alone([(w.t_s, w.accel) for w in data.windows], level, rates)


def _drift_warnings(
    drifts: Mapping[str, DriftTest],
    drifting: set[str],
    data: SessionData,
    level: float,
    moved: tuple[PositionMotion, ...] = (),
) -> tuple[str, ...]:
    """Say what was trimmed, which positions moved, which trends were not taken for drift.

    ``level`` is each drift test's: the family's alpha over its size.
    """
    out = []
    for sensor, fit in data.settling.items():
        if fit.found:
            low, high = fit.tau_ci95_s
            out.append(
                f"{sensor}: settling after each move, time constant {fit.tau_s:.3g} s "
                f"(95 % {low:.3g}–{high:.3g} s); the first {np.min(fit.trim_s):.3g}–"
                f"{np.max(fit.trim_s):.3g} s of each position were trimmed"
            )
    out += [f"accel: {m.line()}; not named bias_drift" for m in moved]
    for sensor, d in drifts.items():
        if d.p_value < level and sensor not in drifting and not (sensor == "accel" and moved):
            out.append(
                f"{sensor}: trends inside the positions (slope χ² = {d.statistic:.1f} on {d.df} "
                "dof) exceed the random walk the Allan deviation allows: motion or settling, "
                "not named bias_drift"
            )
    return tuple(out)


def _temp_rate(t: Array, temp_c: Samples | None) -> float:
    if temp_c is None:
        return 0.0
    temp = np.asarray(temp_c, dtype=np.float64)  # a float32 window: converted before fitting
    keep = np.isfinite(temp)
    if keep.sum() < 2:
        return 0.0
    return float(np.polyfit(t[keep], temp[keep], 1)[0])


class _Whitened:
    """The linear problem and the whitening matrix used to build it."""

    def __init__(self, linear: LinearProblem, whiten: Array) -> None:
        self.linear, self.whiten = linear, whiten


def _scatter_model(
    prepared: PreparedBase,
    drifts: Mapping[str, DriftTest],
    drifting: set[str],
    data: SessionData,
) -> ScatterModel:
    """Build the noise family ``V(τ)`` of :mod:`.noise_model` (scalar fits: τ held at 0).

    With a given scatter (header, flag, plan) ``V`` is the base fit's covariance (the poses'
    tolerances, to second order) and τ is held; estimated, ``V(τ) = C + τ² A``. A scalar fit
    of a gyro of unknown scale estimates the horizontal Earth rate the same way, τ in counts
    (:mod:`.base_fit`).
    """
    extra = _walk_covariance(prepared, drifts, drifting, data)
    if prepared.earth_unit_covariance is not None:  # scalar fit, gyro of unknown scale
        base = prepared.covariance + extra
        unit = prepared.earth_unit_covariance
        blocks = block_labels(base, unit, prepared.block)
        gyro = prepared.sensor == "gyro"
        # counts: up to ten times the gyro rows' raw rms (misfit and noise together)
        top = 10.0 * float(np.sqrt(np.mean(prepared.residual[gyro] ** 2 + np.diag(base)[gyro])))
        return ScatterModel(base, unit, "estimated", blocks=blocks, tau_max=top)
    if prepared.within_covariance is None or prepared.angle_unit_covariance is None:
        return ScatterModel(prepared.covariance + extra, np.zeros_like(extra), "none", 0.0)
    if data.scatter_source == "estimated":
        base = prepared.within_covariance + extra
        unit = prepared.angle_unit_covariance
        blocks = block_labels(base, unit, prepared.block)
        return ScatterModel(base, unit, "estimated", blocks=blocks)
    return ScatterModel(
        prepared.covariance + extra, prepared.angle_unit_covariance, data.scatter_source, 0.0
    )


def _scatter_in(
    scatter: ScatterModel,
    prepared: PreparedBase,
    raw_columns: Mapping[str, Array],
    terms: Sequence[str],
) -> ScatterEstimate:
    """REML pose scatter in the model holding ``terms`` (or the one given, or none)."""
    if scatter.fixed is not None:
        tol = 0.0 if scatter.source == "none" else prepared.pose_tolerance
        return ScatterEstimate(tol, (tol, tol), scatter.source, float("nan"))
    design = np.hstack([prepared.jacobian] + [raw_columns[t] for t in terms])
    return estimate_scatter(scatter, prepared.residual, design)


def _walk_covariance(
    prepared: PreparedBase,
    drifts: Mapping[str, DriftTest],
    drifting: set[str],
    data: SessionData,
) -> Array:
    """Covariance a bias random walk adds to the position means (drift found only)."""
    cov = np.zeros_like(prepared.covariance)
    mids = np.array([float(np.mean(w.t_s)) for w in data.windows])
    secs = np.array([float(w.t_s[-1] - w.t_s[0]) for w in data.windows])
    for sensor in drifting:
        for axis, q in enumerate(drifts[sensor].random_walk):
            channel = axis + (0 if sensor == "accel" else 3)
            rows = np.flatnonzero(prepared.channels == channel)
            if prepared.method == "scalar" and sensor == "accel":
                continue  # the scalar residual mixes axes: its variance is the F test's job
            cov[np.ix_(rows, rows)] += random_walk_covariance(mids, secs, float(q))
    return cov


def _whitened(prepared: PreparedBase, scatter: ScatterModel | None, tau: float) -> _Whitened:
    """Whiten the base fit's linearisation by ``V(τ)`` (a held τ: the family's own)."""
    if scatter is None:
        cov = prepared.covariance
    else:
        cov = scatter.covariance(tau if scatter.fixed is None else scatter.fixed)
    chol = np.asarray(np.linalg.cholesky(0.5 * (cov + cov.T)), dtype=float)
    whiten = np.linalg.inv(chol)
    linear = LinearProblem(
        residual_w=whiten @ prepared.residual,
        base_w=whiten @ prepared.jacobian,
        block=prepared.block,
        unwhiten=chol,
        si_scale=prepared.si_scale,
        sensor=prepared.sensor,
        scatter=scatter if scatter is not None and scatter.fixed is None else None,
    )
    return _Whitened(linear, whiten)


def _final_tests(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    chosen: Sequence[str],
    use_f: bool,
    weights: Mapping[str, float],
    drifts: Mapping[str, DriftTest],
    drifting: set[str],
    prepared: PreparedBase,
    data: SessionData,
) -> list[TestRecord]:
    """Test each candidate beside the chosen terms; weighted Holm over the whole family.

    Candidates get the per-entry test (weight: their number of entries), each drift test
    and the axis-sign test weight 1, as in the selection.
    """
    raw: list[tuple[str, str, str, float, int, float, bool, int]] = []
    w: list[float] = []
    for key in columns:
        others = [c for c in chosen if c != key]
        t = entry_test(problem, columns, others, key, use_f=use_f)
        sensor, effect = key.split(".", 1)
        raw.append((effect, sensor, t.kind, t.statistic, t.df, t.p_value, key in chosen, t.entries))
        w.append(max(float(weights[key]), 1e-12))
    for sensor, d in drifts.items():
        raw.append(
            ("bias_drift", sensor, "slope χ²", d.statistic, d.df, d.p_value, sensor in drifting, 1)
        )
        w.append(1.0)
    if data.known_positions:
        z, p = _axis_sign(prepared, data)
        raw.append(("axis_sign", "accel", "sign z", z, 1, p, z > AXIS_SIGN_SIGMAS, 1))
        w.append(1.0)
    adjusted = holm_adjust([r[5] for r in raw], w)
    return [TestRecord(*r[:6], float(a), r[6], r[7]) for r, a in zip(raw, adjusted, strict=True)]


def _weights(prepared: PreparedBase, candidates: Sequence[Candidate]) -> dict[str, float]:
    """Each candidate's weight in the family: its entries the positions determine alone.

    Computed from the design alone (the base fit's whitening), before any test, as weighted
    Holm requires.
    """
    problem = _whitened(prepared, None, 0.0)
    columns = {c.key: problem.whiten @ c.columns for c in candidates}
    return {k: float(v) for k, v in entry_weights(problem.linear, columns).items()}


def _axis_sign(prepared: PreparedBase, data: SessionData) -> tuple[float, float]:
    """Largest z of a diagonal K against the nominal sign, and its p-value (3 axes)."""
    values, sigmas = named_values(prepared)
    sign = np.sign(data.accel_lsb)
    z = [-sign * values[f"accel.K[{i}][{i}]"] / sigmas[f"accel.K[{i}][{i}]"] for i in range(3)]
    zmax = float(np.max(z))
    from scipy import special  # lazy (issue 23); norm.sf(z) is ndtr(-z)

    return zmax, float(min(1.0, 3.0 * special.ndtr(-zmax)))


def _findings(
    tests: Sequence[TestRecord],
    fit: TermFit,
    by_key: Mapping[str, Candidate],
    drifts: Mapping[str, DriftTest],
    prepared: PreparedBase,
    data: SessionData,
    alpha: float,
) -> list[Finding]:
    units = {name: e.unit_in(scalar=not data.known_positions) for name, e in EFFECTS.items()}
    out = []
    for t in tests:
        key = f"{t.sensor}.{t.effect}"
        if t.effect == "bias_drift" and t.chosen and t.p_adjusted < alpha:
            q, q_sigma = drifts[t.sensor].random_walk, drifts[t.sensor].random_walk_sigma
            evidence = (
                f"within-position slopes χ² = {t.statistic:.1f} on {t.df} dof; random walk "
                f"q = {np.array2string(q, precision=3)} ± "
                f"{np.array2string(q_sigma, precision=2)} counts/√s"
            )
            top = int(np.argmax(q))
            out.append(Finding("bias_drift", t.sensor, float(q[top]), units["bias_drift"],
                               t.p_adjusted, evidence, float(q_sigma[top])))  # fmt: skip
        elif t.effect == "axis_sign" and t.chosen:
            values, _ = named_values(prepared)
            diag = [values[f"accel.K[{i}][{i}]"] for i in range(3)]
            axis = int(np.argmax(-np.sign(data.accel_lsb) * np.array(diag)))
            evidence = (
                f"K[{axis}][{axis}] = {diag[axis]:.4g}, {t.statistic:.0f}σ against the nominal sign"
            )
            out.append(Finding("axis_sign", "accel", float(diag[axis]), units["axis_sign"],
                               t.p_adjusted, evidence))  # fmt: skip
        elif t.chosen and key in fit.coefficients:
            out.append(_column_finding(t, fit, by_key[key], units))
    return out


def _on_residual_scale(fit: TermFit) -> TermFit:
    """Put the fit's σ on the residual scale its F tests use, ``χ²/dof`` of the extended fit.

    When trends inside the positions put the tests on F (``F = (Δχ²/q)/(χ²/ν)``,
    :mod:`.significance`), the noise level is the fit's own; a finding's σ then comes from
    the same noise model as its p-value.
    """
    if fit.dof <= 0:
        return fit
    scale = float(np.sqrt(fit.chi2 / fit.dof))
    return dataclasses.replace(fit, sigmas={k: v * scale for k, v in fit.sigmas.items()})


def _column_finding(
    t: TestRecord, fit: TermFit, cand: Candidate, units: Mapping[str, str]
) -> Finding:
    key = f"{t.sensor}.{t.effect}"
    coef, sig = fit.coefficients[key], fit.sigmas[key]
    z = np.abs(coef) / np.where(sig > 0, sig, np.inf)
    k = int(np.argmax(z))
    test = f"{t.kind} {t.statistic:.1f} on {t.df} dof"
    if t.entries > 1:
        test = f"largest entry's {test}, of {t.entries} entries tested"
    # the value and σ come from the extended fit, which holds every entry of the candidate;
    # an entry test holds one entry beside the other chosen terms, so the two can differ
    held = f" with all {coef.size} entries fitted" if coef.size > 1 else ""
    evidence = (
        f"{cand.labels[k]} = {coef[k]:.4g} ± {sig[k]:.2g} {units[t.effect]} ({z[k]:.1f}σ{held}); "
        + test
    )
    return Finding(t.effect, t.sensor, float(coef[k]), units[t.effect], t.p_adjusted, evidence)


def _scores(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    chosen: Sequence[str],
    held: Holdout,
    earth_rate: bool,
) -> dict[str, SensorScore]:
    """Score each sensor: the fit's rms, and cv_rms from :mod:`.holdout` (refits).

    ``earth_rate``: the gyro's base model holds the Earth rate (from the latitude, or fitted).

    A sensor the full data extends with nothing keeps its base model: ratio 1 and the
    interval (1, 1), though a fold may have chosen a term on its own data (that fold's
    selection is priced in the cv_rms of the sensors that were extended).
    """
    base = score_model(problem, columns, [])
    ext = score_model(problem, columns, chosen)
    gyro_base = ("bias", "earth_rate") if earth_rate else ("bias",)
    out = {}
    for sensor in base.rms:
        terms = tuple(c.split(".", 1)[1] for c in chosen if c.startswith(sensor + "."))
        base_terms = ("bias", "scale") if sensor == "accel" else gyro_base
        out[sensor] = SensorScore(
            base_terms,
            base_terms + terms,
            base.rms[sensor],
            held.base_cv_rms[sensor],
            ext.rms[sensor] if terms else base.rms[sensor],
            held.extended_cv_rms[sensor] if terms else held.base_cv_rms[sensor],
            held.ratio_ci95[sensor] if terms else (1.0, 1.0),
            held.claimed[sensor],
        )
    return out


def _selector(alpha: float, family: float, use_f: bool, weights: Mapping[str, float]) -> Selector:
    """Return the full data's term selection, for each fold of :func:`refit_holdout`."""

    def select(
        sub: LinearProblem, cols: Mapping[str, Array]
    ) -> tuple[list[str], Mapping[str, NDArray[np.bool_]]]:
        terms = forward_select(
            sub, cols, alpha=alpha, family_size=family, use_f=use_f, weights=weights
        )
        terms = confirm_by_cv(sub, cols, terms)
        return terms, significant_masks(sub, cols, terms)

    return select


def _refuted(chosen: Sequence[str], held: Holdout) -> list[str]:
    """Return the chosen terms of each sensor whose held-out error they make worse.

    A term passes its test on the data it was fitted to; the refit with each position left
    out (:mod:`.holdout`) asks whether the model holding it predicts positions it has not
    seen. When the 95 % interval of the base/extended held-out ratio lies wholly below 1,
    the extension predicts significantly worse than the base model, and its causes are not
    named (nor written to ``--truth-out``): the claim would not hold on unseen data. The
    interval is a bootstrap over positions, so this is a sensor-wide verdict on its terms.

    Only where the sensor keeps fewer than :data:`MIN_GAIN_DOF` residual dof, where the
    report already warns that the in-sample p-values cannot be trusted. With more, the
    in-sample test stands: leaving out one of few positions makes a term extrapolate (the
    coldest position of a warm-up for ``temperature_bias``), and on the recommended plan a
    real 9σ temperature term predicted the left-out positions worse (95 % 0.30–0.97, 15 dof).
    """
    bad = {
        s for s, (_, high) in held.ratio_ci95.items() if high < 1.0 and held.dof[s] < MIN_GAIN_DOF
    }
    return [c for c in chosen if c.split(".", 1)[0] in bad]


def _warnings(chosen: Sequence[str], held: Holdout, refuted: Sequence[str]) -> tuple[str, ...]:
    out = []
    for sensor in sorted({c.split(".", 1)[0] for c in refuted}):
        terms = ", ".join(c.split(".", 1)[1] for c in refuted if c.startswith(sensor + "."))
        low, high = held.ratio_ci95[sensor]
        out.append(
            f"{sensor}: {terms} passed the in-sample test but is not named: held out, the "
            f"model holding it predicts worse (cv_rms {held.base_cv_rms[sensor]:.4g} → "
            f"{held.extended_cv_rms[sensor]:.4g}, ratio 95 % {low:.2f}–{high:.2f})"
        )
    for sensor, dof in held.dof.items():
        if dof < MIN_GAIN_DOF:
            out.append(
                f"{sensor}: only {dof} residual degrees of freedom: too few to claim a gain "
                "or to trust the tests' p-values; add positions"
            )
    for sensor, claimed in held.claimed.items():
        if any(t.startswith(sensor + ".") for t in chosen) and not claimed:
            low, high = held.ratio_ci95[sensor]
            out.append(
                f"{sensor}: no gain claimed (held-out cv_rms ratio 95 % {low:.2f}–{high:.2f}, "
                f"{held.dof[sensor]} residual dof)"
            )
    return tuple(out)


def _extended(
    prepared: PreparedBase,
    fit: TermFit,
    drifts: Mapping[str, DriftTest],
    drifting: set[str],
    data: SessionData,
) -> ExtendedParams:
    values = prepared.values + fit.base_delta
    coef = dict(fit.coefficients)
    zero3 = np.zeros(3)
    bias = values[:3]
    if prepared.method == "joint":
        k = np.diag(values[3:6])
        gyro_bias = values[6:9] if data.has_gyro else None
        if "accel.cross_axis" in coef:
            for (i, j), v in zip(_OFF, coef["accel.cross_axis"], strict=True):
                k[i, j] = v
    else:
        # the scalar fit reports diagonal K; its Jacobian is in M = K⁻¹ (diagonal at the base)
        m_diag = np.diag(1.0 / prepared.values[3:6] + fit.base_delta[3:6])
        m = _lower_m(m_diag, coef) if "accel.cross_axis" in coef else m_diag
        k = np.asarray(np.linalg.inv(m), dtype=float)
        gyro_bias = values[6:9] if data.has_gyro else None
    tilt = coef.get("accel.base_tilt", np.zeros(2))
    generic = {k: v for k, v in coef.items() if EFFECTS[k.split(".", 1)[1]].generic_truth}
    walk = {s: (drifts[s].random_walk if s in drifting else zero3) for s in ("accel", "gyro")}
    return ExtendedParams(
        accel_bias=bias,
        K=k,
        alpha0=float(tilt[0]),
        beta0=float(tilt[1]),
        quadratic=coef.get("accel.scale_nonlinearity", zero3),
        accel_temp_coeff=coef.get("accel.temperature_bias", zero3),
        accel_random_walk=walk["accel"],
        gyro_bias=gyro_bias,
        G=coef.get("gyro.gyro_g_sensitivity", np.zeros(9)).reshape(3, 3),
        gyro_temp_coeff=coef.get("gyro.temperature_bias", zero3),
        gyro_random_walk=walk["gyro"] if "gyro" in drifts else zero3,
        effects=generic,
        trials=data.trials,
        trial_accel_bias=trial_biases(prepared.names, values, data.trials, "accel"),
        trial_gyro_bias=trial_biases(prepared.names, values, data.trials, "gyro"),
    )


_OFF = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


def _lower_m(m: Array, coef: Mapping[str, Array]) -> Array:
    out = m.copy()
    for (i, j), v in zip(((1, 0), (2, 0), (2, 1)), coef["accel.cross_axis"], strict=True):
        out[i, j] = v
    return out


def effect_sigmas(data: SessionData) -> dict[str, Array]:
    """σ of each candidate entry fitted beside the base model and every other candidate.

    The size scale of hidden-effect tests (docs/design.md §5: 5σ–10σ of the effect's own estimate
    under the plan and noise of ``data``); only the design and the noise enter, not the
    residuals. Entries that the positions cannot determine are infinite.
    """
    prepared = fit_known(data)[0] if data.known_positions else fit_scalar_base(data)[0]
    problem = _whitened(prepared, None, 0.0)
    all_cols = {c.key: problem.whiten @ c.columns for c in prepared.candidates}
    out = {}
    for cand in prepared.candidates:
        others = [k for k in all_cols if k != cand.key]
        sig = np.full(all_cols[cand.key].shape[1], np.inf)
        for k in range(sig.size):
            cols = {**all_cols, cand.key: all_cols[cand.key][:, k : k + 1]}
            stacked = np.hstack([cols[o] for o in others])
            gained = effective_rank(problem.linear, np.hstack([stacked, cols[cand.key]]))
            if gained - effective_rank(problem.linear, stacked) == 1:
                fit = fit_terms(problem.linear, cols, [*others, cand.key])
                sig[k] = float(fit.sigmas[cand.key][0])
        out[cand.key] = sig
    return out
