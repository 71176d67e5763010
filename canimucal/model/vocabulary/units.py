"""The calibration's parameters and their units (docs/design.md §2), defined once.

Every parameter of the solver's vector (``accel.bias[i]``, ``accel.K[i][j]``,
``base_tilt.alpha0``, ``mounting_trim.alpha``, ``gyro.bias[i]``, ``gyro.S[i][j]``,
``gyro.G[i][j]``) belongs to one
:class:`Quantity`, which says in which unit the solver, the bound table and the files hold
it, how it converts to SI and to the unit an operator reads (mg, ppm, °, °/s), and in which
unit the calibration file holds it (the base tilt and the mounting trim in degrees). The
results screen, the certificate, the CLI's text and the JSON outputs take their units from
:data:`QUANTITIES`.

The conversions are factors (a σ converts as its value does): SI and operator values of a
scale factor are relative to the nominal scale (``K·|LSB|``: 1 at nominal, in ppm an
error of 1e-6 of the scale).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from canimucal.model.frames import EARTH_RATE_RAD_S
from canimucal.model.vocabulary.registry import Registry


@dataclass(frozen=True)
class Scales:
    """What a conversion may depend on: the nominal LSBs (m/s², rad/s per count) and g."""

    accel_lsb: float
    gyro_lsb: float
    g: float


Factor = Callable[[Scales], float]


@dataclass(frozen=True)
class Quantity:
    """One family of parameters (``accel.K``) and its units (module doc).

    ``unit`` is the solver's and the bound table's; ``file_unit`` the calibration file's and
    the results screen's (``file_per_unit`` of them per ``unit``); ``si_unit`` and
    ``operator_unit`` with their factors per ``unit`` at given :class:`Scales`;
    ``effect_counts`` the counts one unit changes at 1 g (biases 1, K and G entries g, tilt
    angles |k|·g, S entries the Earth rate Ω).
    """

    family: str
    wording: str
    unit: str
    si_unit: str
    to_si: Factor
    operator_unit: str
    to_operator: Factor
    effect_counts: Callable[[float, float], float] = lambda g, k: 1.0
    """Counts one unit changes at 1 g, of ``(g, |k| counts per m/s²)``: the bound table's
    normalisation (docs/design.md §3)."""
    file_unit: str = ""
    file_per_unit: float = 1.0

    @property
    def shown_unit(self) -> str:
        """The unit of the calibration file and the results screen."""
        return self.file_unit or self.unit

    @property
    def unit_words(self) -> str:
        """The unit in running text: ``counts per m/s²`` for ``counts/(m/s²)``."""
        return words(self.shown_unit)

    def si(self, value: float, scales: Scales) -> float:
        """``value`` (in ``unit``) in SI."""
        return value * self.to_si(scales)

    def operator(self, value: float, scales: Scales) -> float:
        """``value`` (in ``unit``) in the operator's unit."""
        return value * self.to_operator(scales)


def words(unit: str) -> str:
    """Spell a unit for running text: ``counts/(m/s²)`` → ``counts per m/s²``."""
    head, sep, tail = unit.partition("/(")
    return f"{head} per {tail.removesuffix(')')}" if sep else unit


QUANTITIES: Registry[Quantity] = Registry("parameter family", lambda q: q.family)
"""Every family of the parameter vector, in the vector's order (module doc)."""


def family_of(name: str) -> str:
    """``accel.K`` of ``accel.K[0][1]``, ``base_tilt`` of ``base_tilt.alpha0``."""
    head = name.split("[", 1)[0]
    return head if head in QUANTITIES else head.split(".", 1)[0]


def quantity_of(name: str) -> Quantity:
    """Return the quantity of parameter ``name`` (ModelError for a name of no family)."""
    return QUANTITIES.lookup(family_of(name))


_DEG = float(np.rad2deg(1.0))

QUANTITIES.register(
    Quantity(
        "accel.bias", "accelerometer bias", "counts",
        "m/s²", lambda s: abs(s.accel_lsb), "mg", lambda s: abs(s.accel_lsb) / s.g * 1e3,
    )
)  # fmt: skip
QUANTITIES.register(
    Quantity(
        "accel.K", "accelerometer scale and cross-axis matrix", "counts/(m/s²)",
        "1", lambda s: abs(s.accel_lsb), "ppm", lambda s: abs(s.accel_lsb) * 1e6,
        effect_counts=lambda g, k: g,
    )
)  # fmt: skip
QUANTITIES.register(
    Quantity(
        "base_tilt", "tilt of the base the poses are set on", "rad",
        "rad", lambda s: 1.0, "°", lambda s: _DEG, effect_counts=lambda g, k: k * g,
        file_unit="deg", file_per_unit=_DEG,
    )
)  # fmt: skip
QUANTITIES.register(
    Quantity(
        "mounting_trim", "mounting trim of the unit in the vehicle", "rad",
        "rad", lambda s: 1.0, "°", lambda s: _DEG, effect_counts=lambda g, k: k * g,
        file_unit="deg", file_per_unit=_DEG,
    )
)  # fmt: skip
QUANTITIES.register(
    Quantity(
        "gyro.bias", "gyro bias", "counts",
        "rad/s", lambda s: abs(s.gyro_lsb), "°/s", lambda s: abs(s.gyro_lsb) * _DEG,
    )
)  # fmt: skip
QUANTITIES.register(
    Quantity(
        "gyro.S", "gyro scale and cross-axis matrix", "counts/(rad/s)",
        "1", lambda s: abs(s.gyro_lsb), "ppm", lambda s: abs(s.gyro_lsb) * 1e6,
        effect_counts=lambda g, k: EARTH_RATE_RAD_S,
    )
)  # fmt: skip
QUANTITIES.register(
    Quantity(
        "gyro.G", "gyro sensitivity to specific force", "counts/(m/s²)",
        "(rad/s)/(m/s²)", lambda s: abs(s.gyro_lsb),
        "(°/s)/g", lambda s: abs(s.gyro_lsb) * _DEG * s.g, effect_counts=lambda g, k: g,
    )
)  # fmt: skip


SCALE_FAMILIES = ("accel.K", "gyro.S")
"""The families whose diagonal is a scale factor: shown to an operator as ppm from nominal."""


def operator_value(family: str, value: float, scales: Scales, *, diagonal: bool = False) -> float:
    """``value`` (in the family's ``unit``) in the operator's unit.

    A scale factor's diagonal entry is shown as its deviation from the nominal scale (ppm from
    nominal: 0 at nominal), its off-diagonal entries and every other family as converted.
    """
    quantity = QUANTITIES[family]
    shown = quantity.operator(value, scales)
    if diagonal and family in SCALE_FAMILIES:
        shown -= 1e6  # K·|LSB| = 1 at nominal
    return shown


def with_unit(value: float, sigma: float | None, unit: str, digits: int = 6) -> str:
    """``1.25 ± 0.03 mg``: a value (± σ) and its unit, never a bare number."""
    text = f"{value:.{digits}g}" if sigma is None else f"{value:.{digits}g} ± {sigma:.2g}"
    return f"{text} {unit}"
