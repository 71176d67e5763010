"""Search for the recommended plan: exchange algorithm over round poses (not a test).

Objective: the worst-case Cramér–Rao effect at 1 g (bias + diagonal K + rigid tilt) at a
fixed total averaging time, subject to bias + FULL K + rigid tilt being identifiable and
separable. Run: ``.venv/bin/python benchmarks/plan_search.py``.
"""

from __future__ import annotations

import itertools
import sys

import numpy as np

from canimucal.model.layout import JointSpec
from canimucal.model.plan import cramer_rao
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.vocabulary.plans import FIVE, RECOMMENDED

TOTAL_S = FIVE.total_seconds
TILTS = (0.0, 45.0, -45.0)
PSIS = (0.0, 90.0, 180.0, 270.0)
CANDIDATES = [(a, b, p) for a, b in itertools.product(TILTS, TILTS) for p in PSIS]
DIAG = JointSpec(accel_k="diag", tilt="rigid")
FULL = JointSpec(accel_k="full", tilt="rigid")


def make_plan(poses: list[tuple[float, float, float]]) -> Plan:
    each = TOTAL_S / len(poses)
    return Plan(
        "candidate",
        tuple(PlannedPosition(*np.deg2rad([a, b, p]).tolist(), seconds=each) for a, b, p in poses),
    )


def score(poses: list[tuple[float, float, float]]) -> float:
    plan = make_plan(poses)
    full = cramer_rao(plan, FULL)
    if not full.separability.separable:
        return float("inf")
    return max(cramer_rao(plan, DIAG).worst_case_counts, 0.0)


def exchange(n: int, rng: np.random.Generator, sweeps: int = 6) -> tuple[float, list]:
    poses = [CANDIDATES[k] for k in rng.choice(len(CANDIDATES), n)]
    best = score(poses)
    for _ in range(sweeps):
        improved = False
        for i in range(n):
            for cand in CANDIDATES:
                trial = poses[:i] + [cand] + poses[i + 1 :]
                s = score(trial)
                if s < best - 1e-9:
                    best, poses, improved = s, trial, True
        if not improved:
            break
    return best, poses


def main() -> None:
    five = cramer_rao(FIVE, DIAG).worst_case_counts
    print(f"FIVE worst case {five:.3f} counts at {TOTAL_S:.0f} s")
    rng = np.random.default_rng(int(sys.argv[1]) if len(sys.argv) > 1 else 0)
    for n in range(4, 9):
        results = sorted((exchange(n, rng) for _ in range(4)), key=lambda r: r[0])
        best, poses = results[0]
        print(f"n={n}: worst {best:.3f} counts, ratio {five / best:.2f}: {sorted(poses)}")
    ours = cramer_rao(RECOMMENDED.with_total_seconds(TOTAL_S), DIAG).worst_case_counts
    print(f"RECOMMENDED: worst {ours:.3f} counts, ratio {five / ours:.2f}")


if __name__ == "__main__":
    main()
