"""Time import-log on each bus log format of a simulated session (python-can's writers).

Run: ``.venv/bin/python benchmarks/bus_log_import.py [--seconds S]``. Records the five plan
(``S`` seconds a position, default 30) from the simulated node at 50× time with
``record --can-log`` in every format python-can writes without extras, then imports each log
and prints wall and CPU seconds, frames per second, the file size and the ratio to the
target: an hour at 200 Hz (about 1.5 million frames with TPDO1–3) in under 60 s on a
shared 2-core machine, scaled to the frames of the log.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canimucal.cli.main import main as canimucal
from canimucal.runtime.inputs import import_log

FORMATS = (".log", ".asc", ".blf", ".trc", ".csv", ".db")
HOUR_FRAMES = 3600 * 200 * 2.05  # TPDO1 and TPDO2 per sample, TPDO3 at 10 Hz
TARGET_HOUR_S = 60.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        argv = ["record", str(root / "rec.csv"), "--sim", "--plan", "five", "--seconds",
                str(args.seconds), "--time-scale", "50", "--seed", "1"]  # fmt: skip
        for suffix in FORMATS:
            argv += ["--can-log", str(root / f"session{suffix}")]
        with contextlib.redirect_stdout(io.StringIO()):
            assert canimucal(argv) == 0
        for suffix in FORMATS:
            path = root / f"session{suffix}"
            wall, cpu = time.perf_counter(), time.process_time()
            result = import_log(path, plan="five", sample_rate_hz=200.0)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            target = TARGET_HOUR_S * result.frames / HOUR_FRAMES
            print(
                f"{suffix:>5}: {result.frames} frames ({path.stat().st_size / 1e6:.1f} MB), "
                f"{result.recording.n_rows} rows: {wall:.2f} s wall, {cpu:.2f} s CPU, "
                f"{result.frames / wall:,.0f} frames/s; target {target:.2f} s "
                f"(ratio {wall / target:.2f})"
            )


if __name__ == "__main__":
    main()
