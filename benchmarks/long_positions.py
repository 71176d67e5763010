"""`analyze` on long positions, the issue's shape (issue 21 item 12).

The recommended plan at 200 Hz with 417 s a position (670 k rows) and 625 s (10⁶ rows), a
random unit (cross-axis up to 1 %, base tilt up to 1°; ``--clean`` for none), no tolerance
in the header: the recording is written as a CSV and ``canimucal analyze`` run on it
in-process, as a user would. Printed: rows, exit status, what was named, the pose scatter
estimated, and the seconds it took. Before the fit's rank was judged at each parameter's
own precision it exited 2 ("the plan cannot determine accel.bias[1], …").

    python benchmarks/long_positions.py [--seconds 417,625] [--seed 1] [--clean]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canimucal.analysis.simulated import simulate_plan_recording  # noqa: E402
from canimucal.cli.main import main as canimucal  # noqa: E402
from canimucal.io.recording_writer import write_recording  # noqa: E402
from canimucal.model.vocabulary.plans import RECOMMENDED  # noqa: E402
from canimucal.sim.truth import Truth  # noqa: E402


def run(seconds: float, seed: int, clean: bool, folder: Path) -> str:
    """Simulate, write and analyse one recording; return the line to print."""
    limits = {"cross_axis_max": 0.0, "tilt_max_deg": 0.0} if clean else {}
    truth = Truth.random(np.random.default_rng(seed), **limits)
    plan = RECOMMENDED.with_total_seconds(seconds * len(RECOMMENDED.positions))
    rec = simulate_plan_recording(truth, plan, seed=seed)
    path = write_recording(folder / f"long_{seconds:g}.csv", rec, overwrite=True)
    out = folder / f"long_{seconds:g}.json"
    start = time.perf_counter()
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = canimucal(["analyze", str(path), "--json", str(out), "--overwrite"])
    elapsed = time.perf_counter() - start
    if code != 0:
        return f"{seconds:g} s a position: {rec.n_rows} rows, exit {code}: {err.getvalue().strip()}"
    doc = json.loads(out.read_text())
    named = [f["effect"] for f in doc["findings"]]
    tau = doc["noise"].get("pose_scatter_deg", {}).get("value")
    return (
        f"{seconds:g} s a position: {rec.n_rows} rows, exit 0, named {named or 'nothing'}, "
        f"pose scatter {tau:.3g}° [{elapsed:.0f} s]"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", default="417,625", help="seconds a position, comma-separated")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--clean", action="store_true", help="no cross-axis, a level base")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        for seconds in (float(s) for s in args.seconds.split(",")):
            print(run(seconds, args.seed, args.clean, Path(folder)), flush=True)


if __name__ == "__main__":
    main()
