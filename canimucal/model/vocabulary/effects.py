"""The candidate effects of the discrepancy loop (docs/design.md §6), defined once.

An :class:`Effect` is what the base model (bias + diagonal scale + white noise) may be
missing: its name, the sensors it applies to, one line of wording, the units of its size,
and, for an effect that enters the data linearly, its model columns as pure numpy functions:

- ``known`` for the joint fit at labelled poses: ``(PoseInputs, sensor) -> (n, channels, q)``,
  the derivative of every channel's prediction with respect to the ``q`` entries, one row per
  pose (a position's mean, or one sample of the simulator);
- ``scalar`` for the ``|f| = g`` fit at unknown poses: ``(ScalarInputs, sensor) -> (rows, q)``.

``truth`` says where the simulator's truth JSON holds an entry (``{sensor}``, ``{label}``,
``{name}`` and the entry's number ``{k}`` filled in; times ``truth_per_unit``). An effect
whose path is under ``effects.`` needs no physics of its own in the simulator: the simulator
adds ``known(inputs) @ coefficients`` to its outputs, so a new effect is one registration::

    EFFECTS.register(Effect("cubic", ("accel",), "a cubic term of each axis",
                            "counts per (m/s²)³", labels=("cubic[0]", "cubic[1]", "cubic[2]"),
                            known=lambda x, s: per_channel(x, [(i, x.f[:, i] ** 3)
                                                               for i in range(3)])))

The simulator hides it (:func:`canimucal.sim.effects.hide_effect`), ``analyze`` tests it,
names it, and writes it to ``--truth-out``; the analysis JSON lists its tests.
``bias_drift`` (slopes inside the positions) and ``axis_sign`` (a sign check of K) are tested
by the loop itself and have no columns.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import ModelError
from canimucal.model.dcm_stack import dcm_stack
from canimucal.model.frames import specific_force_level
from canimucal.model.vocabulary.registry import Registry

Array = NDArray[np.float64]
Sensor = Literal["accel", "gyro"]

GENERIC_TRUTH = "effects.{sensor}.{name}[{k}]"
"""Where the truth JSON holds an effect the simulator applies through its columns."""


@dataclass(frozen=True)
class PoseInputs:
    """What a known-pose column builder may use, one row per pose.

    ``angles`` ``(n, 3)`` rad; ``f`` the body specific force at those poses ``(n, 3)``
    m/s²; ``k_matrix`` and ``s_matrix`` the scale matrices the columns are linearised at
    (counts per m/s², per rad/s); ``w_level`` the Earth rate in the level frame (rad/s);
    ``channels`` 3 (accelerometer) or 6 (with gyro); ``temperatures`` ``(n,)`` °C from a
    reference (None: no temperature recorded).
    """

    angles: Array
    f: Array
    g: float
    k_matrix: Array
    s_matrix: Array
    w_level: Array
    channels: int
    temperatures: Array | None = None

    @classmethod
    def at(
        cls,
        angles: Array,
        *,
        g: float,
        k_matrix: Array,
        s_matrix: Array,
        w_level: Array,
        channels: int,
        temperatures: Array | None = None,
    ) -> PoseInputs:
        """Return the inputs at poses ``angles``, no base tilt: ``f = C(alpha, beta, psi) f_L``."""
        c, _, _ = dcm_stack(angles, 0.0, 0.0, "rigid")
        f = c @ specific_force_level(g)
        return cls(angles, f, g, k_matrix, s_matrix, w_level, channels, temperatures)


@dataclass(frozen=True)
class ScalarInputs:
    """The scalar ``|f| = g`` base fit the scalar columns are linearised at.

    ``means`` ``(n, 3)`` accelerometer means (counts), ``bias`` and ``m_matrix`` (``K⁻¹``)
    of the fit; rows are the ``n`` accelerometer residuals, then 3 gyro rows per position
    when ``gyro_present``. ``temperatures`` ``(n,)`` °C from their mean, or None.
    """

    means: Array
    bias: Array
    m_matrix: Array
    gyro_present: bool
    temperatures: Array | None = None

    @property
    def rows(self) -> int:
        """Number of residual rows."""
        n = self.means.shape[0]
        return n + (3 * n if self.gyro_present else 0)

    @property
    def force(self) -> Array:
        """The corrected specific force ``f = M (U − b)`` of each position, ``(n, 3)``."""
        return np.asarray((self.means - self.bias) @ self.m_matrix.T)

    @property
    def back(self) -> Array:
        """``d|f|/dU`` of each position, ``(n, 3)``."""
        f = self.force
        return np.asarray((f / np.linalg.norm(f, axis=1, keepdims=True)) @ self.m_matrix)

    def accel_rows(self, cols: Array) -> Array:
        """Columns on the accelerometer rows, zero on the gyro rows."""
        out = np.zeros((self.rows, cols.shape[1]))
        out[: self.means.shape[0]] = cols
        return out


KnownColumns = Callable[[PoseInputs, Sensor], Array | None]
ScalarColumns = Callable[[ScalarInputs, Sensor], Array | None]


@dataclass(frozen=True)
class Effect:
    """One candidate effect (module doc).

    ``labels`` name the entries of ``known``'s columns (``scalar_labels`` those of the
    scalar fit's, when they differ); ``unit`` is the size's unit in known-pose fits
    (``scalar_unit`` in scalar fits, when it differs). ``one_pose``: a single static record
    can show it (else ``analyze`` of one pose lists it as untestable). A builder returns
    None where the data cannot show the effect (no temperature, no gyro channels).
    """

    name: str
    sensors: tuple[Sensor, ...]
    wording: str
    unit: str
    labels: tuple[str, ...] = ()
    known: KnownColumns | None = None
    scalar: ScalarColumns | None = None
    scalar_labels: tuple[str, ...] | None = None
    scalar_unit: str | None = None
    truth: str = GENERIC_TRUTH
    truth_per_unit: float = 1.0
    one_pose: bool = False

    def __post_init__(self) -> None:
        """Check the name, the sensors and that columns come with their labels."""
        if not self.name.isidentifier() or self.name != self.name.lower():
            raise ModelError(f"effect name {self.name!r}: lower-case letters, digits and _ only")
        if not self.sensors or not set(self.sensors) <= {"accel", "gyro"}:
            raise ModelError(f"effect {self.name!r}: sensors must be accel and/or gyro")
        if self.known is not None and not self.labels:
            raise ModelError(f"effect {self.name!r}: columns need a label per entry")

    @property
    def has_columns(self) -> bool:
        """True for an effect tested as extra columns of the base fit."""
        return self.known is not None or self.scalar is not None

    @property
    def generic_truth(self) -> bool:
        """True when the simulator applies the effect through its columns (module doc)."""
        return self.truth.startswith("effects.")

    def unit_in(self, scalar: bool) -> str:
        """Return the size's unit in a known-pose (False) or scalar (True) fit."""
        return self.scalar_unit if scalar and self.scalar_unit is not None else self.unit

    def labels_in(self, scalar: bool) -> tuple[str, ...]:
        """Return the entries' labels in a known-pose (False) or scalar (True) fit."""
        return self.scalar_labels if scalar and self.scalar_labels is not None else self.labels

    def truth_path(self, sensor: Sensor, k: int) -> str:
        """Where the truth JSON holds entry ``k`` of this effect on ``sensor``."""
        return self.truth.format(sensor=sensor, label=self.labels[k], name=self.name, k=k)


EFFECTS: Registry[Effect] = Registry("effect", lambda e: e.name)
"""The candidate effects, in the order they are tested and reported (module doc)."""


def column_effects() -> tuple[Effect, ...]:
    """Return the effects tested as extra columns, in registry order."""
    return tuple(e for e in EFFECTS.values() if e.has_columns)


def per_channel(inputs: PoseInputs, columns: Sequence[tuple[int, Array]]) -> Array:
    """Columns ``(n, channels, q)`` from ``(channel, values (n,))`` pairs, one per entry."""
    out = np.zeros((inputs.angles.shape[0], inputs.channels, len(columns)))
    for k, (channel, values) in enumerate(columns):
        out[:, channel, k] = values
    return out


OFF_DIAGONAL = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))
"""K entries of ``cross_axis`` in known-pose fits, row by row."""
LOWER = ((1, 0), (2, 0), (2, 1))
"""M = K⁻¹ entries of ``cross_axis`` in scalar fits (model "9")."""


def _base_tilt(x: PoseInputs, sensor: Sensor) -> Array:
    """``K dC/d(alpha0, beta0) f_L`` (and ``S dC w_L`` on gyro rows): rigid tilt, eq. (15)."""
    _, _, d_tilt = dcm_stack(x.angles, 0.0, 0.0, "rigid")
    f_level = specific_force_level(x.g)
    out = np.zeros((x.angles.shape[0], x.channels, 2))
    out[:, :3] = x.k_matrix @ np.einsum("nkij,j->nik", d_tilt, f_level)
    if x.channels == 6:
        out[:, 3:] = x.s_matrix @ np.einsum("nkij,j->nik", d_tilt, x.w_level)
    return out


def _cross_axis(x: PoseInputs, sensor: Sensor) -> Array:
    """``f_j`` on channel i for each off-diagonal K entry (eq. 6)."""
    return per_channel(x, [(i, x.f[:, j]) for i, j in OFF_DIAGONAL])


def _cross_axis_scalar(x: ScalarInputs, sensor: Sensor) -> Array:
    """d|M (U − b)|/dM_ij for the lower off-diagonal entries of M."""
    f, d = x.force, x.means - x.bias
    unit = f / np.linalg.norm(f, axis=1, keepdims=True)
    return x.accel_rows(np.column_stack([unit[:, i] * d[:, j] for i, j in LOWER]))


def _quadratic(x: PoseInputs, sensor: Sensor) -> Array:
    """``f_i²`` on channel i."""
    return per_channel(x, [(i, x.f[:, i] ** 2) for i in range(3)])


def _quadratic_scalar(x: ScalarInputs, sensor: Sensor) -> Array:
    """``U = b + K f + q ⊙ f²`` seen through ``|f|``."""
    return x.accel_rows(-x.back * x.force**2)


def _temperature(x: PoseInputs, sensor: Sensor) -> Array | None:
    """``T − T_ref`` on each channel of ``sensor``."""
    first = 0 if sensor == "accel" else 3
    if x.temperatures is None or first >= x.channels:
        return None
    return per_channel(x, [(first + i, x.temperatures) for i in range(3)])


def _temperature_scalar(x: ScalarInputs, sensor: Sensor) -> Array | None:
    """``f = M (U − b − c (T − T̄))`` seen through ``|f|``; ``T − T̄`` on each gyro row."""
    if x.temperatures is None:
        return None
    dt = x.temperatures[:, None]
    if sensor == "accel":
        return x.accel_rows(-x.back * dt)
    if not x.gyro_present:
        return None
    n = x.means.shape[0]
    out = np.zeros((x.rows, 3))
    for i in range(3):
        out[n + i :: 3, i] = dt[:, 0]
    return out


def _gyro_g(x: PoseInputs, sensor: Sensor) -> Array | None:
    """``f_j`` on gyro channel i for each entry of G."""
    if x.channels != 6:
        return None
    return per_channel(x, [(3 + i, x.f[:, j]) for i in range(3) for j in range(3)])


def _gyro_g_scalar(x: ScalarInputs, sensor: Sensor) -> Array | None:
    """Put the corrected specific force of each position on its gyro rows."""
    if not x.gyro_present:
        return None
    n, f = x.means.shape[0], x.force
    out = np.zeros((x.rows, 9))
    for i in range(3):
        for j in range(3):
            out[n + i :: 3, 3 * i + j] = f[:, j]
    return out


_G_LABELS = tuple(f"G[{i}][{j}]" for i in range(3) for j in range(3))
_TEMP_LABELS = tuple(f"temp_coeff[{i}]" for i in range(3))

EFFECTS.register(
    Effect(
        "base_tilt", ("accel",), "the base the poses are set on is tilted (rigid tilt)", "rad",
        labels=("alpha0", "beta0"), known=_base_tilt, truth="base_tilt_deg.{label}",
        truth_per_unit=float(np.rad2deg(1.0)),
    )
)  # fmt: skip
EFFECTS.register(
    Effect(
        "cross_axis", ("accel",), "cross-axis sensitivity: off-diagonal terms of K",
        "counts per m/s²", labels=tuple(f"K[{i}][{j}]" for i, j in OFF_DIAGONAL),
        known=_cross_axis, scalar=_cross_axis_scalar,
        scalar_labels=tuple(f"M[{i}][{j}]" for i, j in LOWER), scalar_unit="m/s² per count",
        truth="{sensor}.{label}",
    )
)  # fmt: skip
EFFECTS.register(
    Effect(
        "scale_nonlinearity", ("accel",), "a quadratic term of each axis in its own input",
        "counts per (m/s²)²", labels=tuple(f"quadratic[{i}]" for i in range(3)),
        known=_quadratic, scalar=_quadratic_scalar, truth="{sensor}.{label}",
    )
)  # fmt: skip
EFFECTS.register(
    Effect(
        "temperature_bias", ("accel", "gyro"), "a bias that follows the temperature",
        "counts per °C", labels=_TEMP_LABELS, known=_temperature, scalar=_temperature_scalar,
        truth="{sensor}.{label}", one_pose=True,
    )
)  # fmt: skip
EFFECTS.register(
    Effect(
        "bias_drift", ("accel", "gyro"), "a bias that wanders: a random walk inside positions",
        "counts/√s", one_pose=True,
    )
)  # fmt: skip
EFFECTS.register(
    Effect(
        "gyro_g_sensitivity", ("gyro",), "the gyro's sensitivity to specific force (G)",
        "counts per m/s²", labels=_G_LABELS, known=_gyro_g, scalar=_gyro_g_scalar,
        truth="{sensor}.{label}",
    )
)  # fmt: skip
EFFECTS.register(
    Effect("axis_sign", ("accel",), "an accelerometer axis with the wrong sign", "counts per m/s²")
)
