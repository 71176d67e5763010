"""The plans (docs/design.md §3): every plan name the tool knows, defined once.

A :class:`PlanEntry` holds what every part of the tool needs to know of one plan: its
positions (with their tolerances and averaging times) and prior on K (in :class:`Plan`), the
model its positions determine, its own acceptance defaults, the code the device stores in
0x2121:02, the TUI's key, and a one-line description. The CLI's help, the TUI's plan screen,
the solver's plan detection, the device's plan code, the calibration file's ``plan`` and the
demo's random truths all read :data:`PLANS`.

``custom`` (poses from a file, or recognised as no built-in plan) and ``scalar`` (no angles:
the ``|f| = g`` fit) are plan names of files and devices without positions of their own.

To add a plan, register an entry::

    PLANS.register(PlanEntry(Plan("six", positions), device_code=7, tui_key="6",
                             description="six faces on a cube", accel_k="full"))
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from canimucal.errors import ModelError
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.vocabulary.registry import Registry

DEFAULT_PLAN = "recommended"
"""The plan the commands and the TUI choose when none is named."""
CUSTOM = "custom"
"""The plan name of poses from a file, or of poses no built-in plan has."""
SCALAR = "scalar"
"""The plan name of a calibration without angles (the ``|f| = g`` fit)."""

DEVICE_CODE_MAX = 255
"""0x2121:02 is an UNSIGNED8; code 0 is "none" (the factory calibration)."""


@dataclass(frozen=True)
class PlanEntry:
    """One plan of the vocabulary (module doc).

    ``plan`` None: a plan name without positions of its own (``custom``, ``scalar``).
    ``accel_k`` and ``tilt``: the accelerometer model the positions determine, fitted by the
    procedure and assumed by the plan screen's bounds. ``vehicle``: the instructions are
    worded for a vehicle through the mounting map by default. ``acceptance``: limits of
    :class:`~canimucal.analysis.acceptance.AcceptanceLimits` (by key) this plan holds to
    instead of the built-in ones; a user's ``[plan.NAME]`` table still overrides them.
    ``trim``: the procedure also fits the unit's mounting trim in the vehicle (only a plan
    that holds K at a prior determines it: a free full K absorbs any rotation of the
    unit's axes, docs/method.md §3).
    """

    name: str
    plan: Plan | None
    device_code: int
    description: str
    tui_key: str | None = None
    accel_k: Literal["diag", "full"] = "full"
    tilt: Literal["none", "rigid"] = "rigid"
    vehicle: bool = False
    trim: bool = False
    acceptance: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    def __post_init__(self) -> None:
        """Check the name, the code and that the plan carries the entry's name."""
        if not self.name.isidentifier() or self.name != self.name.lower():
            raise ModelError(f"plan name {self.name!r}: lower-case letters, digits and _ only")
        if self.plan is not None and self.plan.name != self.name:
            raise ModelError(f"plan entry {self.name!r} holds the plan {self.plan.name!r}")
        if not 1 <= self.device_code <= DEVICE_CODE_MAX:
            raise ModelError(f"plan {self.name!r}: device code must be 1..{DEVICE_CODE_MAX}")
        if self.tui_key is not None and len(self.tui_key) != 1:
            raise ModelError(f"plan {self.name!r}: the TUI key must be one character")

    @property
    def builtin(self) -> bool:
        """True for a plan with positions of its own (not ``custom`` or ``scalar``)."""
        return self.plan is not None

    @property
    def holds_k_prior(self) -> bool:
        """True when the plan holds K at a factory prior (what its poses cannot separate)."""
        return self.plan is not None and self.plan.prior_k_sigma is not None


def _check(entry: PlanEntry, plans: Registry[PlanEntry]) -> None:
    for other in plans.values():
        if other.device_code == entry.device_code:
            raise ModelError(
                f"plan {entry.name!r}: device code {entry.device_code} is {other.name!r}'s"
            )
        if entry.tui_key is not None and other.tui_key == entry.tui_key:
            raise ModelError(f"plan {entry.name!r}: TUI key {entry.tui_key!r} is {other.name!r}'s")


PLANS: Registry[PlanEntry] = Registry("plan", lambda e: e.name, _check)
"""Every plan name, in the order the CLI and the TUI offer them (module doc)."""


def builtin_names() -> tuple[str, ...]:
    """Names of the plans with positions of their own, in registry order."""
    return tuple(name for name, entry in PLANS.items() if entry.builtin)


def builtin_plan(name: str) -> Plan:
    """Return the positions of the built-in plan ``name`` (ModelError for any other name)."""
    entry = PLANS.get(name)
    if entry is None or entry.plan is None:
        raise ModelError(f"unknown plan {name!r}; built-in plans: {', '.join(builtin_names())}")
    return entry.plan


def plan_named_by(device_code: int) -> str | None:
    """Name the plan whose device code (0x2121:02) is ``device_code``; None for 0 or unknown."""
    return next((e.name for e in PLANS.values() if e.device_code == device_code), None)


def worded_for_vehicle(name: str) -> bool:
    """Tell whether plan ``name``'s instructions are worded for a vehicle by default."""
    entry = PLANS.get(name)
    return entry is not None and entry.vehicle


def plan_help() -> str:
    """``"two, five, recommended, vehicle or a plan file"``: what ``--plan`` accepts."""
    names = builtin_names()
    return f"{', '.join(names[:-1])}, {names[-1]} or a plan file" if names else "a plan file"


def plan_of_poses(angles: ArrayLike, atol_rad: float) -> str | None:
    """Name the built-in plan whose poses ``angles`` ``(n, 3)`` rad are, in order; else None."""
    got = np.asarray(angles, dtype=float)
    for name in builtin_names():
        plan = builtin_plan(name)
        want = np.array([p.angles for p in plan.positions])
        if want.shape == got.shape and np.allclose(want, got, atol=atol_rad):
            return name
    return None


def _plan(name: str, degrees: Sequence[tuple[float, float, float]]) -> Plan:
    return Plan(
        name,
        tuple(
            PlannedPosition(
                float(np.deg2rad(a)), float(np.deg2rad(b)), float(np.deg2rad(p)), seconds=30.0
            )
            for a, b, p in degrees
        ),
    )


TWO = _plan("two", [(0, 0, 0), (45, 5, 0)])
"""The paper's two positions (eq. 1-14): level and (45°, 5°); 30 s each, tolerance 0.1°."""

FIVE = _plan("five", [(0, 0, 0), (22.5, 0, 0), (22.5, 2.5, 0), (45, 2.5, 0), (45, 5, 0)])
"""The paper's five positions (eq. 15-34), degrees; 30 s each, tolerance 0.1°."""

RECOMMENDED = _plan(
    "recommended",
    [(0, 0, 0), (45, 45, 0), (45, 45, 90), (0, 0, 90)]
    + [(0, 0, 180), (45, 45, 180), (45, 45, 270), (0, 0, 270)],
)
"""Ours: two stands (level, and alpha = beta = 45°), the unit turned by psi 0/90/180/270° on each.

Eight positions, 30 s each; the second stand is a double wedge (45° about z, then 45° about
the new x: gravity 60° off the unit's y axis). The stands alternate: level, tilted, tilted,
level, level, tilted, tilted, level (psi 0, 0, 90, 90, 180, 180, 270, 270), so that the
moves turn about every body axis: the four stand changes, made at four different psi, turn
about x and z, the turns on a stand about y. The gyro's full S is then identifiable from the
moves (``plan --gyro moves``: σ 0.10–0.20 % of the scale on every entry at 1 count/√Hz and
100 Hz); visiting each stand's four poses in a row turns about y only and leaves S's columns
x and z not identifiable.

The accelerometer's bounds depend on the poses, not their order. The level turns separate
the x/z biases from the base tilt (the tilt reverses under a 180° turn, the biases do not);
the tilted turns put ±0.5 g on x and z and -0.5 g on y, so bias, FULL K and the rigid tilt
are identifiable and separable (smallest normalised eigenvalue ratio 0.014, largest
|correlation| 0.96). Found with ``benchmarks/plan_search.py`` (exchange search over round
poses; its best, 0.327 counts, needs mixed poses). At equal total averaging time (150 s,
white noise 1 count/√Hz, k = 2048/g) the worst-case bound for bias + diagonal K + rigid tilt
is 0.383 counts (K[1][1]) against FIVE's 4.21 counts (bias z, correlated -0.9996 with
beta0): a ratio of 11.0; with the 0.1° angle tolerances included, 3.99 against 63.7 counts
(16×). With the tolerances included, bias y and K[1][1] correlate at +0.9996 (every plan
with tilts ≤ 45° sees f_y only in [-g, -g/2]); repeating the poses is what reduces that.
"""


VEHICLE_TILT_DEG = 10.0
"""Largest tilt of the vehicle plan: a step ladder or ramp under one axle or one side."""
VEHICLE_LEVEL_TOLERANCE_DEG = 0.2
"""1σ of the vehicle's attitude when parked again on the same spot (floor unevenness)."""
VEHICLE_TILT_TOLERANCE_DEG = 0.5
"""1σ of a ladder tilt: the nominal 10° is set by eye and the wheelbase, not measured."""
VEHICLE_TURN_TOLERANCE_DEG = 5.0
"""1σ of a turn of the whole vehicle on the spot."""
VEHICLE_PRIOR_K_SIGMA = 0.01
"""Relative 1σ of the factory K the vehicle plan relies on (1 % of the nominal scale, on
every entry: a datasheet's scale-factor tolerance and cross-axis sensitivity)."""


def _vehicle_plan() -> Plan:
    level, tilt = np.deg2rad(VEHICLE_LEVEL_TOLERANCE_DEG), np.deg2rad(VEHICLE_TILT_TOLERANCE_DEG)
    turn, t = np.deg2rad(VEHICLE_TURN_TOLERANCE_DEG), np.deg2rad(VEHICLE_TILT_DEG)
    positions = [
        PlannedPosition(0.0, 0.0, float(psi), float(level), 60.0, psi_tolerance=float(turn))
        for psi in np.deg2rad([0.0, 90.0, 180.0, 270.0])
    ]
    positions += [
        PlannedPosition(float(a), float(b), 0.0, float(tilt), 60.0)
        for a, b in ((t, 0.0), (-t, 0.0), (0.0, t), (0.0, -t))
    ]
    return Plan("vehicle", tuple(positions), prior_k_sigma=VEHICLE_PRIOR_K_SIGMA, setup_seconds=180)


VEHICLE = _vehicle_plan()
"""The whole vehicle, the unit bolted in: no tilt above 10°, nothing unbolted.

Four level poses, the vehicle turned on the spot by psi 0/90/180/270° (1σ 5°; its level
repeatable to 0.2° on the same spot), then four ladder poses: each end and each side raised
by 10° (alpha ±10° about z, beta ±10° about x; 1σ 0.5°), 60 s each, 3 min of setting up each.
The turns reverse the floor's slope under the unit, separating it (the base tilt) from the
x/z biases. Every pose sees f_y within cos 10° = 0.985 of -g, so bias y and K_yy (and the
x/z biases and the K entries driven by f_y) cannot be told apart: the plan holds K at the
factory value with 1 % relative σ (a prior, stated in the bound table and the calibration),
and the bias y is then known to about g·σ(K_yy).
"""

VEHICLE_ACCEPTANCE = MappingProxyType(
    {"max_bias_sigma_mg": 15.0, "max_scale_sigma_ppm": 10000.0, "max_rms_ms2": 0.1}
)
"""What a vehicle plan is for (docs/design.md §3): biases at the σ its 1 % prior on K lets it
reach with the mounting trim fitted beside them (13.9 mg predicted with its angle tolerances;
10.1 mg if the trim were assumed zero: at level a trim's roll and pitch look like the x and z
biases, docs/method.md §3), and the scale held at the factory value with the prior's own σ
(1 % = 10000 ppm; 8100 ppm predicted), and the fit's rms at what its poses leave: the ladder
poses are set to 0.5° 1σ, g·0.5°·√(2/3) = 0.07 m/s² in their residuals (clean sessions on a
sloped floor with a trim: 0.04–0.06 m/s²; the bench's 0.05 failed 8 of 20,
``benchmarks/floor_sessions.py``), so a clean unit on a clean floor passes by default. A
stricter department writes ``[plan.vehicle]`` in acceptance.toml."""

PLANS.register(
    PlanEntry(
        "two", TWO, 1, "the paper's two positions: bias and diagonal scale",
        tui_key="2", accel_k="diag", tilt="none",
    )
)  # fmt: skip
PLANS.register(
    PlanEntry(
        "five", FIVE, 2, "the paper's five positions: bias, diagonal scale and base tilt",
        tui_key="5", accel_k="diag",
    )
)  # fmt: skip
PLANS.register(
    PlanEntry(
        "recommended", RECOMMENDED, 3,
        "two stands turned four ways: bias, full K and base tilt, separable",
        tui_key="r",
    )
)  # fmt: skip
PLANS.register(
    PlanEntry(
        "vehicle", VEHICLE, 6,
        "the whole vehicle turned, raised 10°: biases, slope and trim; K at a 1 % prior",
        tui_key="v", vehicle=True, trim=True, acceptance=VEHICLE_ACCEPTANCE,
    )
)  # fmt: skip
PLANS.register(
    PlanEntry(
        CUSTOM, None, 4, "poses from a plan file (or poses no built-in plan has)",
        tui_key="u",
    )
)  # fmt: skip
PLANS.register(PlanEntry(SCALAR, None, 5, "no angles: the |f| = g fit"))
