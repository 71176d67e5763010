"""imucal's example session: `solve --gyro moves` and `analyze` beside imucal's own Ferraris run.

Issue 23 asks both to be no slower than imucal 2.6.0 on the session it ships (102.4 Hz, six
static poses and three turns; ``../shared/data/imucal_example_ferraris_session.csv`` and its
section list), wall seconds, paired. The peer is a four-line driver of imucal's public API
(read the CSV with pandas, the section list, ``ferraris_regions_from_section_list``,
``FerrarisCalibration().compute``), run by ``--imucal-python``: a scratch venv's python with
``imucal==2.6.0`` (not a dependency). Each pair runs the two commands back to back, in turn
which goes first, ``--repeats`` times after one warm-up pair; printed: wall and CPU seconds
(user + system, the child's own ``wait4`` usage) min/median/max, and the median of the
pairwise ratios, canimucal over imucal (below 1: faster).

Run: ``.venv/bin/python benchmarks/imucal_session.py --imucal-python /tmp/im/bin/python
[--repeats 7]``. Skips with a message when the data or the peer are absent.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SESSION = DATA / "imucal_example_ferraris_session.csv"
SECTIONS = DATA / "imucal_example_ferraris_session_list.json"
RATE_HZ = "102.4"

IMUCAL_DRIVER = """
import sys, pandas as pd
from imucal import FerrarisCalibration, ferraris_regions_from_section_list
data = pd.read_csv(sys.argv[1], header=0, index_col=0)
regions = ferraris_regions_from_section_list(data, pd.read_json(sys.argv[2]).T)
info = FerrarisCalibration().compute(
    regions, sampling_rate_hz=float(sys.argv[3]), from_acc_unit="m/s^2", from_gyr_unit="deg/s"
)
print(info.K_g @ info.R_g)
"""


def bytecode_env(cache: str) -> dict[str, str]:
    """The children's environment: bytecode cached under ``cache``, as an installed wheel has it.

    pip compiles a wheel's modules when it installs them (imucal's, in the peer's venv), but
    an editable install is compiled on first import and, where ``PYTHONDONTWRITEBYTECODE`` is
    set (this machine sets it), on every run: about 0.4 s of `solve`'s CPU here is compiling
    canimucal. Both sides get one cache prefix, filled by the warm-up pair.
    """
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = cache
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


ENV: dict[str, str] | None = None


def run(argv: list[str]) -> tuple[float, float]:
    """Run ``argv``; return (wall s, CPU s). A failing command stops the benchmark."""
    start = time.perf_counter()
    proc = subprocess.Popen(
        argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=ENV
    )
    _pid, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        err = proc.stderr.read().decode() if proc.stderr else ""
        raise SystemExit(f"{' '.join(argv[:4])} … failed: {err.strip()[-400:]}")
    return wall, usage.ru_utime + usage.ru_stime


def spread(values: list[float]) -> str:
    return f"{min(values):.2f} / {statistics.median(values):.2f} / {max(values):.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--imucal-python", required=True, help="python with imucal 2.6.0")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    if not SESSION.is_file() or not SECTIONS.is_file():
        print(f"imucal's example session not found under {DATA}: nothing measured")
        return
    global ENV
    with tempfile.TemporaryDirectory() as tmp:
        ENV = bytecode_env(f"{tmp}/pycache")
        driver = Path(tmp) / "imucal_ferraris.py"
        driver.write_text(IMUCAL_DRIVER)
        peer = [args.imucal_python, str(driver), str(SESSION), str(SECTIONS), RATE_HZ]
        common = ["--format", "imucal", str(SESSION), str(SECTIONS), "--sample-rate-hz", RATE_HZ]
        ours = {
            "solve --gyro moves": [
                sys.executable, "-m", "canimucal", "solve", *common, "--gyro", "moves",
                "--model", "full", "--no-check", "--json", f"{tmp}/s.json", "--overwrite",
            ],
            "analyze": [
                sys.executable, "-m", "canimucal", "analyze", *common, "--g", "9.81",
                "--json", f"{tmp}/a.json", "--overwrite",
            ],
        }  # fmt: skip
        try:
            run(peer)
        except (OSError, SystemExit) as exc:
            print(f"the peer does not run ({exc}): nothing measured")
            return
        print(f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}; {args.repeats} pairs each")
        print("wall and CPU s: min / median / max; ratio: median of canimucal/imucal per pair")
        for name, argv in ours.items():
            mine, theirs = [], []
            run(argv)  # warm-up pair
            run(peer)
            for k in range(args.repeats):
                if k % 2:
                    theirs.append(run(peer))
                    mine.append(run(argv))
                else:
                    mine.append(run(argv))
                    theirs.append(run(peer))
            wall = [a[0] / b[0] for a, b in zip(mine, theirs, strict=True)]
            cpu = [a[1] / b[1] for a, b in zip(mine, theirs, strict=True)]
            print(
                f"{name:>20}: wall {spread([m[0] for m in mine])}, "
                f"CPU {spread([m[1] for m in mine])}"
                f" | imucal wall {spread([t[0] for t in theirs])}, CPU "
                f"{spread([t[1] for t in theirs])} | ratio wall {statistics.median(wall):.2f}, "
                f"CPU {statistics.median(cpu):.2f}"
            )


if __name__ == "__main__":
    main()
