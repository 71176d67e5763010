"""Solving a recording: the library function behind ``canimucal solve`` and ``cm.calibrate``.

One place decides how a recording becomes positions: its labels, else the static intervals
the detector finds (:func:`canimucal.io.grouping.position_rows`). Positions with known angles
go to the joint least squares (:func:`~canimucal.analysis.calibrate.solve_positions`), others
to the scalar ``|f| = g`` fit. With ``--gyro moves`` the moves give the gyro's S: between
positions of known angles (:mod:`~canimucal.analysis.gyro_moves`), or, without angles
(imu_tk), between static intervals matched on gravity
(:mod:`~canimucal.analysis.gravity_moves`). The acceptance limits are checked and their
verdict travels in the record (never an exception: a failed check is a result).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from canimucal.analysis.acceptance import AcceptanceLimits, Limits, Verdict, judge, limits_for
from canimucal.analysis.calibrate import (
    SiteConditions,
    Solution,
    solve_positions,
    solve_scalar,
    trials_line,
)
from canimucal.analysis.conditions import recording_conditions
from canimucal.analysis.gravity_moves import solve_gravity_moves_recording
from canimucal.analysis.gyro_moves import solve_gyro_moves
from canimucal.analysis.gyro_only import has_accel, solve_gyro_only
from canimucal.analysis.motion import moved_alone
from canimucal.analysis.pose_scatter import PoseScatter, fit_scatter
from canimucal.analysis.repeats import unique_samples
from canimucal.analysis.session_model import (
    GyroChoice,
    ModelChoice,
    ModelName,
    TiltModel,
    session_model,
)
from canimucal.errors import InputError, ModelError
from canimucal.io.calibration import Calibration, Device, Fit, RecordingRef
from canimucal.io.grouping import (
    Rows,
    average_rows,
    detect_trials,
    has_angles,
    interval_trials,
    position_averages,
    position_labels,
    position_parts,
    position_rows,
    trial_label_rows,
)
from canimucal.io.recording import Recording
from canimucal.model.layout import JointSpec
from canimucal.model.moves import PositionKey
from canimucal.model.positions import PositionAverage
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, STANDARD_GRAVITY


@dataclass(frozen=True)
class RecordingSolution:
    """A solved recording: the solution, where its g came from, the acceptance verdict."""

    solution: Solution
    g_source: str
    verdict: Verdict | None = None
    notes: tuple[str, ...] = ()
    """How the noise model was chosen (e.g. the pose scatter estimated from the data)."""

    @property
    def record(self) -> Calibration:
        """The calibration record (with its acceptance verdict when the fit is joint)."""
        return self.solution.record


def site_of(rec: Recording, choice: ModelChoice) -> tuple[SiteConditions, str]:
    """Return the site conditions of ``rec`` (header, ``choice`` overrides) and g's source."""
    cond = recording_conditions(rec, choice.g)
    latitude = cond.latitude_rad
    if choice.latitude_deg is not None:
        latitude = float(np.deg2rad(choice.latitude_deg))
    t = np.asarray(rec.temp_c[np.isfinite(rec.temp_c)], dtype=np.float64)
    site = SiteConditions(
        g=cond.g,
        latitude=latitude,
        heading=cond.heading_rad,
        height_m=cond.height_m,
        accel_lsb=cond.accel_lsb,
        gyro_lsb=cond.gyro_lsb,
        temp_c=float(t.mean()) if t.size else None,
    )
    return site, cond.g_source


def solve_recording(
    rec: Recording,
    choice: ModelChoice | None = None,
    *,
    recording: RecordingRef | None = None,
    limits: Limits | None = None,
) -> RecordingSolution:
    """Solve ``rec`` for the calibration ``choice`` asks for (module doc).

    Options ``choice`` leaves unset come from the recording's header (the session's own
    model, tolerance and plan prior). ``limits``: the acceptance limits, or a config that
    picks them for the session's plan; None, the built-in limits.
    """
    rec, held = unique_samples(rec)
    choice, session = session_model(rec, choice or ModelChoice())
    notes: tuple[str, ...] = () if held is None else (held.line(),)
    if bool((rec.position >= 0).any()):  # several trials in one file, no trial column
        rec, found = detect_trials(rec)
        notes += () if found is None else (found,)
    site, g_source = site_of(rec, choice)
    serial, node_id = _header_int(rec, "device_serial"), _header_int(rec, "node_id")
    device = Device(serial=serial or 0, node_id=node_id)
    moved: tuple[str, ...] = ()  # labelled positions whose unit moved (accel and angles only)
    if not has_accel(rec):  # gyro only: its bias (and S from the Earth rate), nothing else
        solution = solve_gyro_only(
            rec, site, device, gyro=choice.gyro, plan_name=session.plan_name, recording=recording
        )
    elif has_angles(rec):
        averages = [
            a
            for trial in by_trial(position_averages(rec, tolerance_deg=session.tolerance_deg))
            for a in session.tolerances(trial)
        ]
        spec = choice.spec(has_gyro=all(a.mean_gyro is not None for a in averages))
        spec = session.with_trim(spec, by_trial(averages)[0])  # the vehicle plan's trim
        context = SolveContext(
            recording=recording,
            plan_name=session.plan_name,
            prior=session.prior(spec, site.accel_lsb),
            prior_source=session.prior_source,
        )
        if session.tolerance_source == "default":  # no flag, no header: the data say
            planned = (
                [a.pose.tolerance for a in averages]
                if all(session.matches(t) for t in by_trial(averages))
                else None
            )
            solution, scatter = solve_estimating_scatter(
                averages, spec, site, device, planned=planned, context=context
            )
            notes += () if scatter is None else (scatter.note(),)
        else:
            solution = solve_positions(averages, spec, site, device, **context.keywords())
        line = trials_line(solution.record)
        notes += () if line is None else (line,)
        moved = _moved(rec)
        if choice.gyro == "moves":  # imucal's turns are known; its poses leave psi free
            sigmas = _pose_sigmas(rec, averages) if session.tolerance_source != "default" else None
            solution, _ = solve_gyro_moves(
                rec, solution, site, pose_moves=not rec.turns, pose_sigmas=sigmas
            )
    else:
        if choice.gyro == "moves" and position_labels(rec):
            raise InputError(
                "gyro='moves' needs labelled positions with angles", options=("gyro='moves'",)
            )
        solution = solve_scalar(
            _unknown_pose_averages(rec),
            site,
            device,
            full=choice.model == "full",
            recording=recording,
        )
        if choice.gyro == "moves":  # imu_tk: the moves' rotations known through gravity only
            solution, _ = solve_gravity_moves_recording(rec, solution, site)
    unchecked = _unchecked_gyro(solution) if has_accel(rec) else ()
    warnings = moved + solution.warnings + unchecked + _few_dof(solution)
    # the limits of the plan the record names: the header's, else the one its poses match
    accept = limits_for(limits, session.plan_name or solution.record.plan)
    verdict = judge(solution, site, accept)
    record = replace(solution.record, acceptance=verdict.block)
    return RecordingSolution(
        replace(solution, record=record, warnings=warnings), g_source, verdict, notes
    )


def by_trial(averages: Sequence[PositionAverage]) -> list[list[PositionAverage]]:
    """``averages`` split by trial, in their order (one list without trials)."""
    out: dict[int | None, list[PositionAverage]] = {}
    for a in averages:
        out.setdefault(a.trial, []).append(a)
    return list(out.values()) or [[]]


def _pose_sigmas(
    rec: Recording, averages: Sequence[PositionAverage]
) -> dict[PositionKey, tuple[float, ...]] | None:
    """Return each position's key → 1σ (rad) of its angles ``(alpha, beta, psi)``.

    The key is the label, ``(trial, label)`` with trials (:mod:`.gyro_moves`).
    The procedure weighs its moves so (:mod:`canimucal.procedure.gyro_fit`); None when the
    averages are not one per key.
    """
    keys: list[PositionKey]
    if rec.trial is None:
        keys = [int(k) for k in position_labels(rec)]
    else:
        keys = [(t, label) for t, label, _rows in trial_label_rows(rec.position, rec.trial)]
    if len(keys) != len(averages):
        return None
    return {
        k: tuple(float(t) for t in a.pose.tolerances) for k, a in zip(keys, averages, strict=True)
    }


MIN_DOF = 10
"""Below this many residual degrees of freedom `solve` warns (docs/design.md §10)."""


MOTION_LEVEL = 1e-4
"""Level of the test for a unit that moved inside a position (Bonferroni inside), as strict as
analyze's family-wise one: a turn that matters is far beyond it (0.2° in a 10 s position:
across χ² ≥ 490 on 2 dof; the threshold at five positions is 22), a mild bias walk is not."""


def _moved(rec: Recording) -> tuple[str, ...]:
    """Say which labelled positions moved (:func:`~.motion.moved_alone`, as ``analyze``).

    A position whose accelerometer direction turned while ``|f|`` stayed steady, when the
    other positions do not trend and a walk as large as theirs does not explain it: its mean
    is of a pose held only part of the time. Numbered as ``analyze`` numbers them: 1, 2, …
    in label order (within each trial).
    """
    keyed: list[tuple[int | None, Rows]]
    if rec.trial is None:
        keyed = [(None, rows) for rows in position_parts(rec)[0]]
    else:
        keyed = [(trial, rows) for trial, _, rows in trial_label_rows(rec.position, rec.trial)]
    names, count = [], dict[int | None, int]()
    for trial, _ in keyed:
        count[trial] = count.get(trial, 0) + 1
        names.append(f"{count[trial]}" + ("" if trial is None else f" of trial {trial}"))
    windows = [(np.asarray(rec.t[rows], dtype=np.float64), rec.accel[rows]) for _, rows in keyed]
    return tuple(
        f"accel: {m.line(names[m.index])}: its mean is of a pose held only part of the time "
        "(redo the position)"
        for m in moved_alone(windows, MOTION_LEVEL)
    )


def _few_dof(solution: Solution) -> tuple[str, ...]:
    if solution.joint is None or solution.joint.dof >= MIN_DOF:
        return ()
    return (
        f"only {solution.joint.dof} residual degrees of freedom: the σ and the fit's χ² rest "
        "on very few residuals (add positions)",
    )


@dataclass(frozen=True)
class SolveContext:
    """What :func:`~canimucal.analysis.calibrate.solve_positions` takes beside the positions."""

    recording: RecordingRef | None = None
    plan_name: str | None = None
    prior: Mapping[str, tuple[float, float]] | None = None
    prior_source: str = "factory K"

    def keywords(self) -> dict[str, Any]:
        """Return the keyword arguments of ``solve_positions``."""
        return {
            "recording": self.recording,
            "plan_name": self.plan_name,
            "prior": self.prior,
            "prior_source": self.prior_source,
        }


def solve_estimating_scatter(
    averages: Sequence[PositionAverage],
    spec: JointSpec,
    site: SiteConditions,
    device: Device,
    *,
    planned: Sequence[float] | None = None,
    context: SolveContext | None = None,
) -> tuple[Solution, PoseScatter | None]:
    """Solve positions whose pose scatter no header gives: the data say (docs/design.md §10).

    The scatter is estimated from the fit's residuals (REML; with few residuals its one-sided
    95 % upper bound, or ``planned``, each position's tolerance from the header's plan, where
    larger: :func:`~canimucal.analysis.pose_scatter.fit_scatter`), the poses carry it, and
    the record's ``fit`` block says what the σ rest on. What ``solve`` does without a
    ``tolerance_deg``, for averages from anywhere (the departures suite's offline sessions).
    """
    keywords = (context or SolveContext()).keywords()
    try:
        averages, scatter = fit_scatter(
            averages, spec, g=site.g, latitude=site.latitude, heading=site.heading,
            accel_lsb=site.accel_lsb, gyro_lsb=site.gyro_lsb, planned=planned,
        )  # fmt: skip
    except ModelError:  # the solve itself says what is wrong with these positions
        return solve_positions(averages, spec, site, device, **keywords), None
    solution = solve_positions(averages, spec, site, device, **keywords)
    fit = solution.record.fit or Fit()
    fit = replace(fit, pose_scatter_deg=scatter.used_deg, pose_scatter_basis=scatter.basis)
    return replace(solution, record=replace(solution.record, fit=fit)), scatter


def _unchecked_gyro(solution: Solution) -> tuple[str, ...]:
    """Say so when the gyro's scale went unchecked (no S from moves or Earth rate)."""
    gyro = solution.record.gyro
    if gyro is None or (gyro.S is not None and any(v is not None for r in gyro.S for v in r)):
        return ()
    return (
        "gyro scale and misalignment were not checked (bias only); --gyro moves estimates "
        "them from the moves between positions",
    )


def _unknown_pose_averages(rec: Recording) -> list[PositionAverage]:
    """Averages of the still stretches whose orientations are not known (scalar fit only)."""
    rows, labelled = position_rows(rec)
    if labelled:
        return position_averages(rec, require_angles=False)
    return [
        average_rows(rec, part) if trial is None else replace(average_rows(rec, part), trial=trial)
        for trial, part in interval_trials(rec, list(rows))
    ]


def _header_int(rec: Recording, key: str) -> int | None:
    value = rec.header.get(key)
    return int(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def calibrate(
    source: Recording | Sequence[PositionAverage],
    *,
    model: ModelName | None = None,
    tilt: bool | None = None,
    gyro: GyroChoice | None = None,
    tilt_model: TiltModel | None = None,
    gyro_g: bool = False,
    g: float | None = None,
    latitude_deg: float | None = None,
    tolerance_deg: float | None = None,
    limits: Limits | None = None,
    ref: RecordingRef | None = None,
) -> Calibration:
    """Calibrate from a recording or from position averages.

    The defaults are ``canimucal solve``'s (the recording header's session model, else
    diagonal K without tilt), so ``calibrate(rec, model="full", tilt=True)`` gives the
    numbers of ``canimucal solve REC --model full --tilt``. Averages (from
    :func:`~canimucal.model.positions.average_position`) are solved with standard gravity
    (or ``g``) and the nominal LSBs of docs/design.md §4. The result is judged against
    ``limits`` (an :class:`~canimucal.analysis.acceptance.AcceptanceLimits`, or an
    :class:`~canimucal.analysis.acceptance.AcceptanceConfig` that picks them per plan), the
    built-in limits when None: no user file is read. A failed acceptance check is reported
    in ``.acceptance``, never raised. ``ref`` names the file a recording came from in the
    result; ``cm.calibrate`` (:func:`canimucal.runtime.inputs.calibrate`) reads a path in any
    input format and passes it.
    """
    choice = ModelChoice(
        model=model,
        tilt=tilt,
        tilt_model=tilt_model,
        gyro=gyro,
        gyro_g=gyro_g,
        latitude_deg=latitude_deg,
        g=g,
        tolerance_deg=tolerance_deg,
    )
    if isinstance(source, str | os.PathLike):
        raise TypeError("a path is read by canimucal.calibrate (any input format), not here")
    if isinstance(source, Recording):
        return solve_recording(source, choice, recording=ref, limits=limits).record
    return _calibrate_averages(list(source), choice, limits_for(limits, None))


def _calibrate_averages(
    averages: list[PositionAverage], choice: ModelChoice, limits: AcceptanceLimits
) -> Calibration:
    if not averages:
        raise InputError("calibrate: no position averages given")
    latitude = None if choice.latitude_deg is None else float(np.deg2rad(choice.latitude_deg))
    site = SiteConditions(
        g=choice.g or STANDARD_GRAVITY,
        latitude=latitude,
        accel_lsb=DEFAULT_ACCEL_LSB,
        gyro_lsb=DEFAULT_GYRO_LSB,
    )
    device = Device(serial=0)
    if choice.gyro == "moves":
        raise InputError("calibrate: gyro 'moves' needs a recording (the moves are its samples)")
    if all(np.all(np.isfinite(a.pose.angles)) for a in averages):
        spec = choice.spec(has_gyro=all(a.mean_gyro is not None for a in averages))
        solution = solve_positions(averages, spec, site, device)
    else:
        solution = solve_scalar(averages, site, device, full=choice.model == "full")
    verdict = judge(solution, site, limits)
    return replace(solution.record, acceptance=verdict.block)
