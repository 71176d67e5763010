"""The simulator's truth: every parameter of the simulated unit (docs/design.md §5, truth JSON).

Angles are radians inside (``alpha0``, ``beta0``, ``trim``, ``latitude``, ``heading``) and
degrees in the JSON dict; every other value keeps the JSON's units: biases, quantization,
random walk and bias instability in counts (output-referred), K counts per m/s², S counts
per rad/s, G counts per m/s², quadratic counts per (m/s²)², temp_coeff counts/°C, noise
densities input-referred (m/s²/√Hz and rad/s/√Hz).

Defaults when a key is absent: ``nominal_lsb`` ±16 g (9.80665/2048 m/s² per count) and
±2000 °/s (π/(180·16.4) rad/s per count), K and S their inverses on the diagonal, G zero,
zero biases and drifts, noise densities of a consumer MEMS unit (accel 1.5e-3 m/s²/√Hz,
gyro 1.2e-4 rad/s/√Hz), correlation time 100 s, quantization 1 count, 200 Hz, rigid tilt,
latitude 50.45°, height 0 m, heading 0, and g from WGS-84 normal gravity at that latitude and
height when ``g`` is absent.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import SchemaError
from canimucal.model.frames import TiltModel
from canimucal.model.gravity import normal_gravity
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, AccelParams, GyroParams
from canimucal.model.vocabulary.constants import INT16_SPAN, OUTPUT_DATA_RATES_HZ
from canimucal.model.vocabulary.effects import EFFECTS
from canimucal.schema import (
    fail,
    frozen_array,
    is_numeric_tree,
    key_path,
    read_array,
    read_integer,
    read_list,
    read_number,
    read_object,
)

log = logging.getLogger(__name__)

Vector = NDArray[np.float64]

SCHEMA = "canimucal.truth/1"
DEFAULT_LATITUDE_DEG = 50.45
_TILT_MODELS = ("rigid", "additive")
DEFAULT_DEVICE_NAME = "canimucal IMU"
DEFAULT_HARDWARE_VERSION = "sim 1"
DEFAULT_SOFTWARE_VERSION = "sim 1"
_TOP_KEYS = tuple(
    "schema sample_rate_hz g latitude_deg height_m heading_deg serial tilt_model base_tilt_deg"
    " floor_slope_deg mounting_trim_deg accel gyro temperature faults nmt_start heartbeat_ms"
    " store_delay_s"
    " store_pdo_mode"
    " storage_subs sync_pdos timer_skew_ppm calibration_store_sub documented_store_sub"
    " second_send_ms refuses_start trim_object"
    " device_name hardware_version software_version effects trials".split()
)
NMT_STARTS = ("pre-operational", "operational")
DEFAULT_STORAGE_SUBS = (1, 2, 3, 4)
STORE_PDO_MODES = ("drop", "queue", "continue")
MAX_TIMER_SKEW_PPM = 100_000.0
"""±10 %: beyond that the event timer is not the sample clock's, it is a different rate."""


@dataclass(frozen=True)
class TemperatureProfile:
    """Temperature of the unit against simulated time.

    ``start_c + rate_c_per_s·t``, or, when ``profile`` is given, linear interpolation between
    its ``(seconds, °C)`` pairs (the end values hold outside them); the profile overrides
    both ``start_c`` and ``rate_c_per_s``.
    """

    start_c: float = 25.0
    rate_c_per_s: float = 0.0
    profile: tuple[tuple[float, float], ...] | None = None

    @classmethod
    def from_dict(cls, obj: Any, path: str = "temperature") -> TemperatureProfile:
        """Validate and read the ``temperature`` object of the truth JSON."""
        obj = read_object(obj, path, ("start_c", "rate_c_per_s", "profile"))
        start = read_number(obj.get("start_c", 25.0), key_path(path, "start_c"))
        rate = read_number(obj.get("rate_c_per_s", 0.0), key_path(path, "rate_c_per_s"))
        profile = None
        if "profile" in obj:
            p_path = key_path(path, "profile")
            raw = obj["profile"]
            ok = isinstance(raw, list | tuple) and len(raw) > 0 and is_numeric_tree(raw)
            arr = np.array(raw, dtype=float) if ok else np.empty((0, 0))
            if arr.ndim != 2 or arr.shape[1] != 2 or not np.all(np.isfinite(arr)):
                fail(p_path, "must be a non-empty list of [seconds, °C] pairs of finite numbers")
            if np.any(np.diff(arr[:, 0]) <= 0.0):
                fail(p_path, "times must be strictly increasing")
            profile = tuple((float(t), float(c)) for t, c in arr)
        return cls(start, rate, profile)

    def to_dict(self) -> dict[str, Any]:
        """Return the ``temperature`` object of the truth JSON."""
        out: dict[str, Any] = {"start_c": self.start_c, "rate_c_per_s": self.rate_c_per_s}
        if self.profile is not None:
            out["profile"] = [list(p) for p in self.profile]
        return out

    def at(self, t_s: ArrayLike) -> Vector:
        """Temperature (°C) at simulated times ``t_s`` (seconds)."""
        t = np.asarray(t_s, dtype=float)
        if self.profile is None:
            return self.start_c + self.rate_c_per_s * t
        times, temps = np.array(self.profile).T
        return np.interp(t, times, temps)


@dataclass(frozen=True, eq=False)
class Truth:
    """Every parameter of the simulated unit; see the module docstring for units."""

    sample_rate_hz: float = 200.0
    g: float = field(default_factory=lambda: normal_gravity(np.deg2rad(DEFAULT_LATITUDE_DEG)))
    latitude: float = float(np.deg2rad(DEFAULT_LATITUDE_DEG))
    height_m: float = 0.0
    heading: float = 0.0
    serial: int = 0
    tilt_model: TiltModel = "rigid"
    alpha0: float = 0.0
    beta0: float = 0.0
    trim: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """The unit's mounting trim in the vehicle ``(alpha_m, beta_m, psi_m)``, radians:
    ``R_m = Ay(psi_m) A2(beta_m) A1(alpha_m)`` applied after the pose (docs/design.md §2)."""
    trim_object: bool = True
    """The node has the mounting-trim object 0x2122 (False: a firmware before it, whose
    calibration CRC covers the 39 objects of 0x2100–0x2121:04 alone; docs/design.md §4)."""
    accel: AccelTruth = field(default_factory=lambda: AccelTruth.from_dict({}))
    gyro: GyroTruth = field(default_factory=lambda: GyroTruth.from_dict({}))
    temperature: TemperatureProfile = field(default_factory=TemperatureProfile)
    faults: Mapping[str, Any] = field(default_factory=dict)
    nmt_start: str = "pre-operational"
    """NMT state after boot-up (CANopenNode devices often start OPERATIONAL)."""
    heartbeat_ms: int | None = None
    """Producer heartbeat 0x1017 after boot (0: off); None keeps the EDS default."""
    store_delay_s: float = 0.0
    """A 0x1010 store blocks the SDO answer this long (flash erased in the SDO handler)."""
    store_pdo_mode: str = "drop"
    """TPDO frames while the store blocks: ``drop``ped, ``queue``d (a burst after it) or
    ``continue`` (sent on time)."""
    storage_subs: tuple[int, ...] = DEFAULT_STORAGE_SUBS
    """0x1010/0x1011 sub-indices the node has (stock CANopenNode: no 4)."""
    sync_pdos: bool = False
    """TPDO1–3 on every SYNC (transmission type 1) instead of their event timers (254)."""
    timer_skew_ppm: float = 0.0
    """TPDO event timers run this far off the sample clock (+: slow, counters skipped;
    −: fast, counters sent twice), as on an MCU whose timer and sensor have two clocks."""
    calibration_store_sub: int = 4
    """The 0x1010/0x1011 sub-index whose 'save'/'load' covers the calibration group."""
    documented_store_sub: int | None = 4
    """What 0x2011 says stores the calibration (None: no 0x2011, as firmware before issue
    24); a firmware may be wrong. Without the key: ``calibration_store_sub`` when the node
    has that sub-index, else 1."""
    second_send_ms: float = 0.0
    """TPDO1/2 go out a second time this long after each sample: a second send trigger (an
    event timer beside data-ready sending). 0: off."""
    refuses_start: bool = False
    """Boot with EMCY 0x5000 and error register 0x01, and stay PRE-OPERATIONAL after an NMT
    start (CANopenNode's stock error-register rule on a blank storage)."""
    device_name: str = DEFAULT_DEVICE_NAME
    """0x1008, any text (tests present hostile names); 0x1009/0x100A likewise."""
    hardware_version: str = DEFAULT_HARDWARE_VERSION
    software_version: str = DEFAULT_SOFTWARE_VERSION
    effects: Mapping[str, Vector] = field(default_factory=dict)
    """Coefficients of effects the simulator applies through their columns, by
    ``sensor.effect`` (:mod:`canimucal.model.vocabulary.effects`; its unit, in counts)."""
    trials: tuple[TrialBiases, ...] = ()
    """Each trial's biases (the unit re-mounted between trials of one recording: ``analyze
    --truth-out`` of such a file, docs/design.md §6 *Trials*); the simulator runs
    ``accel.bias``/``gyro.bias``, their mean, and :meth:`trial_units` each trial's unit."""

    @classmethod
    def from_dict(cls, d: Any) -> Truth:
        """Validate a truth JSON document; :class:`SchemaError` names the bad key.

        Messages read ``truth: key.path: problem``.
        """
        try:
            return cls._parse(d)
        except SchemaError as exc:
            raise SchemaError(f"truth: {exc}") from None

    @classmethod
    def _parse(cls, d: Any) -> Truth:
        if isinstance(d, Mapping) and "floor_tilt_deg" in d:  # the contract's name for it
            if "floor_slope_deg" in d:
                fail("floor_tilt_deg", "give floor_tilt_deg or floor_slope_deg, not both")
            d = {("floor_slope_deg" if k == "floor_tilt_deg" else k): v for k, v in d.items()}
        d = read_object(d, "", _TOP_KEYS)
        if d.get("schema", SCHEMA) != SCHEMA:
            fail("schema", f"must be {SCHEMA!r}")
        rate = read_number(d.get("sample_rate_hz", 200), "sample_rate_hz")
        if rate not in OUTPUT_DATA_RATES_HZ:
            fail("sample_rate_hz", f"must be one of {', '.join(map(str, OUTPUT_DATA_RATES_HZ))}")
        lat_deg = read_number(d.get("latitude_deg", DEFAULT_LATITUDE_DEG), "latitude_deg")
        if abs(lat_deg) > 90.0:
            fail("latitude_deg", "must be within [-90, 90]")
        height = read_number(d.get("height_m", 0.0), "height_m")
        if "g" in d:
            g = read_number(d["g"], "g")
            if g <= 0.0:
                fail("g", "must be positive")
        else:
            g = normal_gravity(np.deg2rad(lat_deg), height)
            log.info(
                "truth: g = %.6f m/s² from latitude %.4f° and height %.1f m", g, lat_deg, height
            )
        tilt_model = _tilt_model(d.get("tilt_model", "rigid"))
        slope_key = "floor_slope_deg" if "floor_slope_deg" in d else "base_tilt_deg"
        tilt = read_object(d.get("base_tilt_deg", {}), "base_tilt_deg", ("alpha0", "beta0"))
        if "floor_slope_deg" in d:
            tilt = _floor_slope(d, tilt_model)
        faults = d.get("faults", {})
        if not isinstance(faults, Mapping) or not all(isinstance(k, str) for k in faults):
            fail("faults", "must be a JSON object")
        return cls(
            sample_rate_hz=rate,
            g=g,
            latitude=float(np.deg2rad(lat_deg)),
            height_m=height,
            heading=float(np.deg2rad(read_number(d.get("heading_deg", 0.0), "heading_deg"))),
            serial=_serial(d.get("serial", 0)),
            tilt_model=tilt_model,
            alpha0=float(np.deg2rad(_tilt_angle(tilt, "alpha0", slope_key))),
            beta0=float(np.deg2rad(_tilt_angle(tilt, "beta0", slope_key))),
            trim=_mounting_trim(d.get("mounting_trim_deg", [0.0, 0.0, 0.0])),
            trim_object=_flag(d.get("trim_object", True), "trim_object"),
            accel=AccelTruth.from_dict(d.get("accel", {})),
            gyro=GyroTruth.from_dict(d.get("gyro", {})),
            temperature=TemperatureProfile.from_dict(d.get("temperature", {})),
            faults=copy.deepcopy(dict(faults)),
            **_device_behaviour(d),
            device_name=_text(d.get("device_name", DEFAULT_DEVICE_NAME), "device_name"),
            hardware_version=_text(
                d.get("hardware_version", DEFAULT_HARDWARE_VERSION), "hardware_version"
            ),
            software_version=_text(
                d.get("software_version", DEFAULT_SOFTWARE_VERSION), "software_version"
            ),
            effects=_effects(d.get("effects", {})),
            trials=_trials(d.get("trials", [])),
        )

    def to_dict(self) -> dict[str, Any]:
        """Return the truth JSON document (degrees; ``g`` always recorded).

        The identity strings appear only when they differ from the defaults.
        """
        rate = self.sample_rate_hz
        identity = {
            key: value
            for key, value, default in (
                ("device_name", self.device_name, DEFAULT_DEVICE_NAME),
                ("hardware_version", self.hardware_version, DEFAULT_HARDWARE_VERSION),
                ("software_version", self.software_version, DEFAULT_SOFTWARE_VERSION),
            )
            if value != default
        }
        return {
            "schema": SCHEMA,
            "sample_rate_hz": int(rate) if float(rate).is_integer() else rate,
            "g": self.g,
            "latitude_deg": float(np.rad2deg(self.latitude)),
            "height_m": self.height_m,
            "heading_deg": float(np.rad2deg(self.heading)),
            "serial": self.serial,
            "tilt_model": self.tilt_model,
            "base_tilt_deg": {
                "alpha0": float(np.rad2deg(self.alpha0)),
                "beta0": float(np.rad2deg(self.beta0)),
            },
            **self._trim_dict(),
            "accel": self.accel.to_dict(),
            "gyro": self.gyro.to_dict(),
            "temperature": self.temperature.to_dict(),
            "faults": copy.deepcopy(dict(self.faults)),
            **self._behaviour_dict(),
            **identity,
            **({"effects": effects_document(self.effects)} if self.effects else {}),
            **({"trials": [t.to_dict() for t in self.trials]} if self.trials else {}),
        }

    def trial_units(self) -> tuple[Truth, ...]:
        """Each trial's unit: this one with that trial's biases (none: empty)."""
        out = []
        for t in self.trials:
            accel = dataclasses.replace(self.accel, bias=t.accel_bias)
            gyro = self.gyro
            if t.gyro_bias is not None:
                gyro = dataclasses.replace(self.gyro, bias=t.gyro_bias)
            out.append(dataclasses.replace(self, accel=accel, gyro=gyro, trials=()))
        return tuple(out)

    def _trim_dict(self) -> dict[str, Any]:
        """``mounting_trim_deg`` and ``trim_object`` when they differ from their defaults."""
        out: dict[str, Any] = {}
        if any(self.trim):
            out["mounting_trim_deg"] = [float(np.rad2deg(t)) for t in self.trim]
        if not self.trim_object:
            out["trim_object"] = False
        return out

    def _behaviour_dict(self) -> dict[str, Any]:
        """Return the device-behaviour keys that differ from their defaults."""
        out: dict[str, Any] = {}
        if self.nmt_start != "pre-operational":
            out["nmt_start"] = self.nmt_start
        if self.heartbeat_ms is not None:
            out["heartbeat_ms"] = self.heartbeat_ms
        if self.store_delay_s:
            out["store_delay_s"] = self.store_delay_s
        if self.store_pdo_mode != "drop":
            out["store_pdo_mode"] = self.store_pdo_mode
        if self.storage_subs != DEFAULT_STORAGE_SUBS:
            out["storage_subs"] = list(self.storage_subs)
        if self.sync_pdos:
            out["sync_pdos"] = True
        if self.timer_skew_ppm:
            out["timer_skew_ppm"] = self.timer_skew_ppm
        if self.calibration_store_sub != 4:
            out["calibration_store_sub"] = self.calibration_store_sub
        if self.documented_store_sub != _documented_default(
            self.calibration_store_sub, self.storage_subs
        ):
            out["documented_store_sub"] = self.documented_store_sub
        if self.second_send_ms:
            out["second_send_ms"] = self.second_send_ms
        if self.refuses_start:
            out["refuses_start"] = True
        return out

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        *,
        bias_max_counts: float = 50.0,
        scale_error_max: float = 0.03,
        cross_axis_max: float = 0.01,
        tilt_max_deg: float = 1.0,
        gyro_g_max: float = 0.0,
        trim_max_deg: float = 0.0,
        **overrides: Any,
    ) -> Truth:
        """Draw a plausible random unit for demos and end-to-end tests.

        Biases uniform in ±``bias_max_counts``; ``K = (I + E)/lsb`` with diagonal of E in
        ±``scale_error_max`` and off-diagonal in ±``cross_axis_max`` (same for S); base tilt
        in ±``tilt_max_deg``; G entries in ±``gyro_g_max`` counts per m/s²; a random serial;
        with ``trim_max_deg`` > 0 a mounting trim in ±``trim_max_deg`` about each axis (drawn
        last, so the other draws of a seed do not change).
        ``overrides`` are top-level truth JSON keys applied on top (e.g. ``sample_rate_hz``).
        """

        def matrix(lsb: float) -> list[list[float]]:
            e = rng.uniform(-cross_axis_max, cross_axis_max, (3, 3))
            e[np.diag_indices(3)] = rng.uniform(-scale_error_max, scale_error_max, 3)
            return ((np.eye(3) + e) / lsb).tolist()

        alpha0, beta0 = rng.uniform(-tilt_max_deg, tilt_max_deg, 2)
        d: dict[str, Any] = {
            "serial": int(rng.integers(1, 2**32)),
            "base_tilt_deg": {"alpha0": float(alpha0), "beta0": float(beta0)},
            "accel": {
                "bias": rng.uniform(-bias_max_counts, bias_max_counts, 3).tolist(),
                "K": matrix(DEFAULT_ACCEL_LSB),
            },
            "gyro": {
                "bias": rng.uniform(-bias_max_counts, bias_max_counts, 3).tolist(),
                "S": matrix(DEFAULT_GYRO_LSB),
                "G": rng.uniform(-gyro_g_max, gyro_g_max, (3, 3)).tolist(),
            },
        }
        if trim_max_deg > 0.0:
            d["mounting_trim_deg"] = rng.uniform(-trim_max_deg, trim_max_deg, 3).tolist()
        d.update(overrides)
        return cls.from_dict(d)


def _device_behaviour(d: Mapping[str, Any]) -> dict[str, Any]:
    """Read the node-behaviour keys (docs/design.md §5): NMT start, heartbeat, store, timers."""
    nmt_start = d.get("nmt_start", "pre-operational")
    if nmt_start not in NMT_STARTS:
        fail("nmt_start", f"must be one of {', '.join(NMT_STARTS)}")
    out: dict[str, Any] = {"nmt_start": nmt_start}
    if "heartbeat_ms" in d:
        hb = d["heartbeat_ms"]
        if isinstance(hb, bool) or not isinstance(hb, int) or not 0 <= hb <= 0xFFFF:
            fail("heartbeat_ms", "must be an integer within [0, 65535] (0: off)")
        out["heartbeat_ms"] = hb
    delay = read_number(d.get("store_delay_s", 0.0), "store_delay_s")
    if not 0.0 <= delay <= 60.0:
        fail("store_delay_s", "must be within [0, 60] s")
    out["store_delay_s"] = delay
    mode = d.get("store_pdo_mode", "drop")
    if not isinstance(mode, str) or mode not in STORE_PDO_MODES:
        fail("store_pdo_mode", f"must be one of {', '.join(STORE_PDO_MODES)}")
    out["store_pdo_mode"] = mode
    sync_pdos = d.get("sync_pdos", False)
    if not isinstance(sync_pdos, bool):
        fail("sync_pdos", "must be true or false")
    out["sync_pdos"] = sync_pdos
    skew = read_number(d.get("timer_skew_ppm", 0.0), "timer_skew_ppm")
    if abs(skew) > MAX_TIMER_SKEW_PPM:
        fail("timer_skew_ppm", f"must be within ±{MAX_TIMER_SKEW_PPM:.0f} ppm")
    out["timer_skew_ppm"] = skew
    subs = d.get("storage_subs", list(DEFAULT_STORAGE_SUBS))
    ok = isinstance(subs, list | tuple) and all(
        isinstance(x, int) and not isinstance(x, bool) and 1 <= x <= 127 for x in subs
    )
    if not ok or len(set(subs)) != len(subs):
        fail("storage_subs", "must be a list of distinct sub-indices 1..127 (e.g. [1, 2, 3])")
    out["storage_subs"] = tuple(sorted(subs))
    out.update(_firmware_behaviour(d, out["storage_subs"]))
    return out


def _sub_index(value: Any, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 127:
        fail(key, "must be a sub-index 1..127")
    return int(value)


def _documented_default(store_sub: int, storage_subs: tuple[int, ...]) -> int:
    """Return 0x2011's default: the calibration's sub-index, or 1 when the node lacks it."""
    return store_sub if store_sub in storage_subs else 1


def _firmware_behaviour(d: Mapping[str, Any], storage_subs: tuple[int, ...]) -> dict[str, Any]:
    """Read the keys of issue 24's firmware habits: store sub-index, second send, start refusal."""
    store_sub = _sub_index(d.get("calibration_store_sub", 4), "calibration_store_sub")
    documented = d.get("documented_store_sub", _documented_default(store_sub, storage_subs))
    if documented is not None:
        documented = _sub_index(documented, "documented_store_sub")
    second = read_number(d.get("second_send_ms", 0.0), "second_send_ms")
    if not 0.0 <= second < 1000.0:
        fail("second_send_ms", "must be within [0, 1000) ms (0: off)")
    refuses = d.get("refuses_start", False)
    if not isinstance(refuses, bool):
        fail("refuses_start", "must be true or false")
    return {
        "calibration_store_sub": store_sub,
        "documented_store_sub": documented,
        "second_send_ms": second,
        "refuses_start": refuses,
    }


def _text(value: Any, key: str) -> str:
    if not isinstance(value, str):
        fail(key, "must be a string")
    return value


def _serial(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        fail("serial", "must be an integer")
    if not 0 <= int(value) < 2**32:
        fail("serial", "must be within [0, 2**32)")
    return int(value)


def _tilt_model(value: Any) -> TiltModel:
    if value == "rigid":
        return "rigid"
    if value == "additive":
        return "additive"
    fail("tilt_model", f"must be one of {', '.join(map(repr, _TILT_MODELS))}")


def _floor_slope(d: Mapping[str, Any], tilt_model: TiltModel) -> dict[str, Any]:
    """``floor_slope_deg: [about z, about x]``: the floor's slope, fixed in the level frame.

    The same rotation as the rigid ``base_tilt_deg`` (docs/design.md §2: applied to ``f_L``
    before the pose), under the name a vehicle day uses; one of the two keys.
    """
    if "base_tilt_deg" in d:
        fail("floor_slope_deg", "give floor_slope_deg or base_tilt_deg, not both")
    if tilt_model != "rigid":
        fail("floor_slope_deg", "a floor slope is a rigid tilt (tilt_model 'rigid')")
    value = d["floor_slope_deg"]
    if not isinstance(value, list) or len(value) != 2:
        fail("floor_slope_deg", "must be [about z, about x] in degrees")
    return {"alpha0": value[0], "beta0": value[1]}


def _mounting_trim(value: Any) -> tuple[float, float, float]:
    """``mounting_trim_deg: [alpha, beta, psi]``: about the unit's z, the new x, then y.

    The unit's small rotation in the vehicle, in the angle convention of a position
    (docs/design.md §2), applied after the pose: ``C = R_m · C_pose · T0``.
    """
    if not isinstance(value, list) or len(value) != 3:
        fail("mounting_trim_deg", "must be [alpha, beta, psi] in degrees")
    out = []
    for k, item in enumerate(value):
        angle = read_number(item, f"mounting_trim_deg[{k}]")
        if abs(angle) >= 90.0:
            fail(f"mounting_trim_deg[{k}]", "must be within (-90, 90) degrees")
        out.append(float(np.deg2rad(angle)))
    return out[0], out[1], out[2]


def _flag(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        fail(key, "must be true or false")
    return value


def _tilt_angle(tilt: Mapping[str, Any], key: str, where: str = "base_tilt_deg") -> float:
    path = f"{where}.{key}"
    angle = read_number(tilt.get(key, 0.0), path)
    if abs(angle) >= 90.0:
        fail(path, "must be within (-90, 90) degrees")
    return angle


DEFAULT_ACCEL_NOISE_DENSITY = 1.5e-3
"""Default accelerometer white noise, input-referred, m/s²/√Hz (≈150 µg/√Hz)."""
DEFAULT_GYRO_NOISE_DENSITY = 1.2e-4
"""Default gyro white noise, input-referred, rad/s/√Hz (≈0.007 °/s/√Hz)."""
DEFAULT_CORRELATION_TIME_S = 100.0
NOISE_LIMIT_COUNTS = float(INT16_SPAN)
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
    lsb = read_number(obj.get("nominal_lsb", lsb0), key_path(path, "nominal_lsb"))
    if lsb == 0.0:
        fail(key_path(path, "nominal_lsb"), "must be non-zero")
    out["nominal_lsb"] = lsb
    out["quantization"] = read_number(
        obj.get("quantization", 1.0), key_path(path, "quantization"), 0.0
    )
    out["bias"] = read_array(obj.get("bias", [0.0] * 3), key_path(path, "bias"), (3,))
    defaults = {
        "noise_density": [noise0] * 3,
        "temp_coeff": [0.0] * 3,
        "random_walk": [0.0] * 3,
        "bias_instability": [0.0] * 3,
        "correlation_time_s": [DEFAULT_CORRELATION_TIME_S] * 3,
    }
    for key, default in defaults.items():
        arr = read_array(obj.get(key, default), key_path(path, key), (3,))
        if key != "temp_coeff":
            arr = _nonneg(arr, key_path(path, key))
        out[key] = arr
    if np.any(out["correlation_time_s"] <= 0.0):
        fail(key_path(path, "correlation_time_s"), "must be positive")
    return out


def _check_noise(common: Mapping[str, Any], scale: Vector, path: str) -> None:
    """Refuse noise no INT16 sensor can report (see :data:`NOISE_LIMIT_COUNTS`)."""
    with np.errstate(over="ignore"):  # an absurd density may overflow to inf: refused below
        white = (
            common["noise_density"] * np.abs(np.diag(scale)) * np.sqrt(max(OUTPUT_DATA_RATES_HZ))
        )
    if np.any(white > NOISE_LIMIT_COUNTS):
        fail(
            key_path(path, "noise_density"),
            f"gives a white-noise σ above {NOISE_LIMIT_COUNTS:g} counts per sample at "
            f"{max(OUTPUT_DATA_RATES_HZ)} Hz",
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
        obj = read_object(obj, path, (*_COMMON_KEYS, "K", "quadratic"))
        common = _common(obj, path, DEFAULT_ACCEL_LSB, DEFAULT_ACCEL_NOISE_DENSITY)
        k_default = np.eye(3) / common["nominal_lsb"]
        K = read_array(obj.get("K", k_default), key_path(path, "K"), (3, 3))
        _check_noise(common, K, path)
        return cls(
            **common,
            K=K,
            quadratic=read_array(
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
        obj = read_object(obj, path, (*_COMMON_KEYS, "S", "G"))
        common = _common(obj, path, DEFAULT_GYRO_LSB, DEFAULT_GYRO_NOISE_DENSITY)
        s_default = np.eye(3) / common["nominal_lsb"]
        S = read_array(obj.get("S", s_default), key_path(path, "S"), (3, 3))
        _check_noise(common, S, path)
        return cls(
            **common,
            S=S,
            G=read_array(obj.get("G", np.zeros((3, 3))), key_path(path, "G"), (3, 3)),
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


def _effects(obj: Any) -> dict[str, Vector]:
    """Read ``effects``: ``{sensor: {effect: [a coefficient per entry]}}`` (the registry's)."""
    known = [f"{s}.{e.name}" for e in EFFECTS.values() if e.generic_truth for s in e.sensors]
    out = {}
    for sensor, block in read_object(obj, "effects", ("accel", "gyro")).items():
        if not isinstance(block, Mapping):
            fail(f"effects.{sensor}", "must be a JSON object")
        for name, values in block.items():
            key, path = f"{sensor}.{name}", f"effects.{sensor}.{name}"
            effect = EFFECTS.get(name)
            if effect is None or key not in known:
                fail(path, f"not an effect the simulator applies ({', '.join(known) or 'none'})")
            out[key] = read_array(values, path, (len(effect.labels),))
    return out


def effects_document(effects: Mapping[str, ArrayLike]) -> dict[str, dict[str, list[float]]]:
    """Return the truth JSON's ``effects`` object of coefficients by ``sensor.effect``."""
    out: dict[str, dict[str, list[float]]] = {}
    for key, values in effects.items():
        sensor, name = key.split(".", 1)
        out.setdefault(sensor, {})[name] = np.asarray(values, dtype=float).tolist()
    return out


def _nonneg(arr: Vector, path: str) -> Vector:
    """Return ``arr`` after checking that no entry is negative."""
    if np.any(arr < 0):
        fail(path, "must be non-negative")
    return arr


@dataclass(frozen=True, eq=False)
class TrialBiases:
    """One trial's biases (counts): ``trials[]`` of the truth JSON (docs/design.md §5)."""

    trial: int
    accel_bias: Vector
    gyro_bias: Vector | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the entry of the truth JSON's ``trials``."""
        out: dict[str, Any] = {"trial": self.trial, "accel_bias": self.accel_bias.tolist()}
        if self.gyro_bias is not None:
            out["gyro_bias"] = self.gyro_bias.tolist()
        return out


def _trials(obj: Any) -> tuple[TrialBiases, ...]:
    """Read ``trials``: ``[{trial, accel_bias, gyro_bias?}, …]``, distinct trials (-1: none)."""
    out = []
    for k, entry in enumerate(read_list(obj, "trials")):
        path = f"trials[{k}]"
        entry = read_object(entry, path, ("trial", "accel_bias", "gyro_bias"))
        if "trial" not in entry or "accel_bias" not in entry:
            fail(path, "needs trial and accel_bias")
        gyro = entry.get("gyro_bias")
        out.append(
            TrialBiases(
                read_integer(entry["trial"], key_path(path, "trial"), low=-1),
                read_array(entry["accel_bias"], key_path(path, "accel_bias"), (3,)),
                None if gyro is None else read_array(gyro, key_path(path, "gyro_bias"), (3,)),
            )
        )
    if len({t.trial for t in out}) != len(out):
        fail("trials", "each trial once")
    return tuple(out)
