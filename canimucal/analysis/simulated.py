"""A whole plan recorded straight from the simulator, without the CAN bus.

For studies and tests of the solve path (and for `analyze`'s reproduction of a measured
session): the simulated unit follows the plan's pose schedule and every still sample is
labelled with its position, as the recorder labels a real session.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.io.recording import Recording, recording_from_columns
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.constants import COUNTER_MODULUS
from canimucal.sim.imu import ImuSimulator
from canimucal.sim.schedule import set_by_operator
from canimucal.sim.truth import Truth

BLOCK_SAMPLES = 1000


def simulate_plan_recording(
    truth: Truth,
    plan: Plan,
    *,
    seed: int | None = None,
    transient_s: float = 2.0,
    serial: int | None = None,
    angle_errors: bool = True,
    sample_rate_hz: float | None = None,
) -> Recording:
    """Simulate ``plan`` (angles, seconds) on ``truth`` and return the labelled recording.

    With ``angle_errors`` the unit is really set to each pose plus an error drawn from the
    position's ``tolerance`` (an operator on a step ladder), while the recording is labelled
    with the nominal angles, as in the field.

    ``sample_rate_hz`` simulates at another rate than the truth's (any positive rate, not
    only the device's): the noise densities, walks and time constants are continuous-time,
    so a position's mean has the same statistics from fewer samples (the replay's bound).
    The rounding to counts is white at the truth's rate (step²/12 a sample): it is folded into
    the white density there, and the slower samples are not rounded.
    """
    if sample_rate_hz is not None:
        truth = _at_rate(truth, float(sample_rate_hz))
    sim = ImuSimulator(truth, seed=seed)
    actual = set_by_operator(plan, np.random.default_rng(seed)) if angle_errors else plan
    first = actual.positions[0]
    sim.set_pose(first.alpha, first.beta, first.psi, transient_s=0.0)
    sim.set_schedule(actual, transient_s=transient_s)
    fs = sim.sample_rate_hz
    total = int(np.ceil((plan.total_seconds + transient_s * len(plan.positions)) * fs)) + 1
    blocks = []
    remaining = total
    while remaining > 0:
        blocks.append(sim.next_block(min(BLOCK_SAMPLES, remaining)))
        remaining -= len(blocks[-1])
    index = np.concatenate([b.position_index for b in blocks])
    angles = np.full((index.size, 3), np.nan)
    for i, p in enumerate(plan.positions):
        angles[index == i] = np.rad2deg(p.angles)
    header = {
        "sample_rate_hz": float(fs),
        "g": float(truth.g),
        "latitude_deg": float(np.rad2deg(truth.latitude)),
        "heading_deg": float(np.rad2deg(truth.heading)),
        "accel_lsb": float(truth.accel.nominal_lsb),
        "gyro_lsb": float(truth.gyro.nominal_lsb),
        "device_serial": int(truth.serial if serial is None else serial),
    }
    return recording_from_columns(
        header,
        t=np.concatenate([b.t_s for b in blocks]),
        accel=np.concatenate([b.accel for b in blocks]),
        gyro=np.concatenate([b.gyro for b in blocks]),
        counter=np.arange(index.size) % COUNTER_MODULUS,
        position=index,
        alpha_deg=angles[:, 0],
        beta_deg=angles[:, 1],
        psi_deg=angles[:, 2],
        temp_c=np.concatenate([b.temp_c for b in blocks]),
    )


def _at_rate(truth: Truth, rate_hz: float) -> Truth:
    """``truth`` sampled at ``rate_hz``, its quantization noise kept as white density."""
    fs = float(truth.sample_rate_hz)

    def folded(sensor: Any, scale: Any) -> Any:
        quantization_density = sensor.quantization / np.sqrt(12.0 * fs) / np.abs(np.diag(scale))
        density = np.sqrt(np.asarray(sensor.noise_density) ** 2 + quantization_density**2)
        return dataclasses.replace(sensor, noise_density=density, quantization=0.0)

    return dataclasses.replace(
        truth,
        sample_rate_hz=rate_hz,
        accel=folded(truth.accel, truth.accel.K),
        gyro=folded(truth.gyro, truth.gyro.S),
    )


@dataclass(frozen=True)
class TrialsTruth:
    """What :func:`simulate_trials_recording` drew: each trial's unit (its own biases)."""

    trials: tuple[Truth, ...]

    @property
    def accel_bias(self) -> NDArray[np.float64]:
        """``(n_trials, 3)`` accelerometer biases (counts), one row a trial."""
        return np.array([t.accel.bias for t in self.trials], dtype=float)

    @property
    def gyro_bias(self) -> NDArray[np.float64]:
        """``(n_trials, 3)`` gyro biases (counts), one row a trial."""
        return np.array([t.gyro.bias for t in self.trials], dtype=float)


def remounted(
    truth: Truth, rng: np.random.Generator, accel_counts: float, gyro_counts: float
) -> Truth:
    """``truth`` re-mounted: its biases moved by a draw, uniform within ±the given counts.

    A unit taken off and fastened again keeps its scale (K, S, G) while its biases move
    (mounting stress, a new warm-up): what separates the trials of one recording.
    """
    accel = dataclasses.replace(
        truth.accel, bias=np.asarray(truth.accel.bias) + rng.uniform(-accel_counts, accel_counts, 3)
    )
    gyro = dataclasses.replace(
        truth.gyro, bias=np.asarray(truth.gyro.bias) + rng.uniform(-gyro_counts, gyro_counts, 3)
    )
    return dataclasses.replace(truth, accel=accel, gyro=gyro)


def simulate_trials_recording(
    truth: Truth,
    plan: Plan,
    trials: int,
    *,
    seed: int,
    accel_offset_counts: float = 20.0,
    gyro_offset_counts: float = 5.0,
    angle_errors: bool = True,
    sample_rate_hz: float | None = None,
    gap_s: float = 0.0,
    label_trials: bool = True,
) -> tuple[Recording, TrialsTruth]:
    """Simulate ``trials`` re-mountings of one unit, each running ``plan``, in one recording.

    Each trial's unit is ``truth`` with its accelerometer and gyro biases moved by a draw
    uniform within ±``accel_offset_counts`` and ±``gyro_offset_counts`` (:func:`remounted`;
    K, S and G shared), its poses set anew (``angle_errors``), its noise its own. The trials
    follow one another in time (``gap_s`` of silence between them) with the same position
    labels; with ``label_trials`` every row names its trial in the ``trial`` column
    (docs/design.md §5), else the file has none (what detection must find). Returns the
    recording and the trials' units.
    """
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    rng = np.random.default_rng([seed, 7])
    units = tuple(
        remounted(truth, rng, accel_offset_counts, gyro_offset_counts) for _ in range(trials)
    )
    parts = [
        simulate_plan_recording(
            unit,
            plan,
            seed=int(rng.integers(2**31)),
            angle_errors=angle_errors,
            sample_rate_hz=sample_rate_hz,
        )  # fmt: skip
        for unit in units
    ]
    t, start = [], 0.0
    for part in parts:
        t.append(part.t - part.t[0] + start)
        step = float(np.median(np.diff(part.t))) if part.n_rows > 1 else 0.0
        start = float(t[-1][-1]) + step + gap_s
    n = sum(p.n_rows for p in parts)

    def cat(name: str) -> NDArray[np.float64]:
        return np.concatenate([getattr(p, name) for p in parts])

    rec = recording_from_columns(
        {**parts[0].header, "device_serial": int(parts[0].header["device_serial"])},
        t=np.concatenate(t), accel=cat("accel"), gyro=cat("gyro"),
        counter=np.arange(n) % COUNTER_MODULUS, position=cat("position"),
        alpha_deg=cat("alpha_deg"), beta_deg=cat("beta_deg"), psi_deg=cat("psi_deg"),
        temp_c=cat("temp_c"),
        trial=np.repeat(np.arange(trials), [p.n_rows for p in parts]) if label_trials else None,
    )  # fmt: skip
    return rec, TrialsTruth(units)
