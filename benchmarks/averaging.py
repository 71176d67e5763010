"""The averaging-time rule over many seeds (issue 14, item 6): which axis limits, what it costs.

Two studies, 100 Hz, white noise 3 counts per sample:

1. A white accelerometer and a gyro whose z axis walks (0.025 counts/√s, optimum ≈ 21 s),
   600 s of each: how often ``gyro.z`` is named, the time chosen, and what the limiting gyro
   axis loses against its own best at the old accelerometer-only answer (120 s) and at the
   chosen time.
2. Pure white noise, 120 s (a first position): the time chosen from the accelerometer alone
   and from both sensors (the fitted walks scatter; the rule should stay near the clip).

Run: ``python benchmarks/averaging.py [--seeds N]``. Prints the figures quoted in
``canimucal/procedure/averaging.py`` and the closing notes.
"""

from __future__ import annotations

import argparse

import numpy as np

from canimucal.procedure.averaging import noise_choice

FS = 100.0
CLIP = (15.0, 120.0)


def rows(seed: int, walk: list[float], seconds: float) -> np.ndarray:
    """White noise 3 counts/sample plus a random walk per axis (counts/√s)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    steps = rng.normal(0.0, 1.0, (n, 3)) * np.array(walk) / np.sqrt(FS)
    return rng.normal(0.0, 3.0, (n, 3)) + np.cumsum(steps, axis=0)


def drifting_gyro(seeds: int) -> None:
    named, times, at_upper, at_chosen = 0, [], [], []
    for seed in range(1, seeds + 1):
        samples = {
            "accel": rows(seed, [0.0, 0.0, 0.0], 600.0),
            "gyro": rows(50 + seed, [0.0, 0.0, 0.025], 600.0),
        }
        choice = noise_choice(samples, FS, CLIP)
        if choice is None:
            continue
        picked, terms = choice
        times.append(picked.seconds)
        if picked.limiting_axis != "gyro.z":
            continue
        named += 1
        t = terms["gyro"]
        best = float(t.adev(picked.optima_s["gyro"])[2, 2])
        at_upper.append(float(t.adev(CLIP[1])[0, 2]) / best)
        at_chosen.append(max(float(np.max(v)) for v in picked.loss.values()))
    print(f"1. drifting gyro z, white accelerometer, 600 s, {seeds} seeds")
    print(f"   gyro.z named: {named}/{seeds}")
    print(
        f"   time chosen: median {np.median(times):.0f} s, "
        f"range {min(times):.0f}-{max(times):.0f} s"
    )
    print(
        f"   limiting axis's loss vs its best: at 120 s {min(at_upper):.2f}-{max(at_upper):.2f}"
        f" (median {np.median(at_upper):.2f}); worst axis at the chosen time "
        f"{min(at_chosen):.2f}-{max(at_chosen):.2f}"
    )


def white(seeds: int) -> None:
    accel_only, both = [], []
    for seed in range(1, seeds + 1):
        accel = rows(seed, [0.0] * 3, 120.0)
        gyro = rows(1000 + seed, [0.0] * 3, 120.0)
        for store, samples in (
            (accel_only, {"accel": accel}),
            (both, {"accel": accel, "gyro": gyro}),
        ):
            choice = noise_choice(samples, FS, CLIP)
            store.append(choice[0].seconds if choice is not None else CLIP[1])
    print(f"2. pure white noise, 120 s first position, {seeds} seeds")
    for label, values in (("accelerometer alone", accel_only), ("both sensors", both)):
        print(
            f"   {label}: median {np.median(values):.0f} s, "
            f"5th percentile {np.percentile(values, 5):.0f} s"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    args = parser.parse_args()
    drifting_gyro(args.seeds)
    white(args.seeds)


if __name__ == "__main__":
    main()
