"""Time the overlapping Allan deviation on one hour at 1 kHz (3.6 M samples per axis).

Run: ``.venv/bin/python benchmarks/noise_speed.py``. Prints the wall and CPU time per axis
(CPU time is the fairer number on a shared machine) for the
default (strided starts for m >= 32) and the fully overlapping estimator, and checks that
the two agree within a fraction of each point's σ.
"""

from __future__ import annotations

import time

import numpy as np

from canimucal.model.noise import allan_deviation, fit_noise

FS = 1000.0
N_SAMPLES = 3_600_000


def main() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 1.0, (N_SAMPLES, 3))
    for full in (False, True):
        wall, cpu = time.perf_counter(), time.process_time()
        res = allan_deviation(x, FS, full_overlap=full)
        wall_axis = (time.perf_counter() - wall) / 3
        cpu_axis = (time.process_time() - cpu) / 3
        label = "fully overlapping" if full else "default (strided)"
        print(
            f"{label:>18}: {wall_axis:.3f} s wall, {cpu_axis:.3f} s CPU per axis, "
            f"{res.taus_s.size} taus"
        )
    fast = allan_deviation(x[:, 0], FS)
    full_res = allan_deviation(x[:, 0], FS, full_overlap=True)
    shift = np.max(np.abs(fast.adev - full_res.adev) / full_res.adev_sigma)
    print(f"largest difference between the two: {shift:.3f} σ")
    density = fit_noise(fast).white_noise_density[0]
    print(f"fitted white density {density:.6f} (truth {1.0 / np.sqrt(FS):.6f})")


if __name__ == "__main__":
    main()
