"""Time reading recordings: 6 minutes and one hour at 200 Hz (72 000 and 720 000 rows).

Run: ``.venv/bin/python benchmarks/read_speed.py``. Prints wall and CPU seconds, rows per
second, and the ratio to the target (one hour in under 10 s, 6 minutes in under 3 s, on a
shared 2-core machine).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.support

from canimucal.io.recording import read_recording_csv
from tests.support.recordings import write_bulk_recording

TARGETS_S = {72_000: 3.0, 720_000: 10.0}


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for n, target in TARGETS_S.items():
            path = write_bulk_recording(Path(tmp) / f"r{n}.csv", n)
            wall, cpu = time.perf_counter(), time.process_time()
            rec = read_recording_csv(path)
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            assert rec.n_rows == n
            print(
                f"{n:>7} rows ({path.stat().st_size / 1e6:.0f} MB): {wall:.2f} s wall, "
                f"{cpu:.2f} s CPU, {n / wall:,.0f} rows/s; target {target:g} s "
                f"(ratio {wall / target:.2f})"
            )


if __name__ == "__main__":
    main()
