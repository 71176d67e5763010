"""Write an N-row simulated recording of any plan at 200 Hz, streamed (issue 23).

The simulated unit follows the plan, every position held for an equal share of the N rows
(2 s moves between), labelled as a session labels them; blocks of rows go straight to the
file through :class:`~canimucal.io.recording_writer.RecordingWriter`, so memory does not
grow with N (10⁸ rows need no more than 10⁴).

Run: ``.venv/bin/python benchmarks/make_recording.py OUT.csv 1000000 [--plan recommended]
[--seed 1]``. Imported by ``benchmarks/long_recording.py`` and the long-recording tests.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canimucal.io.recording import HeaderValue
from canimucal.io.recording_writer import RecordingWriter
from canimucal.model.vocabulary.constants import COUNTER_MODULUS
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.imu import ImuSimulator
from canimucal.sim.schedule import set_by_operator
from canimucal.sim.truth import Truth

SAMPLE_RATE_HZ = 200.0
TRANSIENT_S = 2.0
BLOCK_ROWS = 50_000


def write_plan_recording(
    path: Path,
    n_rows: int,
    *,
    plan_name: str = "recommended",
    seed: int = 1,
    angle_errors: bool = False,
) -> Path:
    """Simulate ``plan_name`` over ``n_rows`` samples at 200 Hz into ``path`` (new file).

    With ``angle_errors`` the unit is set to each pose plus an error drawn from the plan's
    tolerance (labelled with the nominal angles, ``tolerance_deg`` in the header).
    """
    truth = Truth.random(np.random.default_rng(seed), cross_axis_max=0.0)
    plan = builtin_plan(plan_name)
    moving_s = TRANSIENT_S * len(plan.positions)
    total_s = n_rows / SAMPLE_RATE_HZ - moving_s
    if total_s <= 0:
        raise ValueError(f"{n_rows} rows are too few for the {plan_name} plan")
    plan = plan.with_total_seconds(total_s)
    sim = ImuSimulator(truth, seed=seed)
    sim.set_sample_rate(SAMPLE_RATE_HZ)
    first = plan.positions[0]
    sim.set_pose(first.alpha, first.beta, first.psi, transient_s=0.0)
    actual = set_by_operator(plan, np.random.default_rng(seed)) if angle_errors else plan
    sim.set_schedule(actual, transient_s=TRANSIENT_S)
    degrees = np.array([np.rad2deg(p.angles) for p in plan.positions])
    header: dict[str, HeaderValue] = {
        "sample_rate_hz": SAMPLE_RATE_HZ,
        "g": float(truth.g),
        "latitude_deg": float(np.rad2deg(truth.latitude)),
        "heading_deg": float(np.rad2deg(truth.heading)),
        "accel_lsb": float(truth.accel.nominal_lsb),
        "gyro_lsb": float(truth.gyro.nominal_lsb),
        "plan": plan_name,
    }
    if angle_errors:
        header["tolerance_deg"] = float(np.rad2deg(plan.positions[0].tolerance))
    written = 0
    with RecordingWriter.open(path, header) as writer:
        while written < n_rows:
            block = sim.next_block(min(BLOCK_ROWS, n_rows - written))
            index = block.position_index
            angles = np.where(index[:, None] >= 0, degrees[np.maximum(index, 0)], np.nan)
            writer.write_rows(
                t=block.t_s,
                accel=block.accel,
                gyro=block.gyro,
                counter=(written + np.arange(index.size)) % COUNTER_MODULUS,
                position=index,
                alpha_deg=angles[:, 0],
                beta_deg=angles[:, 1],
                psi_deg=angles[:, 2],
                temp_c=np.round(block.temp_c, 3),
            )
            written += index.size
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("rows", type=int)
    parser.add_argument("--plan", default="recommended")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--angle-errors", action="store_true", help="poses set within tolerance")
    args = parser.parse_args()
    write_plan_recording(
        args.out, args.rows, plan_name=args.plan, seed=args.seed, angle_errors=args.angle_errors
    )
    print(f"{args.out}: {args.rows} rows, {args.out.stat().st_size / 1e6:.0f} MB")


if __name__ == "__main__":
    main()
