"""Total operator time to reach worst bias σ ≤ 1 mg and scale σ ≤ 100 ppm (issue 4, item 5).

Run: ``.venv/bin/python benchmarks/operator_time.py`` (about a minute on one core).

The Cramér–Rao machinery of ``canimucal.model.plan`` (``cramer_rao``) gives the σ of every
parameter for a plan whose positions are averaged ``T`` seconds each, with realistic noise
and the operator's angle-setting errors included (errors in variables):

- accelerometer white noise 1.5e-3 m/s²/√Hz per axis (the simulator's default, a consumer
  MEMS part), i.e. 0.313 counts/√Hz through the nominal K of ±16 g (k = 2048/g);
- gyro white noise 1.2e-4 rad/s/√Hz (the simulator's default); MEMS gyro model (bias only);
- angle tolerance 0.1° (1σ) on every angle of every position;
- g = 9.80665 m/s², evaluated at K = k·I and zero tilt (docs/design.md §3).

Targets: worst accelerometer bias σ ≤ 1 mg (0.209 counts) and worst relative scale-factor σ
(σ(K_ii)/k) ≤ 100 ppm. The model each plan is solved with: RECOMMENDED bias + full K + rigid
base tilt (what the procedure estimates with it); FIVE bias + diagonal K + rigid base tilt
(it cannot determine the cross-axis terms). Both are also shown for the common model
bias + diagonal K + tilt.

Operator time = averaging + moving. The first (level) position records max(120 s, T)
(the procedure's noise recording); each later one T, plus 2 s of settling. Moving: 20 s per
pose change (tilt changed: set a wedge or the tilting table) and 30 s per psi turn (lift,
turn and reseat the unit on its face); a change of both counts 50 s. A plan may be repeated
``r`` times (the same poses set again: fresh angle errors, the tolerance floor falls as
1/√r); the search takes T from a log grid (5 s … 1 h) and r = 1 … 8 and reports the fastest
combination meeting both targets, or, when none does, the best reachable values.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from canimucal.model.layout import JointSpec
from canimucal.model.plan import cramer_rao
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, STANDARD_GRAVITY
from canimucal.model.vocabulary.plans import builtin_plan

ACCEL_NOISE_COUNTS = 1.5e-3 / DEFAULT_ACCEL_LSB
"""Accelerometer white noise in counts/√Hz (1.5e-3 m/s²/√Hz through the nominal K)."""
GYRO_NOISE_COUNTS = 1.2e-4 / 1.0642251e-3
"""Gyro white noise in counts/√Hz (1.2e-4 rad/s/√Hz through the nominal S)."""
K_NOMINAL = 1.0 / DEFAULT_ACCEL_LSB
BIAS_TARGET_MG = 1.0
SCALE_TARGET_PPM = 100.0
MOVE_POSE_S = 20.0
MOVE_TURN_S = 30.0
SETTLE_S = 2.0
FIRST_MIN_S = 120.0
SECONDS_GRID = np.unique(np.round(np.geomspace(5.0, 3600.0, 60)))
REPEATS = range(1, 9)


@dataclass(frozen=True)
class Outcome:
    """Bounds and operator time of one plan at T seconds per position, repeated r times."""

    seconds: float
    repeats: int
    bias_mg: float
    scale_ppm: float
    scale_xz_ppm: float
    averaging_s: float
    moving_s: float

    @property
    def total_s(self) -> float:
        """Averaging plus moving."""
        return self.averaging_s + self.moving_s

    def meets(self, target: str) -> bool:
        """Whether ``target`` is met: ``both``, ``bias`` only, or ``both_xz`` (scale of x, z)."""
        bias_ok = self.bias_mg <= BIAS_TARGET_MG
        if target == "bias":
            return bias_ok
        scale = self.scale_xz_ppm if target == "both_xz" else self.scale_ppm
        return bias_ok and scale <= SCALE_TARGET_PPM

    def score(self, target: str) -> float:
        """How far from ``target`` (≤ 1: met)."""
        bias = self.bias_mg / BIAS_TARGET_MG
        if target == "bias":
            return bias
        scale = self.scale_xz_ppm if target == "both_xz" else self.scale_ppm
        return max(bias, scale / SCALE_TARGET_PPM)


def repeated(plan: Plan, seconds: float, repeats: int, tolerance_rad: float | None = None) -> Plan:
    """``plan``'s poses at ``seconds`` each, set ``repeats`` times over."""
    one = [
        PlannedPosition(p.alpha, p.beta, p.psi, tolerance_rad or p.tolerance, seconds)
        for p in plan.positions
    ]
    return Plan(plan.name, tuple(one * repeats))


def moving_seconds(plan: Plan) -> float:
    """Moving time between consecutive poses (20 s a tilt change, 30 s a psi turn)."""
    total = 0.0
    for a, b in zip(plan.positions, plan.positions[1:], strict=False):
        if not np.allclose((a.alpha, a.beta), (b.alpha, b.beta)):
            total += MOVE_POSE_S
        if not np.isclose(a.psi, b.psi):
            total += MOVE_TURN_S
    return total


def bounds(plan: Plan, spec: JointSpec) -> tuple[float, float, float]:
    """Worst bias σ (mg), worst relative scale σ (ppm) and the worst of x and z (ppm)."""
    table = cramer_rao(
        plan,
        spec,
        k_nominal_counts_per_ms2=K_NOMINAL,
        g=STANDARD_GRAVITY,
        noise_density=ACCEL_NOISE_COUNTS,
        gyro_noise_density=GYRO_NOISE_COUNTS,
        include_tolerance=True,
    )
    bias, scale = [], []
    for row in table.rows:
        sigma = np.inf if row.sigma is None else row.sigma
        if row.name.startswith("accel.bias"):
            bias.append(sigma * DEFAULT_ACCEL_LSB / STANDARD_GRAVITY * 1000.0)
        elif row.name in (f"accel.K[{i}][{i}]" for i in range(3)):
            scale.append(sigma / K_NOMINAL * 1e6)
    return max(bias), max(scale), max(scale[0], scale[2])


def evaluate(
    plan: Plan, spec: JointSpec, seconds: float, repeats: int, tolerance_rad: float | None = None
) -> Outcome:
    """Bounds and operator time of one combination."""
    full = repeated(plan, seconds, repeats, tolerance_rad)
    first = list(full.positions)
    first[0] = PlannedPosition(*first[0].angles, first[0].tolerance, max(FIRST_MIN_S, seconds))
    full = Plan(plan.name, tuple(first))
    bias_mg, scale_ppm, scale_xz = bounds(full, spec)
    averaging = full.total_seconds + SETTLE_S * len(full.positions)
    return Outcome(seconds, repeats, bias_mg, scale_ppm, scale_xz, averaging, moving_seconds(full))


def fastest(plan: Plan, spec: JointSpec, target: str) -> tuple[Outcome | None, Outcome]:
    """The fastest combination meeting ``target`` (None if none) and the closest reached."""
    best: Outcome | None = None
    closest: Outcome | None = None
    for repeats in REPEATS:
        for seconds in SECONDS_GRID:
            out = evaluate(plan, spec, float(seconds), repeats)
            if closest is None or out.score(target) < closest.score(target):
                closest = out
            if out.meets(target):
                if best is None or out.total_s < best.total_s:
                    best = out
                break  # longer T at this r only costs time
    assert closest is not None
    return best, closest


def describe(best: Outcome | None, closest: Outcome) -> str:
    """One line: the fastest way, or the closest reached."""
    if best is None:
        return (
            f"never (T ≤ 1 h, r ≤ 8); closest: bias σ {closest.bias_mg:.3f} mg, scale σ "
            f"{closest.scale_ppm:.0f} ppm (x, z {closest.scale_xz_ppm:.0f} ppm) at "
            f"T = {closest.seconds:g} s, r = {closest.repeats}"
        )
    return (
        f"T = {best.seconds:g} s × r = {best.repeats}: bias σ {best.bias_mg:.3f} mg, scale σ "
        f"{best.scale_ppm:.0f} ppm (x, z {best.scale_xz_ppm:.0f} ppm); averaging "
        f"{best.averaging_s / 60:.1f} min + moving {best.moving_s / 60:.1f} min = "
        f"{best.total_s / 60:.1f} min"
    )


def tolerance_needed(plan: Plan, spec: JointSpec) -> tuple[float, Outcome] | None:
    """The largest angle tolerance (degrees) at which one pass meets both targets, fastest T."""
    for tol_deg in np.geomspace(0.1, 0.001, 41):
        for seconds in SECONDS_GRID:
            out = evaluate(plan, spec, float(seconds), 1, float(np.deg2rad(tol_deg)))
            if out.meets("both"):
                return float(tol_deg), out
    return None


TARGETS = {
    "both": "bias ≤ 1 mg and every scale ≤ 100 ppm",
    "both_xz": "bias ≤ 1 mg and x, z scale ≤ 100 ppm",
    "bias": "bias ≤ 1 mg only",
}


def main() -> None:
    """Print the fastest way each plan reaches the targets."""
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    diag_tilt = JointSpec(accel_k="diag", tilt="rigid", gyro="mems")
    full_tilt = JointSpec(accel_k="full", tilt="rigid", gyro="mems")
    print(
        f"targets: bias σ ≤ {BIAS_TARGET_MG:g} mg, scale σ ≤ {SCALE_TARGET_PPM:g} ppm; noise "
        f"{ACCEL_NOISE_COUNTS:.3f} counts/√Hz; tolerance 0.1°; moves {MOVE_POSE_S:g} s per "
        f"pose change, {MOVE_TURN_S:g} s per psi turn; first position ≥ {FIRST_MIN_S:g} s"
    )
    cases = [
        ("recommended", "bias + full K + tilt", full_tilt),
        ("recommended", "bias + diagonal K + tilt", diag_tilt),
        ("five", "bias + diagonal K + tilt", diag_tilt),
    ]
    for name, spec_name, spec in cases:
        plan = builtin_plan(name)
        at_30 = evaluate(plan, spec, 30.0, 1)
        print(
            f"\n{name} ({spec_name}); one pass at 30 s: bias σ {at_30.bias_mg:.3f} mg, scale σ "
            f"{at_30.scale_ppm:.0f} ppm (x, z {at_30.scale_xz_ppm:.0f}), "
            f"{at_30.total_s / 60:.1f} min"
        )
        for target, words in TARGETS.items():
            best, closest = fastest(plan, spec, target)
            print(f"  {words:<40} {describe(best, closest)}")
        needed = tolerance_needed(plan, spec)
        if needed is None:
            print("  no tolerance down to 0.001° meets both targets in one pass")
        else:
            tol, out = needed
            print(
                f"  both targets in one pass need a tolerance of {tol:.4f}°: {describe(out, out)}"
            )


if __name__ == "__main__":
    main()
