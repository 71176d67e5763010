"""What the procedure is configured with, and the phases it goes through."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.acceptance import AcceptanceLimits
from canimucal.analysis.calibrate import SiteConditions
from canimucal.io.calibration import Device
from canimucal.model.layout import JointSpec
from canimucal.model.mounting import MountingMap
from canimucal.model.plan import KPrior
from canimucal.model.positions import Plan, PlannedPosition, PositionAverage
from canimucal.model.vehicle_size import VehicleSize
from canimucal.procedure.averaging import AveragingPolicy

LEVEL = PlannedPosition(0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ResumeState:
    """What an interrupted session measured: accepted averages per node, in plan order."""

    averages: dict[int, dict[int, PositionAverage]]
    next_index: int
    recordings: dict[int, Path] = field(default_factory=dict)
    """The file read per node (the ``.partial`` when one was left over)."""
    k_priors: dict[int, KPrior] = field(default_factory=dict)
    """The prior on K each node's recording says the session held (none: not recorded)."""
    first_accel: NDArray[np.float64] | None = None
    """Accelerometer samples ``(n, 3)`` of the first position (first node): the resumed
    procedure chooses the later averaging time from them (and ``first_gyro``) as the session
    did."""
    first_gyro: NDArray[np.float64] | None = None
    """Gyro samples ``(n, 3)`` of the same rows (None: none recorded)."""


@dataclass(frozen=True)
class ProcedureConfig:
    """Everything the procedure needs to know up front."""

    plan: Plan
    node_ids: tuple[int, ...]
    sample_rate_hz: float
    site: SiteConditions
    spec: JointSpec = field(default_factory=lambda: JointSpec(gyro="mems"))
    averaging: AveragingPolicy = field(default_factory=AveragingPolicy)
    limits: AcceptanceLimits = field(default_factory=AcceptanceLimits)
    devices: Mapping[int, Device] = field(default_factory=dict)
    plan_name: str | None = None
    warmup: bool = True
    warmup_window_s: float = 60.0
    warmup_threshold_c_per_min: float = 0.1
    settle_s: float = 2.0
    pose_tolerance_deg: float = 3.0
    first_pose_tolerance_deg: float = 8.0
    """The first pose, which nothing predicts: a floor slope of 3° and a mounting trim of 2°
    about each axis and a bias of 50 counts add up to 7–8° there (docs/design.md §2)."""
    move_tolerance_deg: float | None = 15.0
    """Largest attitude error the gyro may see over a move (None: moves are not checked)."""
    gyro_moves: bool = True
    """Fit the gyro's S to the moves the gyro confirmed (a ``mems`` gyro; columns the plan's
    moves do not turn about stay nominal, reported as not identifiable). The moves are those
    the check passed, so ``move_tolerance_deg`` None leaves S nominal."""
    disturbance_k: float = 6.0
    chunk_s: float = 0.5
    verify_seconds: float = 10.0
    live_period_s: float = 0.5
    progress_period_s: float = 0.25
    k_priors: Mapping[int, KPrior] = field(default_factory=dict)
    """Per node, the prior on K the plan holds (its mean read from the device or a file, its
    σ); a node without one gets the nominal K at the plan's own σ."""
    resume_from: ResumeState | None = None
    """Positions an interrupted session accepted (:mod:`.resume`); the procedure goes on."""
    mounting: MountingMap | None = None
    """How the unit sits in the vehicle: instructions worded for the vehicle (None: body axes)."""
    mounting_note: str = ""
    """Where ``mounting`` came from, for the operator (asked, saved for the serial, default)."""
    vehicle_size: VehicleSize | None = None
    """The vehicle's wheelbase and track: its tilts worded as heights (None: as angles)."""
