"""The departures suite's frame: departures from the simulator's clean shape, and cases.

A **departure** is what a real sensor or a real log does that a clean simulated session does
not: a function that edits the simulator's truth document (a tilted base, a cross-axis term,
a quadratic, a random walk) and, where the departure lives in the log rather than the unit,
a function that edits the recording (samples logged faster than the sensor takes them, a
sensor's columns left empty). A **case** is where it is tried: a plan, how exactly its poses
are set (``tolerance_deg``: 0 exact, else the 1σ of the angle each pose really gets), the
fixed seeds, and the causes ``analyze`` may name (the departure's own effect, or nothing).

Three ways to simulate a case, the cheapest that still tests the path in question:

- :func:`offline_averages`: position means drawn straight from the sensor model
  (:mod:`canimucal.sim.averages`), for ``solve``'s σ (:func:`solve_errors`);
- :func:`session`: position by position from the sample-level simulator, without a
  recording (:func:`tests.support.sessions.simulate_session`), for ``analyze``'s causes;
- :func:`recording`: a whole labelled recording (the departures that live in the log).

Truths are clean units (biases ±50 counts, scale errors ±3 %, no cross-axis, a level base,
a constant temperature, default noise) unless the departure says otherwise; the five-position
plan solves bias, diagonal K and the rigid base tilt, the others bias, full K and the tilt
(docs/design.md §3). Seeds are listed by each test; the departure's own draw uses
``seed + DRAW_OFFSET`` so the unit and the noise of a seed do not change with the departure.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cache
from typing import Any

import numpy as np

from canimucal.analysis.calibrate import SiteConditions
from canimucal.analysis.data import SessionData
from canimucal.analysis.discrepancy import analyse_discrepancy, effect_sigmas
from canimucal.analysis.session import session_from_recording
from canimucal.analysis.session_model import ModelChoice
from canimucal.analysis.simulated import (
    TrialsTruth,
    simulate_plan_recording,
    simulate_trials_recording,
)
from canimucal.analysis.solve import solve_estimating_scatter, solve_recording
from canimucal.io.calibration import Device
from canimucal.io.recording import Recording, recording_from_columns
from canimucal.model.joint import JointResult
from canimucal.model.layout import JointSpec
from canimucal.model.positions import Plan, PlannedPosition, PositionAverage
from canimucal.model.vocabulary.constants import COUNTER_MODULUS
from canimucal.model.vocabulary.effects import OFF_DIAGONAL
from canimucal.model.vocabulary.plans import FIVE, RECOMMENDED
from canimucal.sim.averages import simulate_averages
from canimucal.sim.effects import hide_effect, slope_random_walk
from canimucal.sim.truth import Truth
from tests.support.chi2_band import chi2_ratio_band
from tests.support.plans import TWELVE_DEG
from tests.support.sessions import simulate_session

Doc = dict[str, Any]
DRAW_OFFSET = 50_000
"""The departure's own random draw (its size, axis, entry) uses ``seed + DRAW_OFFSET``."""
SPREAD_BAND = (0.8, 1.25)
"""Where the rms of (estimate − truth)/σ over a case's seeds must lie (issue 21)."""
REFERENCE_SEED = 999
"""The clean session that sizes effects given in σ of their own estimate."""


@dataclass(frozen=True)
class Departure:
    """One way the data leave the clean simulated shape (module doc).

    ``truth`` edits a truth document (a copy: it may change it in place and return it);
    ``log`` edits a recording (None: the departure lives in the unit only). ``causes`` are
    what ``analyze`` may name for it (empty: nothing). ``solvable`` names the plans on which
    ``solve``'s model holds the departure, so that its σ can be judged against the truth.
    """

    name: str
    truth: Callable[[Doc, np.random.Generator, str], Doc] = lambda doc, _rng, _plan: doc
    log: Callable[[Recording, np.random.Generator], Recording] | None = None
    causes: frozenset[str] = frozenset()
    solvable: frozenset[str] = frozenset({"five", "recommended", "twelve"})


@dataclass(frozen=True)
class Case:
    """A departure tried on one plan with poses set to ``tolerance_deg`` (1σ; 0 exact)."""

    departure: Departure
    plan: str
    tolerance_deg: float
    seeds: tuple[int, ...] = field(default=tuple(range(20)))

    @property
    def label(self) -> str:
        """``departure/plan/poses`` for test ids and printed tables."""
        poses = "exact" if self.tolerance_deg == 0 else f"{self.tolerance_deg:g}deg"
        return f"{self.departure.name}/{self.plan}/{poses}"


PLANS = ("five", "recommended")
POSES_DEG = (0.0, 0.1)


def grid(departure: Departure, seeds: Sequence[int] = tuple(range(20))) -> list[Case]:
    """The four cases of the suite: five and recommended plans, exact and 0.1° poses."""
    return [Case(departure, p, t, tuple(seeds)) for p in PLANS for t in POSES_DEG]


# ------------------------------------------------------------------------------ plans, units


SIX_FACES_DEG = ((0, 0, 0), (180, 0, 0), (90, 0, 0), (-90, 0, 0), (0, 90, 0), (0, -90, 0))
"""The classic six-position plan (each axis up and down, degrees): the issue's real trials."""


def plan_of(name: str, tolerance_deg: float) -> Plan:
    """The built-in plan (or ``twelve``, ``six``) with every angle set to ``tolerance_deg`` (1σ)."""
    tol = float(np.deg2rad(tolerance_deg))
    if name == "six":
        degrees = np.deg2rad(np.array(SIX_FACES_DEG, dtype=float))
        poses = tuple(PlannedPosition(*map(float, d), tolerance=tol, seconds=30.0) for d in degrees)
        return Plan("six", poses)
    if name == "twelve":
        degrees = np.deg2rad(np.array(TWELVE_DEG, dtype=float))
        poses = tuple(PlannedPosition(*map(float, d), tolerance=tol, seconds=30.0) for d in degrees)
        return Plan("twelve", poses)
    base = {"five": FIVE, "recommended": RECOMMENDED}[name]
    return Plan(
        base.name,
        tuple(PlannedPosition(p.alpha, p.beta, p.psi, tol, p.seconds) for p in base.positions),
    )


def solve_spec(plan: str) -> JointSpec:
    """What ``solve`` fits on ``plan``: five, bias + diagonal K + tilt; else full K + tilt."""
    return JointSpec(accel_k="diag" if plan == "five" else "full", tilt="rigid", gyro="none")


def clean_truth(seed: int) -> Doc:
    """A clean random unit on a level base at a constant temperature (module doc)."""
    return Truth.random(np.random.default_rng(seed), cross_axis_max=0.0, tilt_max_deg=0.0).to_dict()


def case_truth(case: Case, seed: int) -> Truth:
    """The unit of ``case`` on ``seed``: the clean truth with the departure applied."""
    rng = np.random.default_rng(seed + DRAW_OFFSET)
    return Truth.from_dict(case.departure.truth(clean_truth(seed), rng, case.plan))


# ------------------------------------------------------------------------- three simulations


def session(case: Case, seed: int) -> SessionData:
    """The case as ``analyze`` sees it: sample-level positions, the scatter estimated."""
    plan = plan_of(case.plan, case.tolerance_deg)
    return simulate_session(case_truth(case, seed), plan, seed=seed, estimate_scatter=True)


def recording(case: Case, seed: int) -> Recording:
    """The case as a whole recording, the departure's ``log`` edit applied (no header tolerance)."""
    truth = case_truth(case, seed)
    rec = simulate_plan_recording(
        truth, plan_of(case.plan, case.tolerance_deg), seed=seed,
        angle_errors=case.tolerance_deg > 0,
    )  # fmt: skip
    if case.departure.log is not None:
        rec = case.departure.log(rec, np.random.default_rng(seed + DRAW_OFFSET))
    return rec


def offline_averages(case: Case, seed: int) -> tuple[Truth, list[PositionAverage]]:
    """Position means of the case drawn from the sensor model, labelled without a tolerance.

    The white density is the truth's, output-referred, with the rounding to counts folded
    in (``step²/12`` a sample); the base tilt and K are the truth's. Quadratic and other
    registered effects are not drawn: this path serves departures of bias, K and tilt.
    """
    truth = case_truth(case, seed)
    plan = plan_of(case.plan, case.tolerance_deg)
    acc = truth.accel
    fs = float(truth.sample_rate_hz)
    density = np.sqrt(
        (np.asarray(acc.noise_density) * np.abs(np.diag(acc.K))) ** 2
        + acc.quantization**2 / (12.0 * fs)
    )
    averages = simulate_averages(
        plan.positions, acc.params(), np.random.default_rng(seed), g=truth.g,
        alpha0=truth.alpha0, beta0=truth.beta0, accel_noise_density=density,
        sample_rate_hz=fs, angle_errors=case.tolerance_deg > 0,
    )  # fmt: skip
    return truth, [replace(a, pose=replace(a.pose, tolerance=0.0)) for a in averages]


# ---------------------------------------------------------------------- what is judged


def solve_errors(case: Case, seed: int) -> dict[str, float]:
    """(estimate − truth)/σ of every accelerometer parameter and tilt ``solve`` determined.

    The offline means are solved as ``solve`` solves a recording without ``tolerance_deg``
    (:func:`~canimucal.analysis.solve.solve_estimating_scatter`).
    """
    truth, averages = offline_averages(case, seed)
    site = SiteConditions(
        g=truth.g, latitude=truth.latitude, heading=truth.heading,
        accel_lsb=truth.accel.nominal_lsb, gyro_lsb=truth.gyro.nominal_lsb,
    )  # fmt: skip
    solution, _ = solve_estimating_scatter(averages, solve_spec(case.plan), site, Device(serial=0))
    joint = solution.joint
    assert joint is not None
    return z_scores(joint, true_values(truth))


def z_scores(joint: JointResult, true: Mapping[str, float]) -> dict[str, float]:
    """(estimate − truth)/σ of every determined parameter of ``joint`` that ``true`` holds."""
    sigma = np.sqrt(np.diag(joint.covariance))
    return {
        n: float((joint.values[k] - true[n]) / sigma[k])
        for k, n in enumerate(joint.names)
        if n not in joint.undetermined and n in true
    }


def true_values(truth: Truth) -> dict[str, float]:
    """The truth of every accelerometer parameter and the tilt, by the solver's names."""
    out = {f"accel.bias[{i}]": float(truth.accel.bias[i]) for i in range(3)}
    out |= {f"accel.K[{i}][{j}]": float(truth.accel.K[i][j]) for i in range(3) for j in range(3)}
    return out | {"base_tilt.alpha0": truth.alpha0, "base_tilt.beta0": truth.beta0}


@dataclass(frozen=True)
class Spread:
    """The z of one case over its seeds: their rms and each parameter's Σz²/n.

    ``seeds`` the fewest seeds any parameter's Σz²/n rests on (the χ² band's dof).
    """

    rms: float
    per_parameter: Mapping[str, float]
    largest: float
    seeds: int

    def within(self, comparisons: int = 1) -> list[str]:
        """What is out of bounds: the rms outside :data:`SPREAD_BAND`, or a parameter's
        Σz²/n outside its χ² band (family-wise 1e-3 over its parameters and ``comparisons``
        cases: ``tests/support/chi2_band.py``). Empty when the σ say what they mean."""
        out = []
        if not SPREAD_BAND[0] <= self.rms <= SPREAD_BAND[1]:
            out.append(f"rms z {self.rms:.3f} outside {SPREAD_BAND}")
        low, high = chi2_ratio_band(self.seeds, len(self.per_parameter) * comparisons)
        out += [
            f"{n}: Σz²/n {v:.3f} outside {low:.3f}–{high:.3f}"
            for n, v in self.per_parameter.items()
            if not low <= v <= high
        ]
        return out


def spread(case: Case) -> Spread:
    """:func:`solve_errors` over the case's seeds."""
    return pooled_spread([(case, s) for s in case.seeds])


def rotation(departure: Departure, seeds: Sequence[int]) -> list[tuple[Case, int]]:
    """Seeds dealt round the four cases of :func:`grid` (seed k to case k mod 4).

    Where twenty seeds of every case cost too much for the suite, twenty seeds in all still
    try the departure on every plan and pose setting; ``benchmarks/departures.py`` runs each
    case on forty.
    """
    cases = [c for c in grid(departure, ()) if c.plan in departure.solvable] or grid(departure, ())
    return [(cases[k % len(cases)], int(seed)) for k, seed in enumerate(seeds)]


def rotation_all(departure: Departure, seeds: Sequence[int]) -> list[tuple[Case, int]]:
    """Seeds dealt round all four cases of :func:`grid`, whether ``solve`` holds it or not."""
    cases = grid(departure, ())
    return [(cases[k % len(cases)], int(seed)) for k, seed in enumerate(seeds)]


def pooled_spread(pairs: Sequence[tuple[Case, int]]) -> Spread:
    """:func:`solve_errors` over ``(case, seed)`` pairs, each parameter pooled by its name."""
    return spread_of([solve_errors(case, seed) for case, seed in pairs])


def named(case: Case, seed: int) -> tuple[frozenset[str], bool]:
    """What ``analyze``'s loop names on the case's session, and whether a pair was ambiguous."""
    result = analyse_discrepancy(session(case, seed))
    return frozenset(f.effect for f in result.findings), bool(result.ambiguous)


def wrong_causes(case: Case) -> dict[int, frozenset[str]]:
    """Seeds on which a cause outside the departure's own is named, and what was named."""
    out = {}
    for seed in case.seeds:
        causes, _ambiguous = named(case, seed)
        if causes - case.departure.causes:
            out[seed] = causes
    return out


# ----------------------------------------------------------------------- large effects


def tilted_base(doc: Doc, rng: np.random.Generator, _plan: str) -> Doc:
    """A base tilted 1–3° about alpha0, beta0 or both (the choice drawn too)."""
    size = rng.uniform(1.0, 3.0) * rng.choice([-1.0, 1.0])
    a, b = [(size, 0.0), (0.0, size), (size / np.sqrt(2), size / np.sqrt(2))][rng.integers(3)]
    doc["base_tilt_deg"] = {"alpha0": float(a), "beta0": float(b)}
    return doc


def cross_axis(doc: Doc, rng: np.random.Generator, _plan: str) -> Doc:
    """One off-diagonal entry of K at 1–2 % of its row's scale, either sign."""
    k = doc["accel"]["K"]
    i, j = OFF_DIAGONAL[int(rng.integers(len(OFF_DIAGONAL)))]
    k[i][j] += float(rng.choice([-1.0, 1.0]) * rng.uniform(0.01, 0.02) * k[i][i])
    return doc


def quadratic(doc: Doc, rng: np.random.Generator, plan: str) -> Doc:
    """A quadratic scale term on one axis at 10–20σ of its own estimate under ``plan``."""
    out, _hidden = hide_effect(doc, "scale_nonlinearity", rng, effect_scale(plan), low=10, high=20)
    return out


@cache
def effect_scale(plan: str) -> dict[str, Any]:
    """σ of every candidate entry under ``plan`` at 0.1° poses, that scatter in the noise.

    The sizes' yardstick: the reference session's poses carry their 0.1° (not estimated), so
    the σ are those a 0.1° session has, not the noise-only ones of exact poses.
    """
    truth = Truth.from_dict(clean_truth(REFERENCE_SEED))
    reference = simulate_session(truth, plan_of(plan, 0.1), seed=REFERENCE_SEED)
    return effect_sigmas(reference)


TILTED_BASE = Departure("tilted_base", tilted_base, causes=frozenset({"base_tilt"}))
CROSS_AXIS = Departure(
    "cross_axis", cross_axis, causes=frozenset({"cross_axis"}),
    solvable=frozenset({"recommended", "twelve"}),  # the five plan's diagonal K cannot hold it
)  # fmt: skip
QUADRATIC = Departure(
    "quadratic", quadratic, causes=frozenset({"scale_nonlinearity"}), solvable=frozenset()
)


# -------------------------------------------------------------------------- bias random walk


def bias_walk(sensor: str, k_sigma: tuple[float, float] = (5.0, 8.0)) -> Departure:
    """A bias random walk on one axis of ``sensor``, sized by the slopes it causes.

    ``k_sigma``: its within-position slopes' rms is drawn within this many white-noise
    standard errors of a slope (:func:`canimucal.sim.effects.slope_random_walk`, 30 s
    positions at the truth's rate).
    """

    def edit(doc: Doc, rng: np.random.Generator, _plan: str) -> Doc:
        truth = Truth.from_dict(doc)
        block = getattr(truth, sensor)
        axis = int(rng.integers(3))
        scale = np.abs(np.diag(block.K if sensor == "accel" else block.S))
        white = float(np.asarray(block.noise_density)[axis] * scale[axis])
        fs = float(truth.sample_rate_hz)
        white = float(np.sqrt(white**2 * fs + block.quantization**2 / 12.0))  # per sample
        q = slope_random_walk(float(rng.uniform(*k_sigma)), white, fs, 30.0)
        doc[sensor]["random_walk"] = [q if i == axis else 0.0 for i in range(3)]
        return doc

    return Departure(f"{sensor}_walk", edit, causes=frozenset({"bias_drift"}))


def walk_of(truth: Truth, sensor: str) -> tuple[int, float]:
    """The axis and q (counts/√s) of the walk :func:`bias_walk` put on ``sensor``."""
    walk = np.asarray(getattr(truth, sensor).random_walk, dtype=float)
    axis = int(np.argmax(walk))
    return axis, float(walk[axis])


def recording_session(case: Case, seed: int) -> SessionData:
    """The case's recording grouped as ``analyze`` groups it (settling fitted and trimmed)."""
    truth = case_truth(case, seed)
    return session_from_recording(
        recording(case, seed), g=truth.g, latitude=truth.latitude, heading=truth.heading
    )


# ------------------------------------------------------------------- departures of the log


def held(times: int) -> Callable[[Recording, np.random.Generator], Recording]:
    """A logger polling ``times`` faster than the sensor samples, each sample held until the
    next: the rows between two samples repeat the last one while ``t`` and the counter run."""

    def edit(rec: Recording, _rng: np.random.Generator) -> Recording:
        def rep(x: np.ndarray) -> np.ndarray:
            return np.repeat(x, times, axis=0)

        rate = rec.sample_rate_hz * times
        n = rec.n_rows * times
        return recording_from_columns(
            {**rec.header, "sample_rate_hz": rate}, t=rec.t[0] + np.arange(n) / rate,
            accel=rep(rec.accel), gyro=rep(rec.gyro), counter=np.arange(n) % COUNTER_MODULUS,
            position=rep(rec.position), alpha_deg=rep(rec.alpha_deg), beta_deg=rep(rec.beta_deg),
            psi_deg=rep(rec.psi_deg), temp_c=rep(rec.temp_c),
        )  # fmt: skip

    return edit


def without(sensor: str) -> Callable[[Recording, np.random.Generator], Recording]:
    """The recording with ``sensor``'s three columns left empty (a file of the other only)."""

    def edit(rec: Recording, _rng: np.random.Generator) -> Recording:
        return recording_from_columns(
            rec.header, t=rec.t, counter=rec.counter, position=rec.position,
            alpha_deg=rec.alpha_deg, beta_deg=rec.beta_deg, psi_deg=rec.psi_deg,
            temp_c=rec.temp_c, accel=None if sensor == "accel" else rec.accel,
            gyro=None if sensor == "gyro" else rec.gyro,
        )  # fmt: skip

    return edit


REPEATED = Departure("repeated_samples", log=held(4))
ACCEL_ONLY = Departure("accel_only", log=without("gyro"))
GYRO_ONLY = Departure("gyro_only", log=without("accel"))
SHORT_POSITIONS_S = 10.0
"""Seconds a position of the recording-level cases (their σ do not depend on it)."""
SHORT_RATE_HZ = 100.0
"""The simulated sensor's rate in the recording-level cases."""


def short_recording(case: Case, seed: int) -> Recording:
    """The case's recording at :data:`SHORT_POSITIONS_S` a position and the sensor at
    :data:`SHORT_RATE_HZ`, the departure's log edit applied (recording-level cases)."""
    truth = case_truth(case, seed)
    plan = plan_of(case.plan, case.tolerance_deg)
    plan = plan.with_total_seconds(SHORT_POSITIONS_S * len(plan.positions))
    rec = simulate_plan_recording(
        truth, plan, seed=seed, angle_errors=case.tolerance_deg > 0,
        sample_rate_hz=SHORT_RATE_HZ,
    )  # fmt: skip
    if case.departure.log is not None:
        rec = case.departure.log(rec, np.random.default_rng(seed + DRAW_OFFSET))
    return rec


def recording_errors(case: Case, seed: int) -> dict[str, float]:
    """(estimate − truth)/σ of what ``solve`` determines from the case's short recording.

    ``solve``'s own path (:func:`~canimucal.analysis.solve.solve_recording`), the plan's
    model (:func:`solve_spec`), no tolerance in the header: the scatter estimated.
    """
    truth = case_truth(case, seed)
    spec = solve_spec(case.plan)
    choice = ModelChoice(model=spec.accel_k, tilt=True)  # type: ignore[arg-type]
    joint = solve_recording(short_recording(case, seed), choice).solution.joint
    assert joint is not None
    return z_scores(joint, true_values(truth))


def spread_of(rows: Sequence[Mapping[str, float]]) -> Spread:
    """The :class:`Spread` of z rows (one mapping per seed), each parameter by its name."""
    names = sorted(set().union(*rows))
    per = {n: float(np.mean([r[n] ** 2 for r in rows if n in r])) for n in names}
    z = np.concatenate([list(r.values()) for r in rows])
    seeds = min(sum(n in r for r in rows) for n in names)
    return Spread(float(np.sqrt(np.mean(z**2))), per, float(np.max(np.abs(z))), seeds)


# ---------------------------------------------------------------------------- long positions


def quieter(factor: float) -> Callable[[Doc, np.random.Generator, str], Doc]:
    """The unit's white noise ``factor`` times lower: each mean as precise as a position
    ``factor²`` times longer (a long position's averaging, at a short position's cost)."""

    def edit(doc: Doc, _rng: np.random.Generator, _plan: str) -> Doc:
        for sensor in ("accel", "gyro"):
            doc[sensor]["noise_density"] = (
                np.asarray(doc[sensor]["noise_density"]) / factor
            ).tolist()
        return doc

    return edit


LONG_POSITIONS = Departure("long_positions", quieter(4.0))
"""Means as precise as 480 s positions at the default noise (30 s each, noise ÷ 4)."""


# ---------------------------------------------------------------- re-mounted trials in one file

TRIALS = 4
"""Trials of one unit in one recording (the issue's real file had four)."""
REMOUNTED = Departure("remounted_trials")
"""A unit re-mounted between trials: each trial's biases moved (±20 counts accelerometer,
±5 gyro), K, S and G shared (:func:`canimucal.analysis.simulated.remounted`)."""


def trials_recording(
    case: Case, seed: int, *, label: bool = True, gap_s: float = 0.0
) -> tuple[Recording, TrialsTruth]:
    """:data:`TRIALS` re-mounted trials of the case's unit and plan in one short recording.

    10 s a position, the sensor at 100 Hz (:func:`short_recording`'s); ``label``: the file
    has the ``trial`` column, else only its repeated label sequence (and ``gap_s`` pauses)
    tell the trials apart.
    """
    truth = case_truth(case, seed)
    plan = plan_of(case.plan, case.tolerance_deg)
    plan = plan.with_total_seconds(SHORT_POSITIONS_S * len(plan.positions))
    return simulate_trials_recording(
        truth, plan, TRIALS, seed=seed, angle_errors=case.tolerance_deg > 0,
        sample_rate_hz=SHORT_RATE_HZ, label_trials=label, gap_s=gap_s,
    )  # fmt: skip


def trials_errors(case: Case, seed: int) -> tuple[dict[str, float], float]:
    """(estimate − truth)/σ of K, the tilt and every trial's accelerometer biases from
    ``solve`` of the case's trials recording (no tolerance header: the scatter estimated),
    and the pose scatter (degrees) the σ rested on."""
    rec, units = trials_recording(case, seed)
    spec = solve_spec(case.plan)
    choice = ModelChoice(model=spec.accel_k, tilt=True)  # type: ignore[arg-type]
    solved = solve_recording(rec, choice)
    joint = solved.solution.joint
    assert joint is not None and joint.trial_bias is not None and joint.trial_bias_cov is not None
    true = {n: v for n, v in true_values(units.trials[0]).items() if "bias" not in n}
    out = z_scores(joint, true)
    bias_sigma = np.sqrt(np.diagonal(joint.trial_bias_cov, axis1=1, axis2=2))[:, :3]
    for t, trial in enumerate(joint.trials):
        for i in range(3):
            z = (joint.trial_bias[t, i] - units.accel_bias[trial, i]) / bias_sigma[t, i]
            out[f"trial[{trial}].accel.bias[{i}]"] = float(z)
    fit = solved.record.fit
    assert fit is not None and fit.pose_scatter_deg is not None
    return out, float(fit.pose_scatter_deg)
