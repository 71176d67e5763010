"""The demo's check: each value read back from the simulated device against its truth."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from canimucal.sim.truth import Truth


@dataclass(frozen=True)
class Deviation:
    """One parameter read back from the device against the simulator's truth."""

    name: str
    truth: float
    readback: float
    sigma: float

    @property
    def dev_sigma(self) -> float:
        """(readback − truth) / σ."""
        return (self.readback - self.truth) / self.sigma


def readback_deviations(record: Mapping[str, Any], truth: Truth) -> list[Deviation]:
    """Compare a calibration JSON's ``readback`` with the truth, for every estimated value.

    Accel bias and K (K = M⁻¹ of the read-back correction), gyro bias, S (S = N⁻¹) and G,
    the base tilt and the mounting trim (degrees), each with the σ of the record; values the
    record holds ``null`` (held at nominal, or a trim the plan does not determine) are
    skipped.
    """
    back = record.get("readback")
    if not back:
        return []
    accel, gyro = record["accel"], record.get("gyro") or {}
    out = []
    k_back = np.linalg.inv(np.asarray(back["accel_correction"], dtype=float))
    for i in range(3):
        out += _dev(
            f"accel.bias[{i}]",
            truth.accel.bias[i],
            back["accel_bias"][i],
            _at(accel.get("bias_sigma"), i),
        )
        out += _dev(
            f"gyro.bias[{i}]",
            truth.gyro.bias[i],
            back["gyro_bias"][i],
            _at(gyro.get("bias_sigma"), i),
        )
        for j in range(3):
            sigma = _at(_at(accel.get("K_sigma"), i), j)
            out += _dev(f"accel.K[{i}][{j}]", truth.accel.K[i, j], k_back[i, j], sigma)
    if gyro.get("S") is not None and back.get("gyro_correction") is not None:
        s_back = np.linalg.inv(np.asarray(back["gyro_correction"], dtype=float))
        for i in range(3):
            for j in range(3):
                if _at(_at(gyro["S"], i), j) is None:
                    continue  # held at nominal: not an estimate
                sigma = _at(_at(gyro.get("S_sigma"), i), j)
                out += _dev(f"gyro.S[{i}][{j}]", truth.gyro.S[i, j], s_back[i, j], sigma)
    if gyro.get("G") is not None and back.get("gyro_g") is not None:
        for i in range(3):
            for j in range(3):
                if _at(_at(gyro["G"], i), j) is None:
                    continue
                sigma = _at(_at(gyro.get("G_sigma"), i), j)
                value = back["gyro_g"][i][j]
                out += _dev(f"gyro.G[{i}][{j}]", truth.gyro.G[i, j], value, sigma)
    tilt = record.get("base_tilt_deg") or {}
    sig = tilt.get("sigma") or [None, None]
    for k, (name, true) in enumerate((("alpha0", truth.alpha0), ("beta0", truth.beta0))):
        value = float(np.rad2deg(back["base_tilt_rad"][k]))
        out += _dev(f"base_tilt.{name} (deg)", float(np.rad2deg(true)), value, sig[k])
    trim = record.get("mounting_trim_deg") or {}
    sig = trim.get("sigma") or [None, None, None]
    for k, name in enumerate(("alpha", "beta", "psi")):
        if back.get("mounting_trim_rad") is None or trim.get(name) is None:
            break  # not determined by the plan, or a node without 0x2122
        value = float(np.rad2deg(back["mounting_trim_rad"][k]))
        true = float(np.rad2deg(truth.trim[k]))
        out += _dev(f"mounting_trim.{name} (deg)", true, value, sig[k])
    return out


def _at(seq: Any, i: int) -> Any:
    return None if seq is None else seq[i]


def _dev(name: str, truth: float, readback: float, sigma: Any) -> list[Deviation]:
    if sigma is None or not sigma > 0:
        return []
    return [Deviation(name, float(truth), float(readback), float(sigma))]


def comparison_table(deviations: Sequence[Deviation]) -> str:
    """Format each read-back value beside the truth with σ and the deviation in σ."""
    lines = [f"{'parameter':<24}{'truth':>12}{'read back':>12}{'σ':>10}{'dev/σ':>8}"]
    for d in deviations:
        lines.append(
            f"{d.name:<24}{d.truth:>12.5g}{d.readback:>12.5g}{d.sigma:>10.2g}{d.dev_sigma:>8.2f}"
        )
    if deviations:
        rms = float(np.sqrt(np.mean([d.dev_sigma**2 for d in deviations])))
        lines.append(f"rms deviation {rms:.2f} σ over {len(deviations)} values (expected ≈ 1)")
    return "\n".join(lines)
