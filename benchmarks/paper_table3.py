"""The paper's Table 3 (five positions, base tilted −1°/−1°) against the simulated procedure.

Issue 5, item 7; ``docs/paper-tables.md`` states the assumptions. The paper's Fourier least
squares (``fourier_accel``, eq. 17-34) runs on simulated position means: per-axis
sensitivity k fitted to Table 2 (``benchmarks/discrepancy.py``), bias 0 V, g = 9.81, the
five poses (0,0), (22.5,0), (22.5,2.5), (45,2.5), (45,5), base tilt (−1°, −1°) under both
tilt readings (rigid base, the paper's additive angles). Printed per row: the noise-free
error (systematic part), the σ of one position mean that makes the row's σ (its noise
amplification), the white-noise level fitted to the rows' scatter over 5-60 s, and each
row's scatter and mean in units of that prediction.

Run: ``.venv/bin/python benchmarks/paper_table3.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from discrepancy import G_PAPER, TABLE2, _fit_axes  # noqa: E402

from canimucal.model.dcm_stack import dcm_stack  # noqa: E402
from canimucal.model.layout import ModelContext  # noqa: E402
from canimucal.model.paper.accel import fourier_accel  # noqa: E402
from canimucal.model.paper.common import (  # noqa: E402
    ACCEL_BIAS_NAMES,
    ACCEL_SCALE_NAMES,
    TILT_CHANNEL_NAMES,
)
from canimucal.model.positions import Pose, PositionAverage  # noqa: E402

SECONDS = np.array([5.0, 15.0, 30.0, 45.0, 60.0])
TABLE3 = np.array(  # rows as ROWS; columns SECONDS
    [[-0.00994, 0.00050, 0.00323, 0.00319, 0.00528],
     [-0.02866, 0.03066, 0.02719, 0.02947, 0.02715],
     [-0.01564, -0.04652, -0.01959, -0.00941, -0.00553],
     [-0.00034, 0.00010, -0.00005, -0.00002, 0.00004],
     [0.00179, 0.00162, 0.00200, 0.00180, 0.00204],
     [0.00299, 0.01453, 0.00743, 0.00493, 0.00454],
     [0.09390, 0.02965, 0.00843, 0.00953, -0.00136],
     [0.00046, -0.00172, -0.00137, -0.00899, -0.00455],
     [-0.59054, -1.42053, -0.57973, -0.24924, -0.18906],
     [0.20115, -0.01295, 0.04716, 0.07612, 0.09278],
     [0.00506, 0.17152, 0.02003, -0.03830, -0.05815]]
)  # fmt: skip
ROWS = (
    "dUx0 V", "dUy0 V", "dUz0 V", "dK11", "dK22", "dK33",
    "da0(23) deg", "da0(29) deg", "da0(33) deg", "db0(28) deg", "db0(32) deg",
)  # fmt: skip
NAMES = ACCEL_BIAS_NAMES + ACCEL_SCALE_NAMES + TILT_CHANNEL_NAMES
CHANNEL = (0, 1, 2, 0, 1, 2, 0, 1, 2, 1, 2)
"""The accelerometer channel whose means make each row."""
CHANNEL_ROWS = tuple(tuple(i for i, c in enumerate(CHANNEL) if c == ch) for ch in range(3))
POSES_DEG = ((0.0, 0.0), (22.5, 0.0), (22.5, 2.5), (45.0, 2.5), (45.0, 5.0))
TILT_DEG = (-1.0, -1.0)


def errors_and_sigmas(k: np.ndarray, model: str, sigma_mean: float) -> tuple[np.ndarray, ...]:
    """Noise-free error (estimate − truth) of each row and its σ for position means of σ."""
    f_level = ModelContext.build(G_PAPER).f_level
    angles = np.deg2rad([[a, b, 0.0] for a, b in POSES_DEG])
    alpha0, beta0 = (float(v) for v in np.deg2rad(TILT_DEG))
    c, _, _ = dcm_stack(angles, alpha0, beta0, model)  # type: ignore[arg-type]
    means = (c @ f_level) * k
    avgs = [
        PositionAverage(Pose(*np.deg2rad(p)), 1000, m, np.eye(3) * sigma_mean**2)
        for p, m in zip(POSES_DEG, means, strict=True)
    ]
    res = fourier_accel(avgs, G_PAPER)
    est = np.array([res.value(n) for n in NAMES])
    sig = np.array([res.sigma(n) for n in NAMES])
    truth = np.concatenate([np.zeros(3), k, np.full(5, np.nan)])
    truth[6:9], truth[9:] = np.deg2rad(TILT_DEG[0]), np.deg2rad(TILT_DEG[1])
    err = est - truth
    err[6:], sig[6:] = np.rad2deg(err[6:]), np.rad2deg(sig[6:])
    return err, sig


def main() -> None:
    """Print the Table 3 reproduction."""
    k, _ = _fit_axes("rigid", (1.0, -1.0), TABLE2.mean(axis=1))
    print(f"k (Table 2 fit, rigid +1°/−1°) = {np.array2string(k, precision=4)} V/(m/s²)")
    unit = 1e-3  # σ of one position mean, V: the rows' σ scale linearly with it
    _, amp = errors_and_sigmas(k, "rigid", unit)
    amp = amp / unit
    # white noise: σ_mean(T) = s / √T, s per channel (rows of one channel share its means).
    centred = TABLE3 - TABLE3.mean(axis=1, keepdims=True)
    z2 = (centred**2) * SECONDS / amp[:, None] ** 2  # = s² per entry if white noise
    s_rows = np.sqrt(z2.sum(axis=1) / (len(SECONDS) - 1))
    s_chan = np.array([np.sqrt(np.mean(s_rows[list(r)] ** 2)) for r in CHANNEL_ROWS])
    s_of = np.empty(len(ROWS))
    for c, rows in enumerate(CHANNEL_ROWS):
        s_of[list(rows)] = s_chan[c]
    print(
        f"white noise fitted to the rows' scatter over 5-60 s, s = σ(mean)·√T: per row "
        f"{np.array2string(s_rows * 1e3, precision=2)} mV·√s; per channel x, y, z "
        f"{np.array2string(s_chan * 1e3, precision=2)} mV·√s"
    )
    err_r, _ = errors_and_sigmas(k, "rigid", unit)
    err_a, _ = errors_and_sigmas(k, "additive", unit)
    print(
        f"{'row':12s} {'σ/σ_mean':>9s} {'ampl.':>6s} {'σ at 30 s':>10s} {'scatter':>8s} "
        f"{'mean meas':>10s} {'rigid':>10s} {'additive':>10s} {'at60/σ60':>9s}"
    )
    for i, name in enumerate(ROWS):
        sigma60 = amp[i] * s_of[i] / np.sqrt(60.0)
        gain = np.deg2rad(amp[i]) * abs(k[CHANNEL[i]]) * G_PAPER if i >= 6 else np.nan
        print(
            f"{name:12s} {amp[i]:9.3g} {gain:6.0f} {amp[i] * s_of[i] / np.sqrt(30.0):10.4g} "
            f"{s_rows[i] / s_of[i]:8.2f} {TABLE3[i].mean():+10.5f} {err_r[i]:+10.5f} "
            f"{err_a[i]:+10.5f} {TABLE3[i, -1] / sigma60:+9.1f}"
        )
    print("σ/σ_mean: row σ per 1 V of position-mean σ (deg/V for the tilt rows);")
    print("ampl.: tilt σ (rad) over σ_mean/(|k|·g), the angle one mean would give alone;")
    print("scatter: the row's own s over its channel's s (1 = as noisy as the channel predicts);")
    print("at60/σ60: the 60-s value in units of its predicted noise σ (systematic if ≫ 1).")


if __name__ == "__main__":
    main()
