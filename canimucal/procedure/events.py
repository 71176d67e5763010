"""Events the guided procedure emits (past tense), for the TUI, the CLI and the tests.

Every event is a frozen dataclass. Times are seconds of *sample* time (sample counts over
the output data rate), never wall time. Angles are degrees here: events are for people.
A display keeps the latest event of each kind; :class:`SamplesReceived` carries the live
readout (about twice a second per node) and the data of a sparkline.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from canimucal.model.positions import PlannedPosition, PositionAverage

if TYPE_CHECKING:
    from canimucal.analysis.acceptance import AcceptanceReport
    from canimucal.analysis.calibrate import Solution


class Phase(StrEnum):
    """Where the procedure is."""

    WARMUP = "warmup"
    INSTRUCT = "instruct"
    SETTLING = "settling"
    AVERAGING = "averaging"
    REVIEW_POSITION = "review_position"
    READY_TO_SOLVE = "ready_to_solve"
    REVIEW = "review"
    WRITING = "writing"
    DONE = "done"
    CANCELLED = "cancelled"


Array = NDArray[np.float64]


@dataclass(frozen=True)
class Event:
    """Base of every procedure event."""


@dataclass(frozen=True)
class PhaseChanged(Event):
    """The procedure entered ``phase`` from ``previous`` (None at the start)."""

    phase: Phase
    previous: Phase | None


@dataclass(frozen=True)
class WarmupProgressed(Event):
    """Temperature slope over the warm-up window; ``warm`` once it is below the threshold."""

    temp_c: float
    slope_c_per_min: float | None
    threshold_c_per_min: float
    elapsed_s: float
    window_s: float
    warm: bool
    skipped: bool = False


@dataclass(frozen=True)
class PoseInstructed(Event):
    """Set the unit to ``position`` (index of ``total``) and confirm; ``words`` says how."""

    index: int
    total: int
    position: PlannedPosition
    words: str
    seconds: float
    verification: bool = False


@dataclass(frozen=True)
class SamplesReceived(Event):
    """Live readout of one node: latest means in SI, tilt against the target, sparkline data.

    ``tilt_error_deg`` is (measured − target) of (alpha, beta), None before a target is set.
    ``sparkline`` holds |f| − g (m/s²) of the latest 50 blocks (one mean per block).
    """

    node_id: int
    time_s: float
    accel_ms2: Array
    gyro_rads: Array
    temp_c: float
    tilt_error_deg: tuple[float, float] | None
    moving_std_counts: float
    sparkline: tuple[float, ...]
    lost_total: int


@dataclass(frozen=True)
class StillnessChanged(Event):
    """All nodes became still (``still``) or one started moving; ``still_for_s`` so far."""

    still: bool
    still_for_s: float
    needed_s: float


@dataclass(frozen=True)
class PoseRefused(Event):
    """The measured gravity direction does not match the target pose (wrong sign or size)."""

    index: int
    node_id: int
    measured_deg: tuple[float, float]
    target_deg: tuple[float, float]
    error_deg: float
    tolerance_deg: float
    message: str


@dataclass(frozen=True)
class MoveRefused(PoseRefused):
    """The gyro saw a different turn from the last accepted position than the plan's.

    A :class:`PoseRefused` (displays and operators treat it as one): ``measured_deg`` and
    ``target_deg`` hold the target's (alpha, beta), which the accelerometer confirmed;
    ``error_deg`` is the attitude error the gyro measured. ``turn_measured_deg`` and
    ``turn_target_deg`` are the turns as rotation vectors (degrees, body axes).
    """

    turn_measured_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turn_target_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class AveragingStarted(Event):
    """The pose was checked and averaging of position ``index`` began."""

    index: int
    seconds: float
    tilt_error_deg: tuple[float, float]


@dataclass(frozen=True)
class AveragingProgressed(Event):
    """Averaging progress of position ``index`` (slowest node); ``seconds_left`` to go."""

    index: int
    elapsed_s: float
    total_s: float
    seconds_left: float

    @property
    def fraction(self) -> float:
        """Progress in [0, 1]."""
        return min(1.0, self.elapsed_s / self.total_s) if self.total_s > 0 else 1.0


@dataclass(frozen=True)
class PositionRejected(Event):
    """The attempt at position ``index`` was discarded (motion, disturbance, redo)."""

    index: int
    reason: str
    node_id: int | None = None
    restarting: bool = True


@dataclass(frozen=True)
class PositionAveraged(Event):
    """Position ``index`` averaged on every node; waiting for accept or redo."""

    index: int
    averages: dict[int, PositionAverage]
    seconds: float


@dataclass(frozen=True)
class PositionAccepted(Event):
    """The operator accepted position ``index``."""

    index: int


@dataclass(frozen=True)
class AveragingTimeChosen(Event):
    """The averaging time of the remaining positions and why (``noise``/``user``/``fixed``).

    From the noise: the ``limiting_axis`` (``"gyro.z"``) that set the time, its sensor's
    white noise density, random walk and per-axis ``optima_s`` (clipped); ``sensor_optima``
    and ``sensor_loss`` the same optima and each axis's ADEV at ``seconds`` over its ADEV at
    its optimum, for every sensor that took part (``(("accel", (x, y, z)), ...)``).
    """

    seconds: float
    source: str
    white_noise_density: tuple[float, ...] = ()
    random_walk: tuple[float, ...] = ()
    optima_s: tuple[float, ...] = ()
    limiting_axis: str = ""
    sensor_optima: tuple[tuple[str, tuple[float, ...]], ...] = ()
    sensor_loss: tuple[tuple[str, tuple[float, ...]], ...] = ()

    @property
    def limiting_loss(self) -> float:
        """The limiting axis's ADEV at ``seconds`` over its own best (nan when not from noise)."""
        sensor, _, axis = self.limiting_axis.partition(".")
        for name, values in self.sensor_loss:
            if name == sensor and axis in ("x", "y", "z"):
                return values["xyz".index(axis)]
        return float("nan")

    def describe(self) -> str:
        """One line: the time, its source and, from the noise, the per-axis optima."""
        text = f"{self.seconds:.0f} s ({self.source})"
        optima = self.sensor_optima or ((self.limiting_axis.partition(".")[0], self.optima_s),)
        if self.optima_s:
            parts = [
                f"{name} " + ", ".join(f"{'xyz'[i]} {v:.0f} s" for i, v in enumerate(values))
                for name, values in optima
            ]
            text += f"; per-axis optima {'; '.join(parts)}; limiting axis {self.limiting_axis}"
            loss = self.limiting_loss
            if np.isfinite(loss):
                text += f" ({loss:.2f}× its best)"
        return text


@dataclass(frozen=True)
class Solved(Event):
    """Every node solved; ``acceptance`` says whether a write may be offered."""

    solutions: dict[int, Solution]
    acceptance: dict[int, AcceptanceReport]

    @property
    def acceptable(self) -> bool:
        """Whether every node's result passed the acceptance limits."""
        return all(a.passed for a in self.acceptance.values())


@dataclass(frozen=True)
class RecordSaved(Event):
    """The calibration record, certificate and recording of one node were saved."""

    node_id: int
    record_path: str
    certificate_path: str
    recording_path: str


@dataclass(frozen=True)
class WriteFinished(Event):
    """The transactional write to one node ended (``ok``), with its backup file."""

    node_id: int
    ok: bool
    message: str
    backup_path: str | None = None


@dataclass(frozen=True)
class LevelChecked(Event):
    """|f| − g (m/s²) and the tilt (degrees) at the level pose, nominal and calibrated.

    ``stage`` is ``before`` (the level position of the session, new parameters applied in
    software) or ``after`` (raw data re-read after the write).
    """

    node_id: int
    stage: str
    norm_error_nominal_ms2: float
    tilt_nominal_deg: tuple[float, float]
    norm_error_calibrated_ms2: float
    tilt_calibrated_deg: tuple[float, float]


@dataclass(frozen=True)
class PoseVerified(Event):
    """One verification pose re-read after the write: |f| − g and the tilt error.

    ``index`` of ``total`` verification poses (:mod:`~canimucal.procedure.verification`),
    ``words`` how the pose was worded; |f| − g in m/s², the tilt error the angle (degrees)
    between the measured direction of f and the one the pose predicts with the fitted base
    tilt, nominal (the device's raw counts at nominal LSB) and calibrated (the values
    written, applied as the firmware applies them).
    """

    node_id: int
    index: int
    total: int
    position: PlannedPosition
    words: str
    norm_error_nominal_ms2: float
    norm_error_calibrated_ms2: float
    tilt_error_nominal_deg: float
    tilt_error_calibrated_deg: float


@dataclass(frozen=True)
class DeviceEventReported(Event):
    """The node reported something on the bus (a notice; the machine reacts where needed).

    ``kind``: ``reboot``, ``heartbeat_lost``, ``heartbeat_resumed``, ``emergency``,
    ``serial_changed`` or ``bus_error``; ``message`` says it in words.
    """

    node_id: int
    kind: str
    message: str


@dataclass(frozen=True)
class ProcedureFailed(Event):
    """The procedure stopped on an error (shown in a modal, never a traceback)."""

    message: str
    title: str = "Error"


@dataclass(frozen=True)
class ProcedureFinished(Event):
    """The procedure ended (``cancelled`` when the operator stopped it)."""

    cancelled: bool = False
    notes: tuple[str, ...] = field(default_factory=tuple)
