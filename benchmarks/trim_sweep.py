"""Floor slope and mounting trim over N seeds (issue 22 item 1; docs/method.md §3).

The offline draws of ``tests/model/test_mounting_trim.py`` (which takes seeds 0–19): per
seed a unit within the plan's prior, a floor slope within ±3° and a trim within ±2° about
each axis, pose errors from the plan's tolerances, an Earth rate the fit is not told. For
the vehicle plan: each slope and trim angle's largest |z| and Σz²/N against the χ² band;
for the recommended plan (full K absorbs the trim): the slope's, and Σ Mahalanobis/9N of
K̂ − K·R_m. For both, the fits' χ² p-values: the KS test of uniformity and how many fall
below 0.01.

    PYTHONPATH=. .venv/bin/python benchmarks/trim_sweep.py [--seeds 40]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.stats import kstest

from canimucal.model.frames import trim_dcm
from canimucal.model.layout import TRIM_NAMES
from tests.model.test_mounting_trim import SLOPE_NAMES, _draw
from tests.support.chi2_band import chi2_ratio_band, mahalanobis


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40, help="seeds 0..N-1 (default 40)")
    args = parser.parse_args()
    seeds = range(args.seeds)
    for plan in ("vehicle", "recommended"):
        t0 = time.perf_counter()
        draws = [_draw(plan, seed) for seed in seeds]
        names = SLOPE_NAMES + (TRIM_NAMES if plan == "vehicle" else ())
        z = np.array([d.z(names, np.r_[d.slope, d.trim][: len(names)]) for d in draws])
        low, high = chi2_ratio_band(len(draws), comparisons=len(names))
        print(f"{plan}: {len(draws)} seeds, {time.perf_counter() - t0:.1f} s")
        for k, name in enumerate(names):
            ratio = float(np.mean(z[:, k] ** 2))
            print(
                f"  {name:<22} max |z| {np.max(np.abs(z[:, k])):.2f}  Σz²/N {ratio:.2f} "
                f"(band {low:.2f}–{high:.2f})"
            )
        if plan == "recommended":
            index = [f"accel.K[{i}][{j}]" for i in range(3) for j in range(3)]
            d2 = []
            for d in draws:
                at = [d.fit.names.index(n) for n in index]
                error = d.fit.values[at] - (d.accel.K @ trim_dcm(d.trim)).ravel()
                d2.append(mahalanobis(error, d.fit.covariance[np.ix_(at, at)]))
            lo9, hi9 = chi2_ratio_band(9 * len(draws))
            print(
                f"  K − K·R_m Mahalanobis/9N {np.sum(d2) / (9 * len(draws)):.2f} "
                f"(band {lo9:.2f}–{hi9:.2f})"
            )
        p = np.array([d.p_value for d in draws])
        print(
            f"  fit χ² p: KS p = {kstest(p, 'uniform').pvalue:.3f}, {int(np.sum(p < 0.01))} of "
            f"{len(p)} below 0.01"
        )


if __name__ == "__main__":
    main()
