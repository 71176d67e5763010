"""The simulated IMU: truth parameters + effects + pose schedule -> raw count samples.

Per sample (docs/design.md §2): ``C`` body <- L from the pose, the base tilt and the mounting
trim (``position_dcm``; ``C = R_m C_pose T0``, docs/method.md §3), ``f = C f_L`` and
``w = C w_L + R_m w_motion`` (the body rate of a move, exact from the angle rates). Specific
force from the motion itself (lever arms) is not modelled: a tilt on a step ladder is slow.
Outputs in counts:

- accelerometer ``U = b + K f + quadratic ⊙ f² + temp_coeff (T − T0) + r + m + n``
- gyro ``V = B + S w + G f + temp_coeff (T − T0) + r + m + n``

plus, for each effect of the truth's ``effects``, its model columns (the effect registry's
``known``, :mod:`canimucal.model.vocabulary.effects`) at the sample's pose, specific force
and ``T − T0``, times its coefficients.

``T0`` is the temperature at t = 0; ``r`` a Wiener bias (increment σ = q/√f_s per sample,
so Var r(t) = q² t); ``m`` a first-order Gauss–Markov bias with stationary σ = B and
correlation time T (stationary from the start); ``n`` white noise, input-referred density N
scaled by the axis's own scale factor: per-sample σ = N √f_s |K_ii| (|S_ii| for the gyro),
independent between axes. Then quantization (round to the ``quantization`` step when > 0) and
INT16 saturation, flagged per sample when any of the six channels was clipped.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError
from canimucal.model.frames import (
    earth_rate_level,
    position_dcm,
    specific_force_level,
    trim_dcm,
)
from canimucal.model.positions import Plan, Pose
from canimucal.model.vocabulary.constants import INT16_MAX, INT16_MIN, OUTPUT_DATA_RATES_HZ
from canimucal.model.vocabulary.effects import EFFECTS, PoseInputs
from canimucal.sim.schedule import PoseTrajectory
from canimucal.sim.truth import Truth

log = logging.getLogger(__name__)


Array = NDArray[np.float64]


@dataclass(frozen=True)
class SimBlock:
    """``n`` consecutive samples of the simulated unit.

    ``t_s`` simulated seconds; ``accel``/``gyro`` (n, 3) counts (floats, already quantized
    and saturated); ``temp_c`` °C; ``saturated`` any channel clipped at INT16; ``moving``
    during a pose transient; ``position_index`` the plan index, -1 while moving or unscheduled.
    """

    t_s: Array
    accel: Array
    gyro: Array
    temp_c: Array
    saturated: NDArray[np.bool_]
    moving: NDArray[np.bool_]
    position_index: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def _dcm_batch(angles: Array, alpha0: float, beta0: float, additive: bool) -> Array:
    """``position_dcm`` for each row ``(alpha, beta, psi)``: an (n, 3, 3) array."""
    a, b, p = angles[:, 0], angles[:, 1], angles[:, 2]
    if additive:
        a, b = a + alpha0, b + beta0
    n = angles.shape[0]
    one, zero = np.ones(n), np.zeros(n)
    ca, sa, cb, sb, cp, sp = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(p), np.sin(p)
    a1 = np.stack([ca, sa, zero, -sa, ca, zero, zero, zero, one], axis=1).reshape(n, 3, 3)
    a2 = np.stack([one, zero, zero, zero, cb, sb, zero, -sb, cb], axis=1).reshape(n, 3, 3)
    ay = np.stack([cp, zero, -sp, zero, one, zero, sp, zero, cp], axis=1).reshape(n, 3, 3)
    c = ay @ a2 @ a1  # eq. (3), then the turn psi; additive tilt: eq. (15)
    if not additive:
        c = c @ position_dcm(0.0, 0.0, 0.0, alpha0, beta0, "rigid")
    return c


def body_rate(angles: Array, rates: Array, beta0: float = 0.0) -> Array:
    """Body angular rate (rad/s, (n, 3)) of ``C = Ay(psi) A2(beta) A1(alpha) C0``.

    From ``Ċ = −[w]× C``: ``w = ψ̇ e_y + β̇ Ay(ψ) e_x + α̇ Ay(ψ) A2(β) e_z``; the constant
    base tilt C0 adds nothing. ``beta0`` is added to beta for the additive tilt model.
    """
    b, p = angles[:, 1] + beta0, angles[:, 2]
    da, db, dp = rates[:, 0], rates[:, 1], rates[:, 2]
    cb, sb, cp, sp = np.cos(b), np.sin(b), np.cos(p), np.sin(p)
    return np.stack([db * cp - da * sp * cb, dp + da * sb, db * sp + da * cp * cb], axis=1)


class ImuSimulator:
    """A simulated IMU producing blocks of raw samples, following poses or a plan.

    Deterministic for a given ``seed`` and sequence of calls; blocks split differently give
    the same samples up to floating-point rounding.
    """

    def __init__(self, truth: Truth, seed: int | None = None) -> None:
        self._truth = truth
        self._rng = np.random.default_rng(seed)
        self._trajectory = PoseTrajectory()
        self._static_cache: dict[tuple[float, float, float], Array] = {}
        self._t0_s = 0.0
        self._k = 0
        self._f_level = specific_force_level(truth.g)
        self._trim = trim_dcm(truth.trim)  # R_m: unit ← vehicle
        self._w_level = earth_rate_level(truth.latitude, truth.heading)
        self._temp0_c = float(truth.temperature.at(0.0))
        acc, gyr = truth.accel, truth.gyro
        self._instability = np.concatenate([acc.bias_instability, gyr.bias_instability])
        self._walk = np.zeros(6)
        self._markov = self._rng.normal(0.0, 1.0, 6) * self._instability
        self._set_rate(truth.sample_rate_hz)

    @property
    def truth(self) -> Truth:
        """The parameters of the simulated unit."""
        return self._truth

    @property
    def sample_rate_hz(self) -> float:
        """Output data rate (Hz)."""
        return self._fs

    def set_sample_rate(self, hz: float) -> None:
        """Change the output data rate from the next sample on (one of 50…1000 Hz)."""
        if hz not in OUTPUT_DATA_RATES_HZ:
            rates = ", ".join(map(str, OUTPUT_DATA_RATES_HZ))
            raise InputError(f"sample rate must be one of {rates} Hz, got {hz!r}")
        self._t0_s, self._k = self.time_s, 0
        self._set_rate(float(hz))
        log.debug("simulator: sample rate %g Hz at t = %.3f s", hz, self._t0_s)

    @property
    def time_s(self) -> float:
        """Simulated seconds since the start: the time of the next sample."""
        return self._t0_s + self._k / self._fs

    def set_pose(
        self, alpha: float, beta: float, psi: float = 0.0, transient_s: float = 1.0
    ) -> None:
        """Move to ``(alpha, beta, psi)`` (radians) over ``transient_s``; cancels a schedule."""
        self._trajectory.move_to(self.time_s, (alpha, beta, psi), transient_s)

    def set_schedule(self, plan: Plan, transient_s: float = 1.0) -> None:
        """Follow ``plan`` from now: each position held for its ``seconds``, moves between."""
        self._trajectory.follow(self.time_s, plan, transient_s)

    @property
    def schedule_end_s(self) -> float | None:
        """Time the schedule's last position ends (``None`` without a schedule)."""
        return self._trajectory.end_s

    @property
    def pose(self) -> Pose:
        """Pose at :attr:`time_s` (without the base tilt)."""
        alpha, beta, psi = self._trajectory.sample(self.time_s).angles[0]
        return Pose(float(alpha), float(beta), float(psi))

    @property
    def moving(self) -> bool:
        """Whether the unit is in a pose transient at :attr:`time_s`."""
        return bool(self._trajectory.sample(self.time_s).moving[0])

    @property
    def current_position_index(self) -> int | None:
        """Plan index while holding a scheduled position for its seconds, else ``None``.

        ``None`` while moving, without a schedule, and after the last position's seconds
        (the unit then keeps the last pose; see :attr:`schedule_end_s`).
        """
        index = int(self._trajectory.sample(self.time_s).index[0])
        return index if index >= 0 else None

    def next_block(self, n: int) -> SimBlock:
        """Advance ``n`` samples and return them."""
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
            raise InputError(f"block size must be a non-negative integer, got {n!r}")
        t = self._t0_s + (self._k + np.arange(n)) / self._fs
        self._k += int(n)
        traj = self._trajectory.sample(t)
        temp_c = self._truth.temperature.at(t)
        z = self._rng.standard_normal((n, 18))  # one draw per block: split-invariant stream
        out = self._clean_output(traj.angles, traj.rates) + z[:, 12:] * self._white_sigma
        out += self._drifts(z[:, :12]) + np.outer(temp_c - self._temp0_c, self._temp_coeff)
        out += self._registered_effects(traj.angles, temp_c)
        out = _quantize(out, self._steps)
        clipped = (out < INT16_MIN) | (out > INT16_MAX)
        out = np.clip(out, INT16_MIN, INT16_MAX)
        return SimBlock(
            t_s=t,
            accel=out[:, :3],
            gyro=out[:, 3:],
            temp_c=temp_c,
            saturated=np.asarray(clipped.any(axis=1), dtype=bool),
            moving=traj.moving,
            position_index=traj.index,
        )

    def _set_rate(self, fs: float) -> None:
        """Per-sample noise constants for the output data rate ``fs``."""
        self._fs = float(fs)
        acc, gyr = self._truth.accel, self._truth.gyro
        scale = np.abs(np.concatenate([np.diag(acc.K), np.diag(gyr.S)]))
        density = np.concatenate([acc.noise_density, gyr.noise_density])
        self._white_sigma = density * np.sqrt(self._fs) * scale
        self._walk_sigma = np.concatenate([acc.random_walk, gyr.random_walk]) / np.sqrt(self._fs)
        tau = np.concatenate([acc.correlation_time_s, gyr.correlation_time_s])
        self._phi = np.exp(-1.0 / (self._fs * tau))
        self._markov_sigma = self._instability * np.sqrt(1.0 - self._phi**2)
        self._temp_coeff = np.concatenate([acc.temp_coeff, gyr.temp_coeff])
        self._steps = np.repeat([acc.quantization, gyr.quantization], 3)

    def _clean_output(self, angles: Array, rates: Array) -> Array:
        """Noise- and drift-free counts ``[U | V]`` (n, 6) for the poses and angle rates."""
        if angles.shape[0] and not np.any(rates) and np.all(angles == angles[0]):
            key = (float(angles[0, 0]), float(angles[0, 1]), float(angles[0, 2]))
            if key not in self._static_cache:  # one static pose: one DCM, one output
                f, w = self._kinematics(angles[:1], rates[:1])
                self._static_cache = {key: self._counts(f, w)[0]}
            return np.broadcast_to(self._static_cache[key], (angles.shape[0], 6))
        return self._counts(*self._kinematics(angles, rates))

    def _kinematics(self, angles: Array, rates: Array) -> tuple[Array, Array]:
        """Specific force and angular rate in body axes, (n, 3) each."""
        tr = self._truth
        additive = tr.tilt_model == "additive"
        c = self._trim @ _dcm_batch(angles, tr.alpha0, tr.beta0, additive)  # eq. (T1)
        f = c @ self._f_level  # f = A f_L (eq. 5, z sign corrected: docs/method.md §2)
        motion = body_rate(angles, rates, tr.beta0 if additive else 0.0) @ self._trim.T
        w = c @ self._w_level + motion
        return f, w

    def _counts(self, f: Array, w: Array) -> Array:
        """``U = b + K f + quadratic ⊙ f²`` and ``V = B + S w + G f`` side by side (n, 6)."""
        acc, gyr = self._truth.accel, self._truth.gyro
        accel = acc.bias + f @ acc.K.T + acc.quadratic * f * f  # eq. (6) + quadratic term
        gyro = gyr.bias + w @ gyr.S.T + f @ gyr.G.T  # eq. (35) + g-sensitivity
        return np.hstack([accel, gyro])

    def _registered_effects(self, angles: Array, temp_c: Array) -> Array:
        """Return the counts ``(n, 6)`` of the truth's ``effects``: columns @ coefficients."""
        out = np.zeros((angles.shape[0], 6))
        if not self._truth.effects or not angles.shape[0]:
            return out
        f, _ = self._kinematics(angles, np.zeros_like(angles))
        acc, gyr = self._truth.accel, self._truth.gyro
        inputs = PoseInputs(
            angles, f, self._truth.g, acc.K, gyr.S, self._w_level, 6, temp_c - self._temp0_c
        )
        for key, coefficients in self._truth.effects.items():
            sensor, name = key.split(".", 1)
            columns = EFFECTS[name].known(inputs, sensor)  # type: ignore[arg-type, misc]
            if columns is not None:
                out += columns @ coefficients
        return out

    def _drifts(self, z: Array) -> Array:
        """Random-walk plus Gauss–Markov bias of the six channels from normals ``z`` (n, 12)."""
        n = z.shape[0]
        if n == 0:
            return np.zeros((0, 6))
        if not (np.any(self._walk_sigma) or np.any(self._instability)):
            return np.broadcast_to(self._walk, (n, 6))  # no drift terms: skip the filters
        steps = np.vstack([self._walk, z[:, :6] * self._walk_sigma])
        walk = np.cumsum(steps, axis=0)[1:]  # Wiener bias, increment σ = q/√f_s
        self._walk = walk[-1].copy()
        markov = np.zeros((n, 6))
        sigma, phi = self._markov_sigma, self._phi
        active = np.flatnonzero(self._instability > 0.0)
        if n <= 16:  # per-row recursion is cheaper than filter set-up for tiny blocks
            m = self._markov
            for k in range(n):
                m = phi * m + sigma * z[k, 6:]  # first-order Gauss–Markov
                markov[k] = m
        else:
            from scipy.signal import lfilter  # lazy (issue 23)

            for j in active:  # m[k] = φ m[k-1] + σ_e e[k] (first-order Gauss–Markov)
                zi = [phi[j] * self._markov[j]]
                markov[:, j] = lfilter([sigma[j]], [1.0, -phi[j]], z[:, 6 + j], zi=zi)[0]
        self._markov = markov[-1].copy()
        return walk + markov


def _quantize(x: Array, steps: Array) -> Array:
    """Round each column to its step; a step of 0 leaves the column as is."""
    if np.all(steps == 1.0):
        return np.round(x)
    safe = np.where(steps > 0.0, steps, 1.0)
    return np.where(steps > 0.0, np.round(x / safe) * safe, x)
