"""Cost of long recordings (issue 23): `solve`, `allan`, `analyze` beside pandas' C parser.

Writes an N-row simulated recording of a plan at 200 Hz (``make_recording.py``; kept when
``--file`` names an existing one), then runs ``canimucal solve``, ``allan`` and ``analyze`` on it
as child processes, each ``--repeats`` times, and prints CPU seconds (user + system), wall
seconds and peak RSS of each run (min/median/max), from the child's own ``wait4`` usage.
When pandas is importable by ``--pandas-python`` (default: this interpreter), the same file
is read with ``pandas.read_csv(engine="c")`` as the floor, and each command's CPU and peak
RSS are printed as a ratio to it. pandas is not a dependency: point ``--pandas-python`` at a
scratch venv's python.

Figures before and after the compact reader (issue 23) are in docs/performance.md: at 10⁷
rows on the 2-core machine, ``solve`` 13.9 s CPU and 804 MiB peak (2.2× pandas' CPU, 0.39×
its RSS), ``allan`` 2.6×, ``analyze`` 3.8×.

Run: ``.venv/bin/python benchmarks/long_recording.py --rows 1000000 [--repeats 3]
[--pandas-python /tmp/pd/bin/python] [--file KEEP.csv] [--verbs solve,allan,analyze]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from make_recording import write_plan_recording  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PANDAS_READ = (
    "import sys, pandas; t = pandas.read_csv(sys.argv[1], engine='c', comment='#', header=0,"
    " dtype='float64'); assert len(t) > 0"
)
"""The floor: the file into a float64 table (the header lines are comments to pandas)."""


@dataclass(frozen=True)
class Run:
    """One child process: CPU seconds (user + system), wall seconds, peak RSS (MiB), exit."""

    cpu_s: float
    wall_s: float
    rss_mib: float
    status: int


def run_child(argv: list[str]) -> Run:
    """Run ``argv`` with its output discarded; measure it with ``wait4``."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    start = time.perf_counter()
    child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    cpu = usage.ru_utime + usage.ru_stime
    return Run(cpu, wall, usage.ru_maxrss / 1024.0, child.returncode)


def spread(values: list[float]) -> str:
    """``min/median/max`` of ``values``."""
    return f"{min(values):.2f}/{statistics.median(values):.2f}/{max(values):.2f}"


def count_rows(path: Path) -> int:
    """Data rows of a recording: its lines but the header and the column line."""
    lines = header = 0
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 24), b""):
            lines += block.count(b"\n")
            if not header:
                header = block.count(b"\n#") + 1
    return lines - header - 1


def has_pandas(python: str) -> bool:
    """Whether ``python`` imports pandas."""
    probe = subprocess.run([python, "-c", "import pandas"], capture_output=True, check=False)
    return probe.returncode == 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--plan", default="recommended")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--file", type=Path, help="recording to use (written when absent)")
    parser.add_argument("--pandas-python", default=sys.executable)
    parser.add_argument("--verbs", default="solve,allan,analyze")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.file or Path(tmp) / f"r{args.rows}.csv"
        if not path.exists():
            start = time.perf_counter()
            write_plan_recording(path, args.rows, plan_name=args.plan)
            print(f"wrote {path} in {time.perf_counter() - start:.0f} s")
        size_mb = path.stat().st_size / 1e6
        print(f"{path.name}: {count_rows(path):,} rows, {size_mb:.0f} MB")
        print(f"{'command':<10} {'CPU s (min/med/max)':>22} {'wall s':>22} {'peak MiB':>22}  exit")
        floor: Run | None = None
        results: dict[str, list[Run]] = {}
        if has_pandas(args.pandas_python):
            runs = [
                run_child([args.pandas_python, "-c", PANDAS_READ, str(path)])
                for _ in range(args.repeats)
            ]
            results["pandas"] = runs
            cpu = statistics.median(r.cpu_s for r in runs)
            rss = statistics.median(r.rss_mib for r in runs)
            floor = Run(cpu, statistics.median(r.wall_s for r in runs), rss, 0)
        for verb in args.verbs.split(","):
            argv = [sys.executable, "-m", "canimucal", verb, str(path)]
            results[verb] = [run_child(argv) for _ in range(args.repeats)]
        for name, runs in results.items():
            print(
                f"{name:<10} {spread([r.cpu_s for r in runs]):>22} "
                f"{spread([r.wall_s for r in runs]):>22} "
                f"{spread([r.rss_mib for r in runs]):>22}  {sorted({r.status for r in runs})}"
            )
        if floor is None:
            print("pandas not importable: no ratios (give --pandas-python of a venv with pandas)")
            return
        for verb in args.verbs.split(","):
            runs = results[verb]
            cpu = statistics.median(r.cpu_s for r in runs) / floor.cpu_s
            rss = statistics.median(r.rss_mib for r in runs) / floor.rss_mib
            print(f"{verb:<10} / pandas: CPU ×{cpu:.2f}, peak RSS ×{rss:.2f} (medians)")


if __name__ == "__main__":
    main()
