"""The calibration JSON (docs/design.md §5): a frozen record, a strict reader, an atomic writer.

:class:`Calibration` mirrors the file key for key; nothing else is allowed in it (a
solver's warnings travel beside the record, not inside it). Arrays are tuples whose elements
may be ``None`` (a ``null``: "not estimated: nominal"). A key that is absent and a key that
is ``null`` mean the same and both read as ``None``; the writer omits ``None`` fields.

Units as in the file: counts, counts per m/s² (K, G), counts per rad/s (S), degrees for the
base tilt and the mounting trim, m/s² for ``fit.rms``. The ``covariance`` block keeps the
order of the solver's parameter vector; its rows and columns of ``base_tilt.*`` and
``mounting_trim.*`` are in **degrees** (the vector the solver works with is in radians):
:func:`~canimucal.io.calibration.covariance_si` converts back.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal import schema as cs
from canimucal.errors import InputError, ModelError, SchemaError
from canimucal.io.atomic import write_text_atomic
from canimucal.model.positions import PositionAverage
from canimucal.model.vocabulary.plans import PLANS
from canimucal.version import __version__

POSE_SCATTER_BASES = ("estimated", "upper bound", "plan tolerance", "assumed")
"""``fit.pose_scatter_basis``: the REML estimate, the upper end of its 95 % interval (few
residuals), the plan's tolerance (above that bound), or the plans' default (no residuals)."""

SCHEMA = "canimucal.calibration/1"
"""The only calibration schema this version reads and writes."""

Vector = tuple[float | None, ...]
Matrix = tuple[Vector, ...]


@dataclass(frozen=True, kw_only=True)
class Tool:
    """``tool``: name and version of the program that wrote the file."""

    name: str | None = field(default=None, metadata=cs.text())
    version: str | None = field(default=None, metadata=cs.text())


@dataclass(frozen=True, kw_only=True)
class Device:
    """``device``: identity of the calibrated unit (0x1018) and its node id."""

    node_id: int | None = field(default=None, metadata=cs.integer(1, 127))
    vendor_id: int | None = field(default=None, metadata=cs.integer(0, 0xFFFFFFFF))
    product_code: int | None = field(default=None, metadata=cs.integer(0, 0xFFFFFFFF))
    revision: int | None = field(default=None, metadata=cs.integer(0, 0xFFFFFFFF))
    serial: int = field(metadata=cs.integer(0, 0xFFFFFFFF))


@dataclass(frozen=True, kw_only=True)
class Conditions:
    """``conditions``: gravity and place the calibration was made at."""

    g: float | None = field(default=None, metadata=cs.number(low=0.0, open_low=True))
    latitude_deg: float | None = field(default=None, metadata=cs.number(-90.0, 90.0))
    height_m: float | None = field(default=None, metadata=cs.number())
    heading_deg: float | None = field(default=None, metadata=cs.number())
    temp_c: float | None = field(default=None, metadata=cs.number())


@dataclass(frozen=True, kw_only=True)
class AccelBlock:
    """``accel``: bias (counts) and K (counts per m/s²) with their 1σ."""

    bias: Vector = field(metadata=cs.array((3,)))
    bias_sigma: Vector | None = field(default=None, metadata=cs.array((3,)))
    K: Matrix = field(metadata=cs.array((3, 3)))
    K_sigma: Matrix | None = field(default=None, metadata=cs.array((3, 3)))

    def bias_counts(self) -> NDArray[np.float64]:
        """Return the bias as numpy (counts), ``null`` entries 0 (nominal)."""
        return with_nominal(self.bias, np.zeros(3))

    def K_matrix(self, nominal_lsb: float | None = None) -> NDArray[np.float64]:
        """Return K as numpy (counts per m/s²), ``null`` entries nominal (``I / lsb``)."""
        return with_nominal(self.K, _nominal_scale(self.K, nominal_lsb, "accel.K"))

    def correct(self, counts: ArrayLike, nominal_lsb: float | None = None) -> NDArray[np.float64]:
        """Specific force (m/s²) from raw outputs: ``K⁻¹ (U − b)`` (as the firmware applies).

        ``counts`` is ``(3,)`` or ``(n, 3)``. ``nominal_lsb`` (m/s² per count) stands in for
        entries of K the calibration holds ``null``; it is needed only when there are any.
        """
        return _apply_inverse(
            self.K_matrix(nominal_lsb), np.asarray(counts, float) - self.bias_counts(), "accel.K"
        )


@dataclass(frozen=True, kw_only=True)
class GyroBlock:
    """``gyro``: bias (counts), S (counts per rad/s), G (counts per m/s²) with their 1σ."""

    bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    bias_sigma: Vector | None = field(default=None, metadata=cs.array((3,)))
    S: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    S_sigma: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    G: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    G_sigma: Matrix | None = field(default=None, metadata=cs.array((3, 3)))

    def bias_counts(self) -> NDArray[np.float64]:
        """Return the bias as numpy (counts), ``null`` entries 0 (nominal)."""
        return with_nominal(self.bias, np.zeros(3))

    def S_matrix(self, nominal_lsb: float | None = None) -> NDArray[np.float64]:
        """Return S as numpy (counts per rad/s), ``null`` entries nominal (``I / lsb``)."""
        return with_nominal(self.S, _nominal_scale(self.S, nominal_lsb, "gyro.S"))

    def G_matrix(self) -> NDArray[np.float64]:
        """Return G as numpy (counts per m/s²), ``null`` entries 0 (nominal)."""
        return with_nominal(self.G, np.zeros((3, 3)))

    def correct(
        self,
        counts: ArrayLike,
        specific_force: ArrayLike | None = None,
        nominal_lsb: float | None = None,
    ) -> NDArray[np.float64]:
        """Angular rate (rad/s) from raw outputs: ``S⁻¹ (V − B − G f)`` (the firmware's).

        ``specific_force`` (m/s², e.g. from :meth:`AccelBlock.correct`) is needed when G is
        estimated; ``nominal_lsb`` (rad/s per count) stands in for ``null`` entries of S.
        """
        v = np.asarray(counts, float) - self.bias_counts()
        if specific_force is not None:
            v = v - np.asarray(specific_force, float) @ self.G_matrix().T
        elif np.any(self.G_matrix() != 0.0):
            raise ModelError("gyro.G is estimated: give the specific force to correct the gyro")
        return _apply_inverse(self.S_matrix(nominal_lsb), v, "gyro.S")


@dataclass(frozen=True, kw_only=True)
class BaseTilt:
    """``base_tilt_deg``: the constant tilt of the base, degrees, with 1σ of both."""

    alpha0: float | None = field(default=None, metadata=cs.number())
    beta0: float | None = field(default=None, metadata=cs.number())
    sigma: Vector | None = field(default=None, metadata=cs.array((2,)))


@dataclass(frozen=True, kw_only=True)
class MountingTrim:
    """``mounting_trim_deg``: the unit's small rotation in the vehicle, degrees, with 1σ.

    ``R_m = Ay(psi) A2(beta) A1(alpha)`` (unit ← vehicle), the angle convention of a position
    (docs/design.md §2): ``alpha`` about the unit's z, then ``beta`` about the new x, then
    ``psi`` about y. Absent (or ``null``): not determined by the plan (written as zero).
    """

    alpha: float | None = field(default=None, metadata=cs.number())
    beta: float | None = field(default=None, metadata=cs.number())
    psi: float | None = field(default=None, metadata=cs.number())
    sigma: Vector | None = field(default=None, metadata=cs.array((3,)))

    def radians(self) -> NDArray[np.float64]:
        """``(alpha, beta, psi)`` in radians, ``null`` entries 0."""
        return np.deg2rad([self.alpha or 0.0, self.beta or 0.0, self.psi or 0.0])


@dataclass(frozen=True, kw_only=True)
class Covariance:
    """``covariance``: parameter order and matrix (tilt rows/columns in degrees)."""

    order: tuple[str, ...] = field(metadata=cs.names())
    matrix: tuple[tuple[float, ...], ...] = field(metadata=cs.square())


@dataclass(frozen=True, kw_only=True)
class PositionSummary:
    """One entry of ``positions``: the pose (degrees) and what was measured there."""

    alpha_deg: float | None = field(default=None, metadata=cs.number())
    beta_deg: float | None = field(default=None, metadata=cs.number())
    psi_deg: float | None = field(default=None, metadata=cs.number())
    seconds: float | None = field(default=None, metadata=cs.number(low=0.0))
    n: int | None = field(default=None, metadata=cs.integer(0, None))
    lost: int | None = field(default=None, metadata=cs.integer(0, None))
    mean_accel: Vector | None = field(default=None, metadata=cs.array((3,)))
    mean_gyro: Vector | None = field(default=None, metadata=cs.array((3,)))
    std_accel: Vector | None = field(default=None, metadata=cs.array((3,)))
    std_gyro: Vector | None = field(default=None, metadata=cs.array((3,)))
    temp_c: float | None = field(default=None, metadata=cs.number())
    trial: int | None = field(default=None, metadata=cs.integer(-1, None))


@dataclass(frozen=True, kw_only=True)
class TrialSummary:
    """One entry of ``trials``: one mounting of the unit and the biases it had (counts).

    K, S and G are shared by every trial; the ``accel.bias`` of the record is the trials'
    mean (docs/design.md §5, Trials). ``trial`` is the recording's trial number (-1: the
    rows whose trial cell was empty).
    """

    trial: int = field(metadata=cs.integer(-1, None))
    positions: int | None = field(default=None, metadata=cs.integer(0, None))
    accel_bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    accel_bias_sigma: Vector | None = field(default=None, metadata=cs.array((3,)))
    gyro_bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    gyro_bias_sigma: Vector | None = field(default=None, metadata=cs.array((3,)))


@dataclass(frozen=True, kw_only=True)
class Fit:
    """``fit``: residual rms after correction (m/s²), dof, and the pose scatter of the σ.

    ``pose_scatter_deg`` and ``pose_scatter_basis`` are written by ``solve`` when no
    tolerance was given: the scatter the σ rest on and why that value (docs/design.md §10).
    """

    rms: float | None = field(default=None, metadata=cs.number(low=0.0))
    dof: int | None = field(default=None, metadata=cs.integer(0, None))
    pose_scatter_deg: float | None = field(default=None, metadata=cs.number(low=0.0))
    pose_scatter_basis: str | None = field(
        default=None, metadata=cs.text(choices=POSE_SCATTER_BASES)
    )


@dataclass(frozen=True, kw_only=True)
class RecordingRef:
    """``recording``: the recording the calibration was solved from."""

    file: str | None = field(default=None, metadata=cs.text())
    sha256: str | None = field(default=None, metadata=cs.text(pattern=r"[0-9a-f]{64}"))


@dataclass(frozen=True, kw_only=True)
class Readback:
    """``readback`` (``demo --headless``; ``write-params`` ignores it): values read back."""

    accel_bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    accel_correction: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    gyro_bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    gyro_correction: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    gyro_g: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    base_tilt_rad: Vector | None = field(default=None, metadata=cs.array((2,)))
    mounting_trim_rad: Vector | None = field(default=None, metadata=cs.array((3,)))
    valid: int | None = field(default=None, metadata=cs.integer(0, 1))
    crc_ok: bool | None = field(default=None, metadata=cs.boolean())


@dataclass(frozen=True, kw_only=True)
class Acceptance:
    """``acceptance``: the limits a calibration is checked against, its values, the verdict.

    ``limits`` and ``values`` share keys (``max_bias_sigma_mg`` is the limit of
    ``values["max_bias_sigma_mg"]``, the worst bias σ in mg).
    """

    passed: bool = field(metadata=cs.boolean())
    limits: dict[str, float] = field(default_factory=dict, metadata=cs.number_map())
    values: dict[str, float] = field(default_factory=dict, metadata=cs.number_map())


@dataclass(frozen=True, kw_only=True)
class Verification:
    """``verification``: the check at level after the write, against a stated limit.

    ``done`` is false when the session ended before it (``passed`` is then false too);
    ``values`` and ``limits`` share keys, as in :class:`Acceptance`.
    """

    passed: bool = field(metadata=cs.boolean())
    done: bool = field(metadata=cs.boolean())
    written: bool | None = field(default=None, metadata=cs.boolean())
    limits: dict[str, float] = field(default_factory=dict, metadata=cs.number_map())
    values: dict[str, float] = field(default_factory=dict, metadata=cs.number_map())


@dataclass(frozen=True, kw_only=True)
class Prior:
    """One entry of ``priors``: a parameter held at a stated prior (mean, 1σ, where from).

    Its value and σ in the record are the posterior: the prior combined with the data.
    """

    name: str = field(metadata=cs.text(pattern=r"[a-z_]+\.[A-Za-z_]+(\[\d\])*"))
    mean: float = field(metadata=cs.number())
    sigma: float = field(metadata=cs.number(low=0.0, open_low=True))
    source: str | None = field(default=None, metadata=cs.text())


@dataclass(frozen=True, kw_only=True)
class Calibration:
    """The whole calibration JSON (see the module doc for ``None`` and units)."""

    schema: str = field(default=SCHEMA, metadata=cs.text(choices=(SCHEMA,)))
    created: str | None = field(default=None, metadata=cs.timestamp())
    plan: str | None = field(default=None, metadata=cs.text(choices=PLANS))  # the registry
    tool: Tool | None = field(default=None, metadata=cs.block(Tool))
    device: Device = field(metadata=cs.block(Device))
    conditions: Conditions | None = field(default=None, metadata=cs.block(Conditions))
    accel: AccelBlock = field(metadata=cs.block(AccelBlock))
    gyro: GyroBlock | None = field(default=None, metadata=cs.block(GyroBlock))
    base_tilt_deg: BaseTilt | None = field(default=None, metadata=cs.block(BaseTilt))
    mounting_trim_deg: MountingTrim | None = field(default=None, metadata=cs.block(MountingTrim))
    covariance: Covariance | None = field(default=None, metadata=cs.block(Covariance))
    positions: tuple[PositionSummary, ...] | None = field(
        default=None, metadata=cs.block_list(PositionSummary)
    )
    trials: tuple[TrialSummary, ...] | None = field(
        default=None, metadata=cs.block_list(TrialSummary)
    )
    fit: Fit | None = field(default=None, metadata=cs.block(Fit))
    recording: RecordingRef | None = field(default=None, metadata=cs.block(RecordingRef))
    objects: dict[str, int | float] | None = field(default=None, metadata=cs.objects())
    objects_raw: dict[str, str] | None = field(default=None, metadata=cs.raw_objects())
    """Objects JSON numbers cannot hold (NaN, ±inf), as their SDO bytes in hex."""
    readback: Readback | None = field(default=None, metadata=cs.block(Readback))
    acceptance: Acceptance | None = field(default=None, metadata=cs.block(Acceptance))
    priors: tuple[Prior, ...] | None = field(default=None, metadata=cs.block_list(Prior))
    verification: Verification | None = field(default=None, metadata=cs.block(Verification))

    @classmethod
    def from_json(cls, path: str | os.PathLike[str]) -> Calibration:
        """Read and validate a calibration JSON file (:class:`InputError` on any problem)."""
        return read_calibration(Path(path))

    @classmethod
    def from_dict(cls, document: Any) -> Calibration:
        """Validate a calibration JSON object given as Python data (same rules as a file)."""
        return _record_of(document, "calibration")

    def to_json(self, path: str | os.PathLike[str], *, overwrite: bool = False) -> Path:
        """Write this calibration atomically; an existing file only with ``overwrite``."""
        return write_calibration(path, self, overwrite=overwrite)

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON object (``None`` fields omitted, tuples as lists)."""
        return calibration_to_dict(self)


def with_nominal(
    value: Vector | Matrix | None, nominal: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Return ``value`` as numpy with its ``null`` entries (or all, when None) from ``nominal``."""
    if value is None:
        return nominal.copy()
    out = np.array(value, dtype=float).reshape(nominal.shape)  # None entries become NaN
    return np.where(np.isnan(out), nominal, out)


def _nominal_scale(value: Matrix | None, lsb: float | None, name: str) -> NDArray[np.float64]:
    """``I / lsb``, the nominal K or S; refused when needed for a ``null`` and ``lsb`` is None."""
    if lsb is None:
        if value is None or any(v is None for row in value for v in row):
            raise ModelError(f"{name} has entries held at nominal: give the nominal LSB")
        return np.zeros((3, 3))
    return np.eye(3) / lsb


def _apply_inverse(
    matrix: NDArray[np.float64], rhs: NDArray[np.float64], name: str
) -> NDArray[np.float64]:
    try:
        return np.asarray(np.linalg.solve(matrix, rhs.T).T, dtype=np.float64)
    except np.linalg.LinAlgError:
        raise ModelError(f"{name} is singular: it cannot correct the outputs") from None


# --------------------------------------------------------------------------- read / write


def read_calibration(path_or_text: str | os.PathLike[str]) -> Calibration:
    """Read and validate a calibration JSON; every problem is an :class:`InputError`.

    A :class:`~pathlib.Path` is read as a file; a ``str`` is JSON text when it starts with
    ``{`` (after blanks), a file name otherwise.
    """
    source, text = cs.load_text(path_or_text, "calibration")
    return _record_of(cs.parse_json(text, source), source)


def _record_of(document: Any, source: str) -> Calibration:
    """Build the typed record of a parsed document; errors name ``source``."""
    if not isinstance(document, dict):
        raise InputError(f"{source}: top level is not a JSON object")
    if document.get("schema") != SCHEMA:
        found = document.get("schema")
        raise InputError(f"{source}: schema must be {SCHEMA!r}, got {found!r}")
    try:
        record = cs.build(Calibration, document, "")
    except SchemaError as exc:
        raise InputError(f"{source}: {exc}") from None
    _check_covariance(record, source)
    return record


def _check_covariance(record: Calibration, source: str) -> None:
    cov = record.covariance
    if cov is None:
        return
    if len(cov.matrix) != len(cov.order):
        n, m = len(cov.order), len(cov.matrix)
        raise InputError(f"{source}: covariance.matrix is {m}x{m}, order names {n} parameters")
    if cov.matrix:
        matrix = np.array(cov.matrix)
        scale = max(float(np.max(np.abs(np.diag(matrix)))), 1e-300)
        if np.any(np.diag(matrix) < 0) or np.max(np.abs(matrix - matrix.T)) > 1e-9 * scale:
            raise InputError(f"{source}: covariance.matrix is not a covariance (symmetric, ≥ 0)")


def calibration_to_dict(record: Calibration) -> dict[str, Any]:
    """Return the JSON object of ``record`` (``None`` fields omitted, tuples as lists)."""
    return cs.to_plain(record)


def calibration_to_json(record: Calibration) -> str:
    """Return the JSON text of ``record``: indent 2, keys in the contract's order, final newline."""
    return json.dumps(calibration_to_dict(record), indent=2, allow_nan=False) + "\n"


def write_calibration(
    path: str | os.PathLike[str], record: Calibration, *, overwrite: bool
) -> Path:
    """Validate ``record`` like a reader would, then write it atomically."""
    try:
        text = calibration_to_json(record)
    except ValueError as exc:  # json refuses NaN/inf: name it like the reader would
        raise InputError(f"{path}: calibration holds a non-finite number ({exc})") from exc
    read_calibration(text)
    return write_text_atomic(path, text, overwrite=overwrite)


def sha256_of(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes (for ``recording.sha256``)."""
    return cs.sha256_of(path)


def as_array(value: Vector | Matrix | None, shape: tuple[int, ...]) -> NDArray[np.float64]:
    """Return a record array as numpy, NaN for ``null`` entries (all NaN when ``value`` is None)."""
    if value is None:
        return np.full(shape, np.nan)
    out = np.array(value, dtype=float)  # None elements become NaN
    return out.reshape(shape)


logger = logging.getLogger(__name__)

_RAD_TO_DEG = 180.0 / np.pi
_SCALED_MATRICES = ("accel.K", "gyro.S")
"""Matrices whose off-diagonal is held at 0.0 (sigma null) when only the diagonal is solved."""


def record_from_estimates(
    names: Sequence[str],
    values: ArrayLike,
    covariance: ArrayLike,
    *,
    device: Device,
    held_fixed: Mapping[str, str] | None = None,
    plan: str | None = None,
    created: str | None = None,
    tool: Tool | None = None,
    conditions: Conditions | None = None,
    positions: Sequence[PositionSummary] | None = None,
    fit: Fit | None = None,
    recording: RecordingRef | None = None,
    priors: Sequence[Prior] | None = None,
) -> Calibration:
    """Build a record from a solver's named parameter vector and its covariance.

    ``names`` follow ``accel.bias[i]``, ``accel.K[i][j]``, ``gyro.bias[i]``, ``gyro.S[i][j]``,
    ``gyro.G[i][j]``, ``base_tilt.alpha0``/``beta0``, ``mounting_trim.alpha/beta/psi``; tilt
    and trim values are **radians** in ``values`` and ``covariance`` and come out in degrees
    (``base_tilt_deg``, ``mounting_trim_deg`` and their rows/columns of ``covariance.matrix``).
    A parameter not in ``names`` is ``null`` (value and sigma), except the off-diagonal of K
    or S when some of its diagonal was solved: those were held at zero by the model and read
    ``0.0`` with a ``null`` sigma.
    ``held_fixed`` maps names the solver could not identify to the reason; they are ``null``
    and the reasons are logged (warnings travel beside the record, not in it).
    """
    held = dict(held_fixed or {})
    x, cov = _check_estimates(list(names), values, covariance, held)
    for name, reason in held.items():
        logger.info("%s not estimated: %s", name, reason)
    sigma = np.sqrt(np.diag(cov))
    table = {n: (float(v), float(s)) for n, v, s in zip(names, x, sigma, strict=True)}
    everything = [*names, *held]
    accel, gyro = _sensor_blocks(table, held, everything)
    return Calibration(
        created=created or _utc_now(),
        plan=plan,
        tool=tool or Tool(name="canimucal", version=_tool_version()),
        device=device,
        conditions=conditions,
        accel=accel,
        gyro=gyro,
        base_tilt_deg=_base_tilt(table, everything),
        mounting_trim_deg=_mounting_trim(table, everything),
        covariance=_covariance_deg(list(names), cov) if len(names) else None,
        positions=tuple(positions) if positions is not None else None,
        fit=fit,
        recording=recording,
        priors=tuple(priors) if priors else None,
    )


def re_estimated(
    old: Calibration,
    names: Sequence[str],
    values: ArrayLike,
    covariance: ArrayLike,
    held_fixed: Mapping[str, str] | None = None,
) -> Calibration:
    """Return ``old`` with new estimates (:func:`record_from_estimates`), its context kept.

    Device, plan, creation time, conditions, positions, fit, recording and priors carry
    over: a later fit (the gyro's S from the moves) replaces numbers, not the session.
    """
    return record_from_estimates(
        names,
        values,
        covariance,
        device=old.device,
        held_fixed=held_fixed,
        plan=old.plan,
        created=old.created,
        conditions=old.conditions,
        positions=old.positions,
        fit=old.fit,
        recording=old.recording,
        priors=old.priors,
    )


def _sensor_blocks(
    table: Mapping[str, tuple[float, float]], held: Mapping[str, str], everything: list[str]
) -> tuple[AccelBlock, GyroBlock | None]:
    """Build the ``accel`` block, and the ``gyro`` block when a gyro parameter is named."""
    accel = AccelBlock(
        bias=_vector("accel.bias", table, 0),
        bias_sigma=_vector("accel.bias", table, 1),
        K=_matrix("accel.K", table, held, 0),
        K_sigma=_matrix("accel.K", table, held, 1),
    )
    if not any(n.startswith("gyro.") for n in everything):
        return accel, None
    gyro = GyroBlock(
        bias=_vector("gyro.bias", table, 0),
        bias_sigma=_vector("gyro.bias", table, 1),
        S=_matrix("gyro.S", table, held, 0),
        S_sigma=_matrix("gyro.S", table, held, 1),
        G=_matrix("gyro.G", table, held, 0),
        G_sigma=_matrix("gyro.G", table, held, 1),
    )
    return accel, gyro


def _check_estimates(
    names: list[str], values: ArrayLike, covariance: ArrayLike, held: Mapping[str, str]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    n = len(names)
    for name in [*names, *held]:
        if not cs.PARAMETER_NAME.fullmatch(name):
            raise ModelError(f"unknown parameter name {name!r}")
    if len(set(names)) != n or set(names) & set(held):
        raise ModelError("parameter names repeat, or are both estimated and held fixed")
    x = np.asarray(values, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    if x.shape != (n,) or cov.shape != (n, n):
        raise ModelError(f"need {n} values and a {n}x{n} covariance, got {x.shape}, {cov.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(cov))):
        raise ModelError("estimates and covariance must be finite")
    cov = 0.5 * (cov + cov.T)
    if np.any(np.diag(cov) < 0):
        raise ModelError("covariance has a negative variance")
    return x, cov


def _vector(prefix: str, table: Mapping[str, tuple[float, float]], k: int) -> Vector:
    return tuple(
        table[f"{prefix}[{i}]"][k] if f"{prefix}[{i}]" in table else None for i in range(3)
    )


def _matrix(
    prefix: str, table: Mapping[str, tuple[float, float]], held: Mapping[str, str], k: int
) -> Matrix:
    diagonal_solved = any(f"{prefix}[{i}][{i}]" in table for i in range(3))
    zero_off = prefix in _SCALED_MATRICES and diagonal_solved

    def entry(i: int, j: int) -> float | None:
        name = f"{prefix}[{i}][{j}]"
        if name in table:
            return table[name][k]
        if zero_off and i != j and name not in held:
            return 0.0 if k == 0 else None
        return None

    return tuple(tuple(entry(i, j) for j in range(3)) for i in range(3))


def _base_tilt(table: Mapping[str, tuple[float, float]], everything: list[str]) -> BaseTilt | None:
    if not any(n.startswith("base_tilt.") for n in everything):
        return None

    def degrees(name: str, k: int) -> float | None:
        return table[name][k] * _RAD_TO_DEG if name in table else None

    return BaseTilt(
        alpha0=degrees("base_tilt.alpha0", 0),
        beta0=degrees("base_tilt.beta0", 0),
        sigma=(degrees("base_tilt.alpha0", 1), degrees("base_tilt.beta0", 1)),
    )


def _mounting_trim(
    table: Mapping[str, tuple[float, float]], everything: list[str]
) -> MountingTrim | None:
    if not any(n.startswith("mounting_trim.") for n in everything):
        return None

    def degrees(name: str, k: int) -> float | None:
        return table[name][k] * _RAD_TO_DEG if name in table else None

    axes = ("alpha", "beta", "psi")
    return MountingTrim(
        alpha=degrees("mounting_trim.alpha", 0),
        beta=degrees("mounting_trim.beta", 0),
        psi=degrees("mounting_trim.psi", 0),
        sigma=tuple(degrees(f"mounting_trim.{a}", 1) for a in axes),
    )


_ANGLE_FAMILIES = ("base_tilt.", "mounting_trim.")
"""Parameters held in radians by the solver and in degrees by the file."""


def _tilt_scale(names: Sequence[str]) -> NDArray[np.float64]:
    return np.array([_RAD_TO_DEG if n.startswith(_ANGLE_FAMILIES) else 1.0 for n in names])


def _covariance_deg(names: list[str], cov: NDArray[np.float64]) -> Covariance:
    scale = _tilt_scale(names)
    matrix = cov * np.outer(scale, scale)
    return Covariance(order=tuple(names), matrix=tuple(tuple(row) for row in matrix.tolist()))


def covariance_si(record: Calibration) -> tuple[list[str], NDArray[np.float64]]:
    """Return the record's covariance with tilt rows/columns back in radians (empty when absent)."""
    if record.covariance is None:
        return [], np.zeros((0, 0))
    names = list(record.covariance.order)
    scale = _tilt_scale(names)
    return names, np.array(record.covariance.matrix, dtype=float) / np.outer(scale, scale)


def slope_trim_correlation(record: Calibration) -> float | None:
    """Return the largest correlation (by magnitude) between floor slope and mounting trim.

    From the record's covariance; None when it holds no tilt or no trim. Turning the vehicle
    on the spot is what keeps it small (docs/method.md §3).
    """
    names, cov = covariance_si(record)
    tilt = [k for k, n in enumerate(names) if n.startswith("base_tilt.")]
    trim = [k for k, n in enumerate(names) if n.startswith("mounting_trim.")]
    if not tilt or not trim:
        return None
    sd = np.sqrt(np.abs(np.diag(cov)))
    corr = cov[np.ix_(tilt, trim)] / np.outer(sd[tilt], sd[trim])
    k = int(np.argmax(np.abs(corr)))
    return float(corr.flat[k])


def summarize_position(average: PositionAverage) -> PositionSummary:
    """Summarise one average as a ``positions`` entry (angles in degrees, NaN as ``null``)."""

    def vec(x: NDArray[np.float64] | None) -> Vector | None:
        return None if x is None else tuple(None if np.isnan(v) else float(v) for v in x)

    def deg(angle: float) -> float | None:
        return None if np.isnan(angle) else float(np.rad2deg(angle))

    return PositionSummary(
        alpha_deg=deg(average.pose.alpha),
        beta_deg=deg(average.pose.beta),
        psi_deg=deg(average.pose.psi),
        seconds=float(average.seconds),
        n=int(average.n),
        lost=int(average.lost),
        mean_accel=vec(average.mean_accel),
        mean_gyro=vec(average.mean_gyro),
        std_accel=vec(average.std_accel),
        std_gyro=vec(average.std_gyro),
        temp_c=average.temp_c,
        trial=average.trial,
    )


def _utc_now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _tool_version() -> str:

    return __version__
