"""From a recording to the grouped session the discrepancy analysis reads.

Labelled positions are used as they are (with their angles when every one has them); a
recording without labels is cut into static intervals (:mod:`canimucal.model.static`), whose
orientations are unknown, so only the scalar ``|f| = g`` fit applies. A recording of
several trials (its ``trial`` column, or the trials :func:`~canimucal.io.grouping.detect_trials`
found) gives one position per trial and label, each carrying its trial, as ``solve`` groups
it, with known angles or without: the base fit then gives each trial its own biases
(:mod:`.base_fit`; docs/design.md §6 *Trials*).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.data import SessionData, Window
from canimucal.analysis.pose_scatter import header_tolerance_deg
from canimucal.analysis.separation import plan_tilt_limit_deg
from canimucal.analysis.settling import fit_settling, trim_mask
from canimucal.errors import InputError
from canimucal.io.grouping import (
    Rows,
    has_angles,
    interval_trials,
    position_parts,
    rows_count,
    rows_where,
    trial_label_rows,
)
from canimucal.io.recording import Recording
from canimucal.model.positions import Pose, PositionAverage, average_position
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

MIN_POSITION_SAMPLES = 20
"""Positions with fewer samples are skipped (too short to average or to test for drift)."""


def _lsb(rec: Recording, key: str, default: float) -> float:
    value = rec.header.get(key)
    if isinstance(value, int | float) and not isinstance(value, bool) and value != 0:
        return float(value)
    return default


def _take(values: NDArray[Any], rows: Rows) -> NDArray[Any]:
    """Return ``values[rows]``, a view when the rows are one run (a slice).

    The settling fit reads a window's ends only, and the windows are kept for the whole
    analysis: a long position is not copied.
    """
    return values[rows]


def session_from_recording(
    rec: Recording,
    *,
    g: float,
    latitude: float | None,
    heading: float = 0.0,
    tolerance_deg: float | None = None,
) -> SessionData:
    """Group ``rec`` into positions; ``latitude``/``heading`` radians (None: no Earth rate).

    The pose-setting scatter is ``tolerance_deg`` when given (source ``flag``), else the
    recording's ``tolerance_deg`` header (``header``), else left to be estimated from the
    data (``estimated``: the poses carry no tolerance). A settling transient after each move
    (:mod:`.settling`, fitted per sensor) is trimmed from every position before averaging,
    each by the longer of the two sensors' trims. With labelled positions and two or more
    trials in the ``trial`` column the positions are keyed by (trial, label) (module doc).
    """
    tolerance_deg, source = scatter_source(rec, tolerance_deg)
    groups, labelled = position_parts(rec)
    known = labelled and has_angles(rec)
    trials: list[int | None] = [None] * len(groups)
    if labelled and rec.trial is not None and _trial_count(rec) >= 2:
        keyed = trial_label_rows(rec.position, rec.trial)
        groups, trials = [rows for _t, _l, rows in keyed], [t for t, _l, _r in keyed]
    elif not labelled and rec.trial is not None:  # still intervals found: each in its trial
        pairs = interval_trials(rec, groups)
        groups, trials = [rows for _t, rows in pairs], [t for t, _r in pairs]
    gyro_ok = bool(np.isfinite(rec.gyro).any())
    temp_ok = bool(np.isfinite(rec.temp_c).any())
    tol = float(np.deg2rad(tolerance_deg))
    kept, kept_trials = [], []
    for rows, trial in zip(groups, trials, strict=True):
        keep = rows_where(rows, np.all(np.isfinite(_take(rec.accel, rows)), axis=1))
        if rows_count(keep) >= MIN_POSITION_SAMPLES:
            kept.append(keep)
            kept_trials.append(trial)
    settling = {"accel": fit_settling([(_take(rec.t, k), _take(rec.accel, k)) for k in kept])}
    if gyro_ok:
        settling["gyro"] = fit_settling([(_take(rec.t, k), _take(rec.gyro, k)) for k in kept])
    trim_s = np.max([s.trim_s for s in settling.values()], axis=0)
    averages: list[PositionAverage] = []
    windows: list[Window] = []
    for rows, trim, trial in zip(kept, trim_s, kept_trials, strict=True):
        keep = rows_where(rows, trim_mask(_take(rec.t, rows), float(trim)))
        first = keep.start if isinstance(keep, slice) else int(keep[0])
        angles = [
            float(rec.alpha_deg[first]),
            float(rec.beta_deg[first]),
            float(rec.psi_deg[first]),
        ]
        a, b, p = (float(x) for x in np.deg2rad(angles))
        pose = Pose(a, b, p, tolerance=tol) if known else Pose(np.nan, np.nan)
        # the windows keep the recording's column types, as views when the rows are one run
        # (Window's doc); the averages convert to float64 before summing
        temp = _take(rec.temp_c, keep) if temp_ok else None
        gyro = _take(rec.gyro, keep) if gyro_ok else None
        accel = _take(rec.accel, keep)
        average = average_position(
            pose, accel, gyro, rec.sample_rate_hz,
            float(np.nanmean(np.asarray(temp, dtype=np.float64))) if temp is not None else None,
        )  # fmt: skip
        averages.append(average if trial is None else dataclasses.replace(average, trial=trial))
        windows.append(Window(_take(rec.t, keep), accel, gyro, temp))
    if len(averages) < 3:
        raise InputError(f"{rec.source or 'recording'}: found {len(averages)} positions, need 3")
    return SessionData(
        averages=tuple(averages),
        windows=tuple(windows),
        g=g,
        latitude=latitude,
        heading=heading,
        accel_lsb=_lsb(rec, "accel_lsb", DEFAULT_ACCEL_LSB),
        gyro_lsb=_lsb(rec, "gyro_lsb", DEFAULT_GYRO_LSB if known else 1.0),
        known_positions=known,
        scatter_source=source,
        settling=settling,
        tilt_limit_deg=plan_tilt_limit_deg(rec.header.get("plan")),
        gyro_lsb_known=known or "gyro_lsb" in rec.header,
    )


def _trial_count(rec: Recording) -> int:
    """How many trials the labelled rows of ``rec`` hold (its ``trial`` column)."""
    if rec.trial is None:
        return 0
    keyed = np.where(rec.trial < 0, -1, rec.trial)
    return int(np.unique(keyed[rec.position >= 0]).size)


def scatter_source(rec: Recording, tolerance_deg: float | None) -> tuple[float, str]:
    """Return the pose tolerance (degrees) and its source: flag, header, else estimated."""
    if tolerance_deg is not None:
        if not (np.isfinite(tolerance_deg) and tolerance_deg >= 0):
            raise InputError(
                f"tolerance_deg must be a finite number >= 0, got {tolerance_deg}",
                options=("tolerance_deg",),
            )
        return float(tolerance_deg), "flag"
    header = header_tolerance_deg(rec)
    if header is not None:
        return header, "header"
    return 0.0, "estimated"
