"""Which model to solve, and the model a recording's session solved (docs/design.md §10).

A session writes ``plan``, ``model``, ``tilt``, ``gyro`` and ``tolerance_deg`` into its
recording (and ``gyro_g: true`` when it estimated the gyro's G). An option given (a flag,
a keyword of ``cm.calibrate``) wins over the header; without either, the defaults are
bias + diagonal K, no tilt, gyro ``mems`` when there are gyro data, 0.1°.
When ``plan`` names a built-in plan whose poses the recording's positions match, each
position takes that plan's own tolerances (a vehicle's turn: 5°) and the plan's prior on K:
the one the session held (header ``prior_k``, ``prior_k_sigma`` and their sources) unless
``--prior-k`` or ``--prior-k-sigma`` say otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError
from canimucal.io.calibration import Calibration
from canimucal.io.plans import DEFAULT_TOLERANCE_DEG
from canimucal.io.recording import HeaderValue, Recording, header_matrix
from canimucal.model.layout import GyroSpec, JointSpec
from canimucal.model.plan import KPrior, plan_prior
from canimucal.model.positions import Plan, PositionAverage
from canimucal.model.vocabulary.plans import CUSTOM, PLANS, VEHICLE_PRIOR_K_SIGMA

_MATCH_DEG = 0.05
"""Recorded angles within this of a plan's are that plan's poses."""

ModelName = Literal["diag", "full"]
TiltModel = Literal["rigid", "additive"]
GyroChoice = Literal["none", "mems", "moves", "nav"]


@dataclass(frozen=True)
class ModelChoice:
    """Which model to solve: the options of ``canimucal solve`` (same names, same defaults).

    ``None`` fields come from the recording's header (:func:`session_model`), else the
    defaults above. ``gyro`` None means ``mems`` when every position has gyro data;
    ``moves`` adds S from the moves (:mod:`canimucal.analysis.gyro_moves`) to the ``mems``
    fit. ``latitude_deg`` and ``g`` override the header; ``prior_k`` is a file holding the
    factory K (a calibration JSON or ``read-params --json`` output).
    """

    model: ModelName | None = None
    tilt: bool | None = None
    tilt_model: TiltModel | None = None
    gyro: GyroChoice | None = None
    gyro_g: bool = False
    latitude_deg: float | None = None
    g: float | None = None
    tolerance_deg: float | None = None
    prior_k_sigma: float | None = None
    prior_k: str | None = None

    def spec(self, *, has_gyro: bool) -> JointSpec:
        """Build the :class:`JointSpec` of this choice (InputError: ``nav`` without latitude)."""
        gyro: GyroSpec = (
            "mems" if self.gyro == "moves" else self.gyro or ("mems" if has_gyro else "none")
        )
        if gyro == "nav" and self.latitude_deg is None:
            raise InputError(
                "gyro='nav' needs latitude_deg (the gyro scale comes from Earth rate)",
                options=("gyro='nav'", "latitude_deg"),
            )
        model = self.model or "diag"
        return JointSpec(
            accel_k=model,
            tilt=(self.tilt_model or "rigid") if self.tilt else "none",
            gyro=gyro,
            gyro_s=model,
            gyro_g=self.gyro_g,
        )


@dataclass(frozen=True)
class SessionModel:
    """What the header says about the session: its plan, tolerance and prior."""

    plan_name: str | None
    plan: Plan | None
    tolerance_deg: float
    prior_k_sigma: float | None
    plan_tolerances: bool = True
    factory_k: NDArray[np.float64] | None = None
    prior_source: str = "factory K"
    tolerance_source: str = "default"
    """Where ``tolerance_deg`` came from: ``flag``, ``header``, else ``default`` (then the
    solve estimates the scatter from the data)."""

    def _plan_poses(self, averages: Sequence[PositionAverage]) -> bool:
        """Tell whether the recorded poses are the plan's, in order (within 0.05°)."""
        plan = self.plan
        if plan is None or len(plan.positions) != len(averages):
            return False
        planned = np.array([p.angles for p in plan.positions])
        recorded = np.array([a.pose.angles for a in averages])
        return bool(np.allclose(planned, recorded, atol=np.deg2rad(_MATCH_DEG)))

    def matches(self, averages: Sequence[PositionAverage]) -> bool:
        """Whether the averages are the header's plan's poses (its tolerances then apply)."""
        return self.plan_tolerances and self._plan_poses(averages)

    def with_trim(self, spec: JointSpec, averages: Sequence[PositionAverage]) -> JointSpec:
        """``spec`` with the mounting trim when the plan fits one and these are its poses.

        The plan registry's ``trim`` (the vehicle plan's, docs/method.md §3): a session of
        that plan solved its trim, so its recording solves with it too.
        """
        entry = PLANS.get(self.plan_name) if self.plan_name else None
        if entry is None or not entry.trim or not self._plan_poses(averages):
            return spec
        return replace(spec, trim=True)

    def tolerances(self, averages: Sequence[PositionAverage]) -> list[PositionAverage]:
        """Give each average its plan position's tolerances when the poses are the plan's."""
        plan = self.plan
        if plan is None or not self.matches(averages):
            return list(averages)
        return [
            replace(a, pose=replace(a.pose, tolerance=p.tolerance, psi_tolerance=p.psi_tolerance))
            for a, p in zip(averages, plan.positions, strict=True)
        ]

    def prior(self, spec: JointSpec, accel_lsb: float) -> dict[str, tuple[float, float]]:
        """Return the prior on K the plan (or the flags) hold: the factory K, else nominal.

        ``--prior-k`` alone, with a plan that names no σ, holds K at 1 % (the vehicle
        plan's own value).
        """
        plan = self.plan or Plan(CUSTOM, ())
        sigma = self.prior_k_sigma
        if sigma is None and self.factory_k is not None and plan.prior_k_sigma is None:
            sigma = VEHICLE_PRIOR_K_SIGMA
        return plan_prior(plan, spec, accel_lsb, factory_k=self.factory_k, k_sigma=sigma)


def session_model(rec: Recording, choice: ModelChoice) -> tuple[ModelChoice, SessionModel]:
    """Fill the options ``choice`` leaves unset from the header; the session's plan and prior."""
    header = rec.header
    model = choice.model or str(header.get("model", "diag"))
    if model not in ("diag", "full"):
        raise InputError(f"header model must be diag or full, got {model!r}")
    tilt, tilt_model = choice.tilt, choice.tilt_model
    if tilt is None:
        header_tilt = str(header.get("tilt", "none"))
        tilt = header_tilt != "none"
        if tilt_model is None and tilt:
            tilt_model = header_tilt  # type: ignore[assignment]
    gyro = choice.gyro
    if gyro is None and "gyro" in header:
        gyro = str(header["gyro"])  # type: ignore[assignment]
    tolerance, tolerance_source = choice.tolerance_deg, "flag"
    if tolerance is None:
        value = header.get("tolerance_deg")
        tolerance_source = "header" if isinstance(value, int | float) else "default"
        tolerance = float(value) if isinstance(value, int | float) else DEFAULT_TOLERANCE_DEG
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise InputError(
            f"tolerance_deg must be a finite number >= 0, got {tolerance:g}",
            options=("tolerance_deg",),
        )
    if choice.prior_k_sigma is not None and not choice.prior_k_sigma > 0:
        raise InputError(
            f"prior_k_sigma must be > 0, got {choice.prior_k_sigma:g}", options=("prior_k_sigma",)
        )
    name = header.get("plan")
    entry = PLANS.get(name) if isinstance(name, str) else None
    plan = None if entry is None else entry.plan
    plan_name = None if entry is None else entry.name
    factory_k, source, sigma = (None, "factory K", choice.prior_k_sigma)
    if choice.prior_k:
        factory_k, source = read_factory_k(choice.prior_k), f"K from {Path(choice.prior_k).name}"
    elif (held := header_prior(header)) is not None:  # the prior the session held
        if sigma is not None:
            held = replace(held, rel_sigma=sigma, sigma_source="--prior-k-sigma")
        factory_k, sigma = held.mean, held.rel_sigma
        source = held.describe(plan or Plan(CUSTOM, ()))
    resolved = replace(
        choice,
        model=model,  # type: ignore[arg-type]
        tilt=tilt,
        tilt_model=tilt_model or "rigid",
        gyro=gyro,
        gyro_g=choice.gyro_g or header.get("gyro_g") is True,
        tolerance_deg=tolerance,
    )
    session = SessionModel(
        plan_name,
        plan,
        tolerance,
        sigma,
        plan_tolerances=choice.tolerance_deg is None,
        factory_k=factory_k,
        prior_source=source,
        tolerance_source=tolerance_source,
    )
    return resolved, session


def header_prior(header: Mapping[str, HeaderValue]) -> KPrior | None:
    """Return the prior on K a session held (header ``prior_k`` and kin), None without one."""
    if "prior_k" not in header:
        return None
    return KPrior(
        header_matrix(header["prior_k"]),
        str(header.get("prior_k_source", "the recording's header")),
        float(header.get("prior_k_sigma", VEHICLE_PRIOR_K_SIGMA)),
        str(header.get("prior_k_sigma_source", "the recording's header")),
    )


def read_factory_k(path: str) -> NDArray[np.float64]:
    """Return the accelerometer K of a calibration JSON or of ``read-params --json`` output."""
    from canimucal.schema import parse_json, read_text

    document = parse_json(read_text(path), path)
    if isinstance(document, dict) and isinstance(document.get("calibration"), dict):
        document = document["calibration"]  # read-params output: the block the node holds
    record = Calibration.from_dict(document)
    k = np.array([[np.nan if v is None else v for v in row] for row in record.accel.K or ()])
    if k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise InputError(
            f"{path}: prior_k needs a complete accel.K (3×3, no nulls)", options=("prior_k",)
        )
    check_prior_k(k, path)
    return k


PRIOR_K_MAX_CONDITION = 1e6
"""Largest condition number of a prior K: a K that maps some direction to (almost) nothing
cannot be a unit's scale factors."""


def check_prior_k(k: NDArray[np.float64], source: str) -> None:
    """Refuse a singular K, and one whose axes are mirrored or swapped (InputError, exit 2).

    A prior holds K near the unit's nominal ``I / LSB``: every axis counts along itself
    (each row's diagonal entry outweighs the rest of the row), all with one sign (the
    LSB's), and ``det K`` has the sign of the diagonal's product. One axis negated or two
    swapped is a mirror image, which no scale-factor error produces.
    """
    if not np.linalg.cond(k) < PRIOR_K_MAX_CONDITION:
        raise InputError(
            f"{source}: the accel.K of prior_k is singular (or nearly)", options=("prior_k",)
        )
    diag = np.diag(k)
    off = np.sum(np.abs(k), axis=1) - np.abs(diag)
    same_sign = bool(np.all(diag > 0) or np.all(diag < 0))
    dominant = bool(np.all(np.abs(diag) > off))
    handed = np.sign(np.linalg.det(k)) == np.sign(np.prod(diag))
    if not (same_sign and dominant and handed):
        raise InputError(
            f"{source}: the accel.K of prior_k is mirrored or has axes swapped (a prior must "
            "be near the unit's K = I/LSB: each axis along itself, all with one sign)",
            options=("prior_k",),
        )
