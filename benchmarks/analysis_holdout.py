"""Benchmark of `analyze` on data it was not tuned on (issue 14).

1. Hidden-effect study: twelve-position recordings with exactly set poses (and, with
   ``--tolerance 0.1``, poses set to 0.1°), one effect of the vocabulary each, at ``--size``
   σ of its own estimate under that plan; ``--seeds`` per effect (15 by default: 8 effects
   give 120 recordings). Printed per effect: how often it is named exactly, with the pose
   scatter estimated from the data and with it assumed at 0.1°; the median estimated scatter;
   the extended model's mean χ²/dof; how often the gain is claimed.
2. Clean data: false alarms and the scatter's interval coverage.
3. Real data (``../shared/data``; skipped when absent): the imucal session's estimated noise
   model, its findings and the held-out (refit) cv_rms with the ratio's interval, and its
   gyro rows' χ² without and with the Earth rate fitted (no latitude); the imu_tk session's
   scalar fit the same way (no angles: no pose scatter).

Run: ``.venv/bin/python benchmarks/analysis_holdout.py [--seeds 15] [--size 5]
[--tolerance 0.0]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.support

from canimucal.analysis.discrepancy import analyse_discrepancy, effect_sigmas
from canimucal.analysis.report import analyse_recording
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.effects import EFFECTS
from canimucal.runtime.inputs import read_recording
from canimucal.sim.effects import hide_effect, warm_up_profile
from canimucal.sim.truth import Truth
from tests.support.plans import twelve
from tests.support.sessions import simulate_session

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def clean_truth(seed: int) -> dict[str, Any]:
    """A random unit without any effect of the vocabulary, warming up."""
    doc = Truth.random(np.random.default_rng(seed), cross_axis_max=0.0, tilt_max_deg=0.0)
    out = doc.to_dict()
    out["temperature"] = {"profile": warm_up_profile()}
    return out


def hidden_study(seeds: int, size: float, tolerance: float) -> None:
    """Section 1 and 2 (module doc)."""
    plan = twelve(tolerance)
    sigmas = effect_sigmas(simulate_session(Truth.from_dict(clean_truth(999)), plan, seed=999))
    print(f"twelve positions, poses set to {tolerance}°, effects at {size}σ, {seeds} seeds each")
    print(f"{'effect':<20} {'named (est.)':>12} {'named (0.1°)':>12} {'τ̂ median °':>11} "
          f"{'χ²/dof':>7} {'claimed':>8}")  # fmt: skip
    total_est = total_assumed = 0
    for effect in EFFECTS:
        est_hits = assumed_hits = claimed = 0
        taus, ratios, wrong = [], [], []
        for seed in range(seeds):
            doc, _ = hide_effect(
                clean_truth(seed), effect, np.random.default_rng(40_000 + seed), sigmas,
                low=size, high=size,
            )  # fmt: skip
            truth = Truth.from_dict(doc)
            est = analyse_discrepancy(
                simulate_session(truth, plan, seed=seed, estimate_scatter=True)
            )
            assumed_plan = twelve(0.1)
            # the same draws with the 0.1° assumption: the poses keep their true scatter
            session = simulate_session(truth, plan, seed=seed)
            assumed = analyse_discrepancy(_assume(session, assumed_plan))
            named = {f.effect for f in est.findings}
            est_hits += named == {effect}
            assumed_hits += {f.effect for f in assumed.findings} == {effect}
            if named != {effect}:
                wrong.append(sorted(named))
            assert est.noise is not None
            taus.append(est.noise.pose_scatter.value_deg)
            ratios.append(est.noise.chi2 / max(est.noise.dof, 1))
            claimed += any(s.claimed for s in est.scores.values())
        total_est += est_hits
        total_assumed += assumed_hits
        print(f"{effect:<20} {est_hits:>6}/{seeds:<5} {assumed_hits:>6}/{seeds:<5} "
              f"{np.median(taus):>11.4f} {np.mean(ratios):>7.2f} {claimed:>5}/{seeds}"
              + (f"  other: {wrong}" if wrong else ""))  # fmt: skip
    n = seeds * len(EFFECTS)
    print(f"named exactly: {total_est}/{n} estimated scatter, {total_assumed}/{n} assumed 0.1°")
    alarms = covered = 0
    for seed in range(seeds):
        res = analyse_discrepancy(
            simulate_session(Truth.from_dict(clean_truth(seed)), plan, seed=seed,
                             estimate_scatter=True)
        )  # fmt: skip
        alarms += bool(res.findings)
        assert res.noise is not None
        low, high = res.noise.pose_scatter.ci95_deg
        covered += low <= tolerance <= high
    print(f"clean data: {alarms}/{seeds} false alarms; scatter interval covers {tolerance}° "
          f"in {covered}/{seeds}")  # fmt: skip


def _assume(session: Any, plan: Plan) -> Any:
    """The session labelled with ``plan``'s tolerances (the scatter assumed, not estimated)."""
    import dataclasses

    averages = tuple(
        dataclasses.replace(a, pose=dataclasses.replace(a.pose, tolerance=p.tolerance))
        for a, p in zip(session.averages, plan.positions, strict=True)
    )
    return dataclasses.replace(session, averages=averages, scatter_source="flag")


def real_data() -> None:
    """Section 3 (module doc)."""
    sets = [
        ("imucal", ["imucal_example_ferraris_session.csv",
                    "imucal_example_ferraris_session_list.json"], 102.4, 9.81),
        ("imu_tk", ["imutk_xsens_acc.mat", "imutk_xsens_gyro.mat"], None, 9.81744),
    ]  # fmt: skip
    for name, files, rate, g in sets:
        paths = [DATA / f for f in files]
        if not all(p.exists() for p in paths):
            print(f"{name}: data absent ({DATA}), skipped")
            continue
        rec = read_recording(paths[0], second=paths[1], sample_rate_hz=rate)
        t0 = time.perf_counter()
        a = analyse_recording(rec, g=g)
        r = a.result
        print(f"{name}: {len(a.session.averages)} positions, method {r.method}, "
              f"{time.perf_counter() - t0:.1f} s")  # fmt: skip
        if r.noise is not None:
            est = r.noise.pose_scatter
            low, high = est.ci95_deg
            print(
                f"  pose scatter {est.value_deg:.4f}° (95 % {low:.4f}–{high:.4f}°, {est.source});"
                f" extended χ²/dof {r.noise.chi2 / max(r.noise.dof, 1):.2f} on {r.noise.dof}"
            )
        chi2, dof, _p = r.lack_of_fit
        print(f"  base lack of fit χ²/dof {chi2 / max(dof, 1):.2f} on {dof}")
        print(f"  findings: {[(f.effect, f.sensor) for f in r.findings]}")
        for sensor, s in r.scores.items():
            low, high = s.cv_rms_ratio_ci95
            print(
                f"  {sensor}: cv_rms {s.base_cv_rms:.4g} → {s.extended_cv_rms:.4g} "
                f"(×{s.cv_rms_ratio:.2f}, 95 % {low:.2f}–{high:.2f}); claimed {s.claimed}"
            )
        for w in r.warnings:
            print(f"  warning: {w}")
        if r.method == "joint":
            _earth_rate_gain(a.session)


def _earth_rate_gain(session: Any) -> None:
    """The gyro rows' χ² of the joint base fit without and with the fitted Earth rate."""
    from scipy import stats

    from canimucal.analysis.base_fit import EARTH_RATE_NAMES, fit_known

    prepared, res = fit_known(session)
    kept = [n for n in prepared.names if n in EARTH_RATE_NAMES]
    if not kept:
        return
    gyro = np.flatnonzero(prepared.sensor == "gyro")
    cov = prepared.covariance[np.ix_(gyro, gyro)]

    def chi2(resid: np.ndarray) -> float:
        r = resid[gyro]
        return float(r @ np.linalg.solve(cov, r))

    n = gyro.size
    before, after = chi2(res.residuals.ravel()), chi2(prepared.residual)
    f = ((before - after) / len(kept)) / (after / (n - 3 - len(kept)))
    p = float(stats.f.sf(f, len(kept), n - 3 - len(kept)))
    values = dict(zip(prepared.names, prepared.values, strict=True))
    w = np.array([values[k] for k in kept])
    print(
        f"  gyro rows χ²: bias only {before:.1f} on {n - 3} dof, with the Earth rate "
        f"{after:.1f} on {n - 3 - len(kept)} (F {f:.1f}, p {p:.2g}); fitted "
        f"{', '.join(f'{x:.3g}' for x in w)} rad/s, length {np.linalg.norm(w):.3g}"
    )


def main() -> None:
    """Parse the options and run the sections."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=15)
    p.add_argument("--size", type=float, default=5.0)
    p.add_argument("--tolerance", type=float, default=0.0)
    p.add_argument("--real-only", action="store_true")
    args = p.parse_args()
    real_data()
    if not args.real_only:
        hidden_study(args.seeds, args.size, args.tolerance)


if __name__ == "__main__":
    main()
