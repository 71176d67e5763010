"""`canimucal demo`: the whole job against the built-in simulated IMU.

Draws (or loads) a truth, records the plan from the simulated unit, solves it, and prints
every estimate beside the truth with its σ and the deviation in σ. Writes the recording, the
calibration JSON and the truth into ``--out`` (the tool's own directory: files there are
replaced).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.cli.output import dumps
from canimucal.io.atomic import write_text_atomic
from canimucal.io.calibration import Device, RecordingRef, calibration_to_json, sha256_of
from canimucal.io.grouping import position_averages
from canimucal.io.plans import resolve_plan
from canimucal.io.recording import write_recording
from canimucal.io.truth_file import load_truth
from canimucal.model.layout import JointSpec
from canimucal.model.plan import builtin_plan
from canimucal.procedure.offline import simulate_plan_recording
from canimucal.procedure.solution import SiteConditions, Solution, solve_positions
from canimucal.sim.truth import Truth


def add_subparser(subparsers: Any) -> None:
    """Register ``demo``."""
    p = subparsers.add_parser(
        "demo",
        help="calibrate the built-in simulated IMU end to end",
        description="Record a plan from the simulated IMU, solve it and compare with the truth.",
    )
    p.add_argument("--plan", default="recommended", help="two, five, recommended or a plan file")
    p.add_argument("--truth", help="truth JSON for the simulated unit (default: drawn at random)")
    p.add_argument("--seed", type=int, default=2026, help="random seed (truth and noise)")
    p.add_argument("--seconds", type=float, help="averaging seconds per position")
    p.add_argument("--out", default="demo-out", help="directory for the demo's files")
    p.add_argument("--headless", action="store_true", help="no TUI (the only mode for now)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo and print the comparison."""
    rng = np.random.default_rng(args.seed)
    truth = load_truth(args.truth) if args.truth else Truth.random(rng)
    plan = resolve_plan(args.plan, builtin_plan)
    if args.seconds is not None:
        plan = plan.with_total_seconds(args.seconds * len(plan.positions))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"simulating plan '{plan.name}': {len(plan.positions)} positions, "
        f"{plan.total_seconds:g} s of averaging at {truth.sample_rate_hz:g} Hz"
    )
    rec = simulate_plan_recording(truth, plan, seed=args.seed + 1)
    rec_path = write_recording(out / "recording.csv", rec, overwrite=True)
    spec = JointSpec(accel_k="full", tilt=truth.tilt_model, gyro="mems")
    site = SiteConditions(
        g=truth.g,
        latitude=truth.latitude,
        heading=truth.heading,
        accel_lsb=truth.accel.nominal_lsb,
        gyro_lsb=truth.gyro.nominal_lsb,
    )
    solution = solve_positions(
        position_averages(rec),
        spec,
        site,
        Device(serial=truth.serial),
        recording=RecordingRef(file=rec_path.name, sha256=sha256_of(rec_path)),
        plan_name=plan.name,
    )
    write_text_atomic(
        out / "calibration.json", calibration_to_json(solution.record), overwrite=True
    )
    write_text_atomic(out / "truth.json", dumps(truth.to_dict()), overwrite=True)
    print(comparison_report(solution, truth))
    for warning in solution.warnings:
        print(f"warning: {warning}")
    print(f"wrote {rec_path}, {out / 'calibration.json'}, {out / 'truth.json'}")
    return 0


def _truth_values(truth: Truth) -> dict[str, float]:
    values = {f"accel.bias[{i}]": float(truth.accel.bias[i]) for i in range(3)}
    values.update(
        {f"accel.K[{i}][{j}]": float(truth.accel.K[i, j]) for i in range(3) for j in range(3)}
    )
    values["base_tilt.alpha0"] = float(truth.alpha0)
    values["base_tilt.beta0"] = float(truth.beta0)
    values.update({f"gyro.bias[{i}]": float(truth.gyro.bias[i]) for i in range(3)})
    return values


def comparison_report(solution: Solution, truth: Truth) -> str:
    """Each estimated parameter beside the truth, with σ and the deviation in σ."""
    joint = solution.joint
    assert joint is not None
    expected = _truth_values(truth)
    lines = [f"{'parameter':<20}{'truth':>12}{'estimate':>12}{'σ':>10}{'dev/σ':>8}"]
    devs = []
    for k, name in enumerate(joint.names):
        if name not in expected or name in solution.undetermined:
            continue
        scale = float(np.rad2deg(1.0)) if name.startswith("base_tilt") else 1.0
        est, sig = joint.values[k] * scale, np.sqrt(joint.covariance[k, k]) * scale
        true = expected[name] * scale
        dev = (est - true) / sig
        devs.append(dev)
        label = name.replace("base_tilt.", "tilt.") + (" °" if scale != 1.0 else "")
        lines.append(f"{label:<20}{true:>12.5g}{est:>12.5g}{sig:>10.2g}{dev:>8.2f}")
    rms = float(np.sqrt(np.mean(np.square(devs))))
    lines.append(f"rms deviation {rms:.2f} σ over {len(devs)} parameters (expected ≈ 1)")
    return "\n".join(lines)
