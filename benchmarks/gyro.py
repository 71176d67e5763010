"""Gyro S from the moves: held-out angles, S against truth and bound, and imucal side by side.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/gyro.py [--seeds N] [--imucal-python PY]``.

1. **Simulator, held-out moves.** A unit with a hidden S (scales ±3 %, cross-axis ±1 %)
   records the turns plan (a 90° turn about each body axis and back, 0.1° pose errors) at
   100 Hz; S is fitted on it. A second recording of the same unit, other seed, other moves
   (the recommended plan's turns and tilt) is held out: each of its moves is integrated with
   the nominal S and with the fitted one, and the attitude errors compared with their joint
   covariance (S's, and the errors the moves share through their positions): χ²/dof ≈ 1.
2. **S against the truth and the bound** over ``--seeds`` units: the error of each entry in
   units of its σ, and the bound of ``plan --gyro moves`` for the same plan.
3. **imucal's session.** canimucal's S from the three ``*_rot`` turns against imucal 2.6.0's
   own ``K_g·R_g`` on the same data, each normalised by its trace, and the 360° turns
   integrated raw, with canimucal's S and with imucal's. imucal runs in a scratch venv
   (``--imucal-python``, or one this script creates with pinned versions: it is not a
   dependency of canimucal); without network or data, that part is skipped with a note.
4. **imu_tk's Xsens session, gravity only.** No pose has angles: S is fitted to the moves
   between still intervals through gravity's direction at their ends, on every other move;
   the other moves are held out and their gravity error (degrees) compared with the best
   common scale factor and with the fitted S, both ways round. S is printed beside the
   factory scale published with the data (the truth is unknown).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.support

from canimucal.analysis.calibrate import SiteConditions, solve_scalar
from canimucal.analysis.gravity_moves import recording_gravity_moves
from canimucal.analysis.gyro_bounds import gyro_move_bounds
from canimucal.analysis.gyro_moves import fit_recording_moves, recording_moves
from canimucal.analysis.session_model import ModelChoice
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.analysis.solve import site_of as recording_site
from canimucal.io.calibration import Device
from canimucal.io.grouping import average_rows, position_rows
from canimucal.io.importers import read_imucal, read_imutk
from canimucal.model import gravity_moves as gm
from canimucal.model import moves as mv
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.truth import Truth
from tests.support.moves import turns_plan

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
IMUCAL_PIP = (
    "imucal==2.6.0 numpy==2.4.6 pandas==3.1.1 python-dateutil==4.0.0 tzdata==2026.6 packaging==26.3"
)
IMUCAL_SCRIPT = """
import json, sys
import pandas as pd
from imucal import FerrarisCalibration, ferraris_regions_from_section_list
data = pd.read_csv(sys.argv[1], header=0, index_col=0)
sections = pd.read_json(sys.argv[2]).T
regions = ferraris_regions_from_section_list(data, sections)
cal = FerrarisCalibration().compute(regions, sampling_rate_hz=102.4, from_acc_unit="m/s^2",
                                    from_gyr_unit="deg/s")
print(json.dumps({"KgRg": (cal.K_g @ cal.R_g).tolist(), "b_g": cal.b_g.tolist(),
                  "K_ga": cal.K_ga.tolist()}))
"""


def site_of(truth: Truth) -> SiteConditions:
    return SiteConditions(
        g=truth.g,
        latitude=truth.latitude,
        heading=truth.heading,
        accel_lsb=truth.accel.nominal_lsb,
        gyro_lsb=truth.gyro.nominal_lsb,
    )


def held_out(seeds: int) -> None:
    print("1. held-out moves (recommended plan) of units calibrated on the turns plan")
    print(f"{'seed':>4} {'moves':>5} {'rms before':>11} {'rms after':>10} {'σ':>7} {'χ²/dof':>7}")
    for seed in range(seeds):
        truth = Truth.random(np.random.default_rng(seed), sample_rate_hz=100)
        site = site_of(truth)
        fit_rec = simulate_plan_recording(truth, turns_plan(), seed=seed, transient_s=2.0)
        fit = fit_recording_moves(recording_moves(fit_rec, site), site)
        plan = builtin_plan("recommended").with_total_seconds(40.0)
        test_rec = simulate_plan_recording(truth, plan, seed=1000 + seed, transient_s=2.0)
        found = recording_moves(test_rec, site)
        nominal = np.eye(3) / site.gyro_lsb
        before, after, jacs = [], [], []
        free = np.repeat(fit.identifiable[None, :], 3, axis=0).reshape(9)
        for move, bias in zip(found.moves, found.biases, strict=True):
            e0, _ = mv.move_residual(move, nominal, bias)
            e1, jac = mv.move_residual(move, fit.S_used(), bias)
            before.append(np.linalg.norm(e0))
            after.append(e1)
            jacs.append(jac[:, free])
        # the held-out moves share their positions' errors: one joint χ² over all of them
        r = mv.moves_covariance(
            found.moves, found.biases, fit.S_used(), found.rate_sigma_counts, found.shared
        )
        j = np.concatenate(jacs)
        e = np.concatenate(after)
        chi2 = float(e @ np.linalg.solve(j @ fit.covariance @ j.T + r, e))
        sig = np.sqrt(np.diag(r))
        rms = lambda x: float(np.rad2deg(np.sqrt(np.mean(np.square(x)))))  # noqa: E731
        print(
            f"{seed:>4} {len(found.moves):>5} {rms(before):>10.3f}° "
            f"{rms(np.linalg.norm(after, axis=1)):>9.3f}° {rms(sig):>6.3f}° {chi2 / e.size:>7.2f}"
        )


def s_against_truth(seeds: int) -> None:
    print("\n2. S from the turns plan against the truth (error in σ) and the plan's bound")
    z, rel = [], []
    for seed in range(seeds):
        truth = Truth.random(np.random.default_rng(100 + seed), sample_rate_hz=100)
        site = site_of(truth)
        rec = simulate_plan_recording(truth, turns_plan(), seed=seed, transient_s=2.0)
        fit = fit_recording_moves(recording_moves(rec, site), site)
        z.append(((fit.S - truth.gyro.S) / fit.S_sigma).reshape(9))
        rel.append((fit.S_sigma * site.gyro_lsb).reshape(9))
    za = np.array(z)
    bound = gyro_move_bounds(turns_plan()).relative_sigma.reshape(9)
    print(f"{'entry':>6} {'mean z':>7} {'std z':>6} {'max |z|':>8} {'σ/scale':>9} {'bound':>9}")
    for k, name in enumerate(mv.S_NAMES):
        print(
            f"{name:>6} {za[:, k].mean():>7.2f} {za[:, k].std(ddof=1):>6.2f} "
            f"{np.abs(za[:, k]).max():>8.2f} {np.mean(rel, axis=0)[k]:>9.2e} {bound[k]:>9.2e}"
        )


def imucal_python(given: str | None) -> str | None:
    if given:
        return given
    venv = Path(tempfile.gettempdir()) / "canimucal-bench-imucal-venv"
    python = venv / "bin" / "python"
    if not python.exists():
        print(f"   creating a scratch venv for imucal at {venv}")
        try:
            subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
            pip = [str(venv / "bin" / "pip"), "install", "-q", *IMUCAL_PIP.split()]
            subprocess.run(pip, check=True, timeout=600)
        except (subprocess.SubprocessError, OSError) as exc:
            print(f"   imucal not installed ({exc}); part 3 skipped")
            return None
    return str(python)


def imucal_side_by_side(python: str | None) -> None:
    print("\n3. imucal's example session: canimucal's S against imucal's K_g·R_g")
    csv = DATA / "imucal_example_ferraris_session.csv"
    sections = DATA / "imucal_example_ferraris_session_list.json"
    if not csv.is_file():
        print(f"   data absent at {DATA}; skipped")
        return
    rec = read_imucal(csv, sections, 102.4)
    site = SiteConditions(g=9.81, accel_lsb=1.0, gyro_lsb=float(np.pi / 180.0))
    found = recording_moves(rec, site, pose_moves=False)
    fit = fit_recording_moves(found, site)
    ours = fit.S * np.pi / 180.0  # counts are deg/s
    theirs = None
    py = imucal_python(python)
    if py is not None:
        with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as handle:
            handle.write(IMUCAL_SCRIPT)
        proc = subprocess.run(
            [py, handle.name, str(csv), str(sections)], capture_output=True, text=True
        )
        Path(handle.name).unlink()
        if proc.returncode == 0:
            theirs = np.array(json.loads(proc.stdout)["KgRg"])
        else:
            print(f"   imucal failed: {proc.stderr.strip().splitlines()[-1:]}")
    np.set_printoptions(precision=6, suppress=True)
    print("   canimucal S (dimensionless, per deg/s), σ from the 0.1° pose tolerance:")
    print("   " + str(ours).replace("\n", "\n   "))
    if theirs is not None:
        print("   imucal K_g·R_g:")
        print("   " + str(theirs).replace("\n", "\n   "))
        d = np.abs(ours * 3 / np.trace(ours) - theirs * 3 / np.trace(theirs))
        print(f"   max |ΔS_ij|·3/tr S = {d.max():.2e} (issue limit 5e-3)")
    print(f"   {'turn':<6} {'raw':>28} {'canimucal S':>28} {'imucal S':>28}")
    bias = found.biases[0]
    for move in found.moves:
        raw = np.rad2deg(mv.integrated_turn(move, np.eye(3) * 180 / np.pi, bias))
        cal = np.rad2deg(mv.integrated_turn(move, fit.S, bias))
        row = f"   {move.label:<6} {_vec(raw):>28} {_vec(cal):>28}"
        if theirs is not None:
            row += f" {_vec(np.rad2deg(mv.integrated_turn(move, theirs * 180 / np.pi, bias))):>28}"
        print(row)
    print("   (both fitted on these turns: their calibrated angles are a consistency check)")


def imutk_gravity() -> None:
    print("\n4. imu_tk's Xsens session: S from moves matched on gravity, held-out moves")
    acc, gyr = DATA / "imutk_xsens_acc.mat", DATA / "imutk_xsens_gyro.mat"
    if not (acc.is_file() and gyr.is_file()):
        print(f"   skipped: no imu_tk data in {DATA}")
        return
    rec = read_imutk(acc, gyr)
    site, _ = recording_site(rec, ModelChoice(model="full", g=9.81744))
    averages = [average_rows(rec, r) for r in position_rows(rec)[0]]
    scalar = solve_scalar(averages, site, Device(serial=0), full=True)
    found = recording_gravity_moves(rec, scalar.record.accel, site.accel_lsb)
    s0 = np.eye(3) / site.gyro_lsb
    print(f"   {len(found.moves)} moves; nominal scale {1 / site.gyro_lsb:.1f} counts per rad/s")
    print(
        f"   {'fit on':<7} {'common k':>9} {'rms before':>11} {'rms after':>10} {'max after':>10}"
    )
    for first in (0, 1):
        fitted, held = found.moves[first::2], found.moves[1 - first :: 2]
        fit = gm.solve_gravity_moves(fitted, s0, found.rate_sigma_counts)
        k = gm.start_scale(fitted, s0)
        before = np.array([gm.gravity_angle_deg(m, k * s0) for m in held])
        after = np.array([gm.gravity_angle_deg(m, fit.S_used()) for m in held])
        print(
            f"   {'even' if first == 0 else 'odd':<7} {k:>9.4f} "
            f"{np.sqrt(np.mean(before**2)):>10.2f}° {np.sqrt(np.mean(after**2)):>9.2f}° "
            f"{after.max():>9.2f}°"
        )
    fit = gm.solve_gravity_moves(found.moves, s0, found.rate_sigma_counts)
    print("   S on every move (counts per rad/s, the accelerometer's axes), ± σ:")
    for i in range(3):
        row = "  ".join(f"{fit.S[i, j]:8.1f} ± {fit.S_sigma[i, j]:4.1f}" for j in range(3))
        print(f"     {row}")
    print("   factory scale (published with the data): 4778, 4758, 4766")
    print(
        f"   χ²/dof {fit.chi2 / fit.dof:.1f} (σ scaled by {fit.sigma_inflation:.2f}); "
        f"identifiable columns: {''.join(mv.AXES[j] for j in np.flatnonzero(fit.identifiable))}"
    )


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:8.3f}" for x in v) + "]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--imucal-python", help="python of a venv with imucal 2.6.0")
    args = parser.parse_args()
    start = time.perf_counter()
    held_out(args.seeds)
    s_against_truth(args.seeds)
    imucal_side_by_side(args.imucal_python)
    imutk_gravity()
    print(f"\n{time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
