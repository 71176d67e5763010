"""Replay a measured session through the simulator, before and after the extension.

The truth of the extended model and the observed poses reproduce the session
(`canimucal sim --truth F --poses P`). Replaying it with the base truth (the extension's
terms removed) and with the extended truth, and fitting the base model to each replay,
shows whether the simulation now gets wrong what the measurement got wrong: the base fit's
rms and lack of fit should match the measured ones after the extension, not before.

A replay never re-simulates a long recording at full length (issue 23): it is simulated at
the rate that gives its longest position ``REPLAY_SAMPLES_PER_POSITION`` samples (the
measured rate when lower). Every noise term of the simulator is continuous-time (white
density, random walk, Gauss–Markov time constants, temperature in seconds), so each
position's mean and its covariance have the same statistics as at the measured rate, and the
replay's cost is bounded whatever the recording's length. A session of several trials is
replayed with its trials (:func:`with_trials_of`), so its base fit is the measured one's.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from canimucal.analysis.base_fit import fit_known
from canimucal.analysis.data import SessionData
from canimucal.analysis.report import Analysis, extended_truth, observed_poses
from canimucal.analysis.session import session_from_recording
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.io.recording import Recording
from canimucal.sim.truth import Truth

REPLAY_SAMPLES_PER_POSITION = 4000
"""Samples simulated for the longest position of a replay (module doc)."""


def replay_rate_hz(plan_seconds: list[float], measured_hz: float) -> float:
    """Return the replay's rate: the measured one, or lower so no position exceeds the bound."""
    longest = max(plan_seconds, default=0.0)
    if longest <= 0:
        return measured_hz
    return min(measured_hz, REPLAY_SAMPLES_PER_POSITION / longest)


@dataclass(frozen=True)
class ReplayRow:
    """Base-fit rms (m/s², per-position means) and χ²/dof of one data set."""

    label: str
    accel_rms: float
    chi2_per_dof: float
    runs_rms: tuple[float, ...] = ()
    runs_chi2: tuple[float, ...] = ()


def base_truth(extended: dict[str, Any]) -> dict[str, Any]:
    """Copy the extended truth with every extension removed (bias, diagonal K, white noise)."""
    doc = copy.deepcopy(extended)
    doc["base_tilt_deg"] = {"alpha0": 0.0, "beta0": 0.0}
    acc = doc["accel"]
    acc["K"] = np.diag(np.diag(np.array(acc["K"]))).tolist()
    for key in ("quadratic", "temp_coeff", "random_walk"):
        acc[key] = [0.0, 0.0, 0.0]
    if "gyro" in doc:
        doc["gyro"]["G"] = np.zeros((3, 3)).tolist()
        for key in ("temp_coeff", "random_walk"):
            doc["gyro"][key] = [0.0, 0.0, 0.0]
    return doc


def _base_fit_row(label: str, a: Analysis, truth_doc: dict[str, Any], seed: int) -> ReplayRow:
    plan = observed_poses(a)
    assert plan is not None
    truth = Truth.from_dict(truth_doc)
    rate = replay_rate_hz([p.seconds for p in plan.positions], truth.sample_rate_hz)
    rec = simulate_plan_recording(truth, plan, seed=seed, sample_rate_hz=rate)
    rec = with_trials_of(rec, a.session)
    session = session_from_recording(
        rec, g=a.session.g, latitude=a.session.latitude, heading=a.session.heading,
        tolerance_deg=_scatter_deg(a),
    )  # fmt: skip
    prepared, res = fit_known(session)
    return ReplayRow(label, res.rms_accel_ms2, prepared.chi2 / max(prepared.dof, 1))


def with_trials_of(rec: Recording, session: SessionData) -> Recording:
    """Give a replay of ``session``'s observed poses the session's trials (its ``trial`` column).

    The replay runs one position per average, labelled by its index; each row takes the trial
    of its position (a move's rows, the one before it). The replay's base fit then has the
    measured one's trial offsets and dof: a bias step between trials is absorbed by them
    exactly (the fit is linear in the offsets), so the replay need not simulate the steps.
    """
    if not session.trials:
        return rec
    trials = np.array([-1 if x.trial is None else x.trial for x in session.averages])
    held = np.maximum.accumulate(np.where(rec.position >= 0, np.arange(rec.n_rows), 0))
    index = np.maximum(rec.position[held], 0)
    return dataclasses.replace(rec, trial=trials[index].astype(np.int64))


def _scatter_deg(a: Analysis) -> float:
    """Return the pose-setting scatter the analysis used (estimated, header, flag), degrees."""
    noise = a.result.noise
    return noise.pose_scatter.value_deg if noise is not None else 0.0


def replay(a: Analysis, *, seeds: tuple[int, ...] = (1, 2, 3)) -> list[ReplayRow] | None:
    """Measured, base-truth and extended-truth replays (mean over ``seeds``); None if scalar."""
    if not a.session.known_positions:
        return None
    tol = float(np.deg2rad(_scatter_deg(a)))
    averages = tuple(
        dataclasses.replace(x, pose=dataclasses.replace(x.pose, tolerance=tol))
        for x in a.session.averages
    )
    prepared, res = fit_known(dataclasses.replace(a.session, averages=averages))
    rows = [ReplayRow("measured", res.rms_accel_ms2, prepared.chi2 / max(prepared.dof, 1))]
    ext = extended_truth(a)
    for label, doc in (("simulated, base model", base_truth(ext)), ("simulated, extended", ext)):
        runs = [_base_fit_row(label, a, doc, s) for s in seeds]
        rows.append(
            ReplayRow(
                label,
                float(np.mean([r.accel_rms for r in runs])),
                float(np.mean([r.chi2_per_dof for r in runs])),
                tuple(r.accel_rms for r in runs),
                tuple(r.chi2_per_dof for r in runs),
            )
        )
    return rows


def replay_ratios(rows: list[ReplayRow] | None) -> dict[str, Any] | None:
    """Compare the extended replay with the measurement: rms ratio, its 95 %, χ² ratio.

    The interval is the prediction interval of one replay's ratio from the seeds' spread,
    ``mean ± t(0.975, n−1) · sd · √(1 + 1/n)``: a measurement the extended model reproduces
    has its ratio 1 inside it. None without a replay (orientations unknown).
    """
    if not rows:
        return None
    measured = rows[0]
    ext = rows[-1]
    ratios = np.array(ext.runs_rms) / measured.accel_rms
    n = ratios.size
    mean = float(np.mean(ratios))
    half = float("nan")
    if n >= 2:
        from scipy import special  # lazy (issue 23); t.ppf is stdtrit, without scipy.stats

        half = float(special.stdtrit(n - 1, 0.975) * np.std(ratios, ddof=1) * np.sqrt(1 + 1 / n))
    return {
        "rms_ratio": mean,
        "rms_ratio_ci95": [mean - half, mean + half],
        "chi2_ratio": ext.chi2_per_dof / max(measured.chi2_per_dof, 1e-300),
    }
