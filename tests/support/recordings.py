"""Large recording files written in bulk (the reader's tests and benchmarks/read_speed.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from canimucal.io.recording import COLUMN_LINE


def write_bulk_recording(path: Path, n: int, chunk: int = 20_000) -> Path:
    """A 200 Hz recording of ``n`` rows, 12 000 rows per position, formatted in bulk."""
    rng = np.random.default_rng(6)
    fmt = "%.6f,%d,%d,%.1f,%.2f,0,%d,%d,%d,%d,%d,%d,\n"
    header = "# schema: canimucal.recording/1\n# sample_rate_hz: 200\n" + COLUMN_LINE + "\n"
    with open(path, "w", encoding="ascii") as handle:
        handle.write(header)
        for start in range(0, n, chunk):
            k = np.arange(start, min(n, start + chunk))
            pos = k // 12_000
            cols = [1.7e9 + k / 200, k % 65536, pos, pos * 0.5, pos * 0.25]
            cols += list(rng.integers(-2000, 2000, (6, k.size)))
            rows = np.column_stack(cols).astype(object)
            handle.write((fmt * k.size) % tuple(rows.ravel().tolist()))
    return path
