"""The accelerometer and gyro blocks of the truth JSON, with a sensor's defaults and limits.

Kept apart from :mod:`canimucal.sim.truth` (the whole document): the two sensor blocks share
their keys, defaults and noise checks; units are in :mod:`canimucal.sim.truth`'s docstring.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, AccelParams, GyroParams
from canimucal.sim.truth_fields import (
    Vector,
    fail,
    float_array,
    frozen_array,
    json_object,
    key_path,
    nonneg,
    number,
)

SAMPLE_RATES_HZ = (50, 100, 200, 250, 500, 1000)
"""Output data rates the node accepts (0x2010:03)."""
DEFAULT_ACCEL_NOISE_DENSITY = 1.5e-3
"""Default accelerometer white noise, input-referred, m/s²/√Hz (≈150 µg/√Hz)."""
DEFAULT_GYRO_NOISE_DENSITY = 1.2e-4
"""Default gyro white noise, input-referred, rad/s/√Hz (≈0.007 °/s/√Hz)."""
DEFAULT_CORRELATION_TIME_S = 100.0
NOISE_LIMIT_COUNTS = 65536.0
"""Largest noise σ a truth may ask for, in counts (per sample at the fastest output data
rate for white noise): beyond the INT16 span every sample saturates, and far beyond it the
arithmetic overflows."""
_COMMON_KEYS = tuple(
    "nominal_lsb quantization bias noise_density temp_coeff random_walk bias_instability"
    " correlation_time_s".split()
)


def _common(obj: Mapping[str, Any], path: str, lsb0: float, noise0: float) -> dict[str, Any]:
    """Read the keys accelerometer and gyro share; absent keys get their defaults."""
    out: dict[str, Any] = {}
    lsb = number(obj.get("nominal_lsb", lsb0), key_path(path, "nominal_lsb"))
    if lsb == 0.0:
        fail(key_path(path, "nominal_lsb"), "must be non-zero")
    out["nominal_lsb"] = lsb
    out["quantization"] = number(
        obj.get("quantization", 1.0), key_path(path, "quantization"), minimum=0.0
    )
    out["bias"] = float_array(obj.get("bias", [0.0] * 3), key_path(path, "bias"), (3,))
    defaults = {
        "noise_density": [noise0] * 3,
        "temp_coeff": [0.0] * 3,
        "random_walk": [0.0] * 3,
        "bias_instability": [0.0] * 3,
        "correlation_time_s": [DEFAULT_CORRELATION_TIME_S] * 3,
    }
    for key, default in defaults.items():
        arr = float_array(obj.get(key, default), key_path(path, key), (3,))
        if key != "temp_coeff":
            arr = nonneg(arr, key_path(path, key))
        out[key] = arr
    if np.any(out["correlation_time_s"] <= 0.0):
        fail(key_path(path, "correlation_time_s"), "must be positive")
    return out


def _check_noise(common: Mapping[str, Any], scale: Vector, path: str) -> None:
    """Refuse noise no INT16 sensor can report (see :data:`NOISE_LIMIT_COUNTS`)."""
    with np.errstate(over="ignore"):  # an absurd density may overflow to inf: refused below
        white = common["noise_density"] * np.abs(np.diag(scale)) * np.sqrt(max(SAMPLE_RATES_HZ))
    if np.any(white > NOISE_LIMIT_COUNTS):
        fail(
            key_path(path, "noise_density"),
            f"gives a white-noise σ above {NOISE_LIMIT_COUNTS:g} counts per sample at "
            f"{max(SAMPLE_RATES_HZ)} Hz",
        )
    for key in ("random_walk", "bias_instability"):
        if np.any(common[key] > NOISE_LIMIT_COUNTS):
            fail(key_path(path, key), f"must be at most {NOISE_LIMIT_COUNTS:g} counts")


@dataclass(frozen=True, eq=False)
class _SensorTruth:
    """Fields the accelerometer and the gyro share (units in :mod:`canimucal.sim.truth`)."""

    nominal_lsb: float
    quantization: float
    bias: Vector
    noise_density: Vector
    temp_coeff: Vector
    random_walk: Vector
    bias_instability: Vector
    correlation_time_s: Vector

    def _common_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "nominal_lsb": self.nominal_lsb,
            "quantization": self.quantization,
        }
        for key in _COMMON_KEYS[2:]:
            out[key] = np.asarray(getattr(self, key)).tolist()
        return out


@dataclass(frozen=True, eq=False)
class AccelTruth(_SensorTruth):
    """Accelerometer truth: ``U = b + K f + quadratic ⊙ f² + drifts + noise`` (counts)."""

    K: Vector = field(default_factory=lambda: frozen_array(np.eye(3) / DEFAULT_ACCEL_LSB))
    quadratic: Vector = field(default_factory=lambda: frozen_array(np.zeros(3)))

    @classmethod
    def from_dict(cls, obj: Any, path: str = "accel") -> AccelTruth:
        """Validate and read the ``accel`` object of the truth JSON."""
        obj = json_object(obj, path, (*_COMMON_KEYS, "K", "quadratic"))
        common = _common(obj, path, DEFAULT_ACCEL_LSB, DEFAULT_ACCEL_NOISE_DENSITY)
        k_default = np.eye(3) / common["nominal_lsb"]
        K = float_array(obj.get("K", k_default), key_path(path, "K"), (3, 3))
        _check_noise(common, K, path)
        return cls(
            **common,
            K=K,
            quadratic=float_array(
                obj.get("quadratic", [0.0] * 3), key_path(path, "quadratic"), (3,)
            ),
        )

    def to_dict(self) -> dict[str, Any]:
        """Return the ``accel`` object of the truth JSON."""
        out = self._common_dict()
        out["K"] = self.K.tolist()
        out["quadratic"] = self.quadratic.tolist()
        return out

    def params(self) -> AccelParams:
        """Return the model's bias and K (no drifts, no noise)."""
        return AccelParams(np.array(self.bias), np.array(self.K))


@dataclass(frozen=True, eq=False)
class GyroTruth(_SensorTruth):
    """Gyro truth: ``V = B + S w + G f + drifts + noise`` (counts)."""

    S: Vector = field(default_factory=lambda: frozen_array(np.eye(3) / DEFAULT_GYRO_LSB))
    G: Vector = field(default_factory=lambda: frozen_array(np.zeros((3, 3))))

    @classmethod
    def from_dict(cls, obj: Any, path: str = "gyro") -> GyroTruth:
        """Validate and read the ``gyro`` object of the truth JSON."""
        obj = json_object(obj, path, (*_COMMON_KEYS, "S", "G"))
        common = _common(obj, path, DEFAULT_GYRO_LSB, DEFAULT_GYRO_NOISE_DENSITY)
        s_default = np.eye(3) / common["nominal_lsb"]
        S = float_array(obj.get("S", s_default), key_path(path, "S"), (3, 3))
        _check_noise(common, S, path)
        return cls(
            **common,
            S=S,
            G=float_array(obj.get("G", np.zeros((3, 3))), key_path(path, "G"), (3, 3)),
        )

    def to_dict(self) -> dict[str, Any]:
        """Return the ``gyro`` object of the truth JSON."""
        out = self._common_dict()
        out["S"] = self.S.tolist()
        out["G"] = self.G.tolist()
        return out

    def params(self) -> GyroParams:
        """Return the model's bias, S and G (no drifts, no noise)."""
        return GyroParams(np.array(self.bias), np.array(self.S), np.array(self.G))
