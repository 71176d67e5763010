"""The joint model: its spec, the parameter layout and the forward model with its Jacobians.

One implementation serves both the joint estimator (``joint.py``) and the plan bounds
(``plan.py``): the predicted mean of each position, its derivative with respect to the
parameters and with respect to the position's own angles (for the angle-setting tolerance).

Sensor models (docs/design.md §2, counts): accelerometer ``U = b + K C f_L`` (eq. 6, 15 with a rigid
or additive base tilt), gyro ``V = B + S C w_L + G C f_L`` (eq. 35 with g-sensitivity).
Angles are radians; the base tilt parameters ``base_tilt.alpha0/beta0`` too, and the mounting
trim ``mounting_trim.alpha/beta/psi`` of plans that determine it: ``C = R_m · C_pose · T0``
(docs/method.md §3, eq. T1). The DCMs of all positions and their derivatives come from
:mod:`canimucal.model.dcm_stack`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import ModelError
from canimucal.model.dcm_stack import dcm_stack, trimmed_stack
from canimucal.model.frames import (
    TiltModel,
    earth_rate_level,
    specific_force_level,
)
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.model.vocabulary.units import quantity_of

Array = NDArray[np.float64]
AccelKSpec = Literal["diag", "full"]
TiltSpec = Literal["none", "rigid", "additive"]
GyroSpec = Literal["none", "mems", "nav"]
MatrixSpec = Literal["diag", "full"]

_DIAG = ((0, 0), (1, 1), (2, 2))
_FULL = tuple((i, j) for i in range(3) for j in range(3))


@dataclass(frozen=True)
class JointSpec:
    """Which parameters the joint model estimates.

    ``accel_k``: diagonal scale factors or the full K (cross-axis terms). ``tilt``: no base
    tilt, a rigid tilted base (docs/design.md §2) or the paper's added angles (eq. 15). ``gyro``:
    none; ``mems`` (bias only, S fixed at nominal, Earth rate with nominal S when a latitude is
    given); ``nav`` (bias and S from Earth rate; needs a latitude). ``gyro_s`` the shape of S
    for ``nav``; ``gyro_g`` estimates the g-sensitivity G. ``trim`` estimates the unit's
    mounting trim in the vehicle (docs/method.md §3: only with K held at a prior does a
    plan determine it; a free full K absorbs any rotation of the unit's axes).
    """

    accel_k: AccelKSpec = "diag"
    tilt: TiltSpec = "rigid"
    gyro: GyroSpec = "none"
    gyro_s: MatrixSpec = "diag"
    gyro_g: bool = False
    trim: bool = False

    def __post_init__(self) -> None:
        """Check each field against its allowed values."""
        _check_choice("accel_k", self.accel_k, ("diag", "full"))
        _check_choice("tilt", self.tilt, ("none", "rigid", "additive"))
        _check_choice("gyro", self.gyro, ("none", "mems", "nav"))
        _check_choice("gyro_s", self.gyro_s, ("diag", "full"))
        if self.gyro_g and self.gyro == "none":
            raise ModelError("gyro_g needs a gyro model ('mems' or 'nav'), got gyro='none'")

    @property
    def tilt_model(self) -> TiltModel:
        """The tilt model of the DCM (``rigid`` when no tilt is estimated)."""
        return "additive" if self.tilt == "additive" else "rigid"

    @property
    def channels(self) -> int:
        """Observed channels per position: 3 (accelerometer) or 6 (with gyro)."""
        return 3 if self.gyro == "none" else 6


def _check_choice(field: str, value: object, allowed: tuple[object, ...]) -> None:
    if value not in allowed:
        raise ModelError(f"JointSpec.{field} must be one of {allowed}, got {value!r}")


@dataclass(frozen=True)
class ParameterLayout:
    """Names and positions of the parameters of a :class:`JointSpec` in the vector theta.

    Names follow the calibration JSON's covariance ``order``: ``accel.bias[i]``,
    ``accel.K[i][j]``, ``base_tilt.alpha0``, ``base_tilt.beta0``, ``mounting_trim.alpha``,
    ``mounting_trim.beta``, ``mounting_trim.psi``, ``gyro.bias[i]``, ``gyro.S[i][j]``,
    ``gyro.G[i][j]``.
    """

    spec: JointSpec
    names: tuple[str, ...]
    k_entries: tuple[tuple[int, int], ...]
    s_entries: tuple[tuple[int, int], ...]
    g_entries: tuple[tuple[int, int], ...]

    @classmethod
    def of(cls, spec: JointSpec) -> ParameterLayout:
        """Build the layout of ``spec``."""
        k = _DIAG if spec.accel_k == "diag" else _FULL
        s = () if spec.gyro != "nav" else (_DIAG if spec.gyro_s == "diag" else _FULL)
        gg = _FULL if spec.gyro_g else ()
        names = [f"accel.bias[{i}]" for i in range(3)]
        names += [f"accel.K[{i}][{j}]" for i, j in k]
        if spec.tilt != "none":
            names += ["base_tilt.alpha0", "base_tilt.beta0"]
        if spec.trim:
            names += list(TRIM_NAMES)
        if spec.gyro != "none":
            names += [f"gyro.bias[{i}]" for i in range(3)]
        names += [f"gyro.S[{i}][{j}]" for i, j in s]
        names += [f"gyro.G[{i}][{j}]" for i, j in gg]
        return cls(spec, tuple(names), k, s, gg)

    @property
    def size(self) -> int:
        """Number of parameters."""
        return len(self.names)

    def index(self, name: str) -> int:
        """Position of ``name`` in theta."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ModelError(f"no parameter {name!r} in this model") from None

    def unpack(self, theta: Array, gyro_lsb: float = DEFAULT_GYRO_LSB) -> ModelParams:
        """Split theta into the model's matrices (S nominal ``I/gyro_lsb`` when not estimated)."""
        it = iter(np.asarray(theta, dtype=float))
        bias = np.array([next(it) for _ in range(3)])
        k = np.zeros((3, 3))
        for i, j in self.k_entries:
            k[i, j] = next(it)
        alpha0 = beta0 = 0.0
        if self.spec.tilt != "none":
            alpha0, beta0 = next(it), next(it)
        trim = np.array([next(it) for _ in range(3)]) if self.spec.trim else np.zeros(3)
        gbias, s, gg = np.zeros(3), np.eye(3) / gyro_lsb, np.zeros((3, 3))
        if self.spec.gyro != "none":
            gbias = np.array([next(it) for _ in range(3)])
        if self.s_entries:
            s = np.zeros((3, 3))
        for i, j in self.s_entries:
            s[i, j] = next(it)
        for i, j in self.g_entries:
            gg[i, j] = next(it)
        return ModelParams(bias, k, float(alpha0), float(beta0), gbias, s, gg, trim)

    def effect_scales(self, g: float, k_counts_per_ms2: float) -> Array:
        """Effect of a unit change of each parameter at 1 g, in counts (docs/design.md §3).

        Biases 1; K and G entries g; tilt angles |k|·g; S entries Ω (their effect at the
        Earth rate). Used to normalise the Fisher information so units do not dominate.
        """
        k = abs(k_counts_per_ms2)
        return np.array([quantity_of(n).effect_counts(g, k) for n in self.names])

    def pack(self, params: ModelParams) -> Array:
        """Inverse of :meth:`unpack`: theta from the model's matrices."""
        values = list(params.accel_bias) + [params.K[i, j] for i, j in self.k_entries]
        if self.spec.tilt != "none":
            values += [params.alpha0, params.beta0]
        if self.spec.trim:
            values += list(params.trim)
        if self.spec.gyro != "none":
            values += list(params.gyro_bias)
        values += [params.S[i, j] for i, j in self.s_entries]
        values += [params.G[i, j] for i, j in self.g_entries]
        return np.array(values, dtype=float)


@dataclass(frozen=True)
class ModelParams:
    """The parameters of one evaluation of the model, as matrices (counts, radians).

    ``trim`` is the mounting trim ``(alpha_m, beta_m, psi_m)`` (zero when not estimated).
    """

    accel_bias: Array
    K: Array
    alpha0: float
    beta0: float
    gyro_bias: Array
    S: Array
    G: Array
    trim: Array = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class ModelContext:
    """What the forward model needs besides theta: g (m/s²) and the Earth rate in L (rad/s).

    ``w_level`` is zero when the gyro sees no Earth-rate term (no latitude given).
    """

    g: float
    w_level: Array
    gyro_lsb: float = DEFAULT_GYRO_LSB

    @classmethod
    def build(
        cls,
        g: float,
        latitude: float | None = None,
        heading: float = 0.0,
        gyro_lsb: float = DEFAULT_GYRO_LSB,
    ) -> ModelContext:
        """Context for gravity ``g`` and an optional latitude/heading (radians)."""
        w = np.zeros(3) if latitude is None else earth_rate_level(latitude, heading)
        return cls(float(g), w, gyro_lsb)

    @property
    def f_level(self) -> Array:
        """Specific force at rest in L."""
        return specific_force_level(self.g)


@dataclass(frozen=True)
class Prediction:
    """Predicted means ``(n, m)``, d/dtheta ``(n, m, p)``, d/d(alpha, beta, psi) ``(n, m, 3)``."""

    mean: Array
    d_theta: Array
    d_angles: Array


def predict(layout: ParameterLayout, theta: Array, angles: Array, ctx: ModelContext) -> Prediction:
    """Forward model of every position and its Jacobians (analytic).

    ``angles`` is ``(n, 3)`` (alpha, beta, psi) in radians. Channels: accelerometer x, y, z
    then, with a gyro model, gyro x, y, z.
    """
    spec = layout.spec
    par = layout.unpack(theta, ctx.gyro_lsb)
    if spec.trim:
        c, dc_ang, dc_tilt, dc_trim = trimmed_stack(
            angles, par.alpha0, par.beta0, spec.tilt_model, par.trim
        )  # eq. (T1): C = R_m C_pose T0
        dc_geo = np.concatenate([dc_tilt, dc_trim], axis=1)
    else:
        c, dc_ang, dc_geo = dcm_stack(angles, par.alpha0, par.beta0, spec.tilt_model)
    n, m, p = c.shape[0], spec.channels, layout.size
    mean, d_theta, d_angles = np.zeros((n, m)), np.zeros((n, m, p)), np.zeros((n, m, 3))
    f = c @ ctx.f_level
    df_ang = np.einsum("nkij,j->nik", dc_ang, ctx.f_level)  # d f / d angle k
    df_geo = np.einsum("nkij,j->nik", dc_geo, ctx.f_level)
    mean[:, :3] = par.accel_bias + f @ par.K.T  # eq. (6)
    d_angles[:, :3] = par.K @ df_ang
    geometry = _geometry_columns(layout)
    _accel_columns(layout, f, d_theta)
    d_theta[:, :3, geometry.columns] = (par.K @ df_geo)[:, :, geometry.rows]
    if m == 6:
        w = c @ ctx.w_level
        dw_ang = np.einsum("nkij,j->nik", dc_ang, ctx.w_level)
        dw_geo = np.einsum("nkij,j->nik", dc_geo, ctx.w_level)
        mean[:, 3:] = par.gyro_bias + w @ par.S.T + f @ par.G.T  # eq. (35) + g-sensitivity
        d_angles[:, 3:] = par.S @ dw_ang + par.G @ df_ang
        gyro_geo = par.S @ dw_geo + par.G @ df_geo
        d_theta[:, 3:, geometry.columns] = gyro_geo[:, :, geometry.rows]
        _gyro_columns(layout, (f, w), d_theta)
    return Prediction(mean, d_theta, d_angles)


TRIM_NAMES = ("mounting_trim.alpha", "mounting_trim.beta", "mounting_trim.psi")
"""The mounting trim's parameters: ``R_m = Ay(psi) A2(beta) A1(alpha)`` (docs/method.md §3)."""


@dataclass(frozen=True)
class _Geometry:
    """Which of the five geometric derivatives (alpha0, beta0, trim ×3) a layout fits, where."""

    rows: list[int]
    columns: list[int]


def _geometry_columns(layout: ParameterLayout) -> _Geometry:
    names = ("base_tilt.alpha0", "base_tilt.beta0", *TRIM_NAMES)
    rows = [k for k, name in enumerate(names) if name in layout.names]
    return _Geometry(rows, [layout.index(names[k]) for k in rows])


def _accel_columns(layout: ParameterLayout, f: Array, out: Array) -> None:
    """Fill the bias and K columns of the accelerometer rows of d/dtheta ``(n, m, p)``."""
    out[:, 0:3, 0:3] = np.eye(3)
    col = 3
    for i, j in layout.k_entries:
        out[:, i, col] = f[:, j]
        col += 1


def _gyro_columns(layout: ParameterLayout, fw: tuple[Array, Array], out: Array) -> None:
    """Fill the bias, S and G columns of the gyro rows of d/dtheta; ``fw`` = (f, w)."""
    f, w = fw
    col = layout.index("gyro.bias[0]")
    out[:, 3:6, col : col + 3] = np.eye(3)
    col += 3
    for i, j in layout.s_entries:
        out[:, 3 + i, col] = w[:, j]
        col += 1
    for i, j in layout.g_entries:
        out[:, 3 + i, col] = f[:, j]
        col += 1


def nominal_theta(
    layout: ParameterLayout,
    accel_lsb: float = DEFAULT_ACCEL_LSB,
    gyro_lsb: float = DEFAULT_GYRO_LSB,
) -> Array:
    """Theta at the nominal model: zero biases, ``K = I/accel_lsb``, ``S = I/gyro_lsb``, G 0."""
    zero = np.zeros(3)
    params = ModelParams(
        zero, np.eye(3) / accel_lsb, 0.0, 0.0, zero, np.eye(3) / gyro_lsb, np.zeros((3, 3))
    )
    return layout.pack(params)


@dataclass(frozen=True)
class AngleErrorMoments:
    """Mean shift ``(n, m)`` and covariance ``(n, m, m)`` that angle-setting errors add."""

    shift: Array
    covariance: Array


def angle_error_moments(
    layout: ParameterLayout,
    theta: Array,
    angles: Array,
    ctx: ModelContext,
    tolerances: Array,
) -> AngleErrorMoments:
    """Errors in variables: what random angle errors ε ~ N(0, diag(tol²)) do to each mean.

    To second order, ``m(a + ε) = m(a) + J ε + ½ εᵀ H ε`` per channel, so the mean shifts by
    ``½ Σ_k tol_k² H_kk`` and the covariance is ``J T Jᵀ + ½ tr(H_a T H_b T)`` with
    ``T = diag(tol²)``. The second-order terms matter once ``k·g·tol²`` nears the noise of a
    mean (1° tolerance, 1 count/√Hz over 30 s). ``tolerances`` ``(n,)`` or ``(n, 3)`` radians.
    """
    rows = np.atleast_2d(np.asarray(angles, dtype=float))
    n = rows.shape[0]
    tol2 = np.broadcast_to(np.asarray(tolerances, dtype=float).reshape(n, -1), (n, 3)) ** 2
    jac = predict(layout, theta, rows, ctx).d_angles
    step = 1e-5
    hess = np.zeros(jac.shape + (3,))
    for k in range(3):
        e = np.zeros(3)
        e[k] = step
        plus = predict(layout, theta, rows + e, ctx).d_angles
        minus = predict(layout, theta, rows - e, ctx).d_angles
        hess[..., k] = (plus - minus) / (2.0 * step)
    hess = 0.5 * (hess + np.swapaxes(hess, 2, 3))
    shift = 0.5 * np.einsum("nckk,nk->nc", hess, tol2)
    first = np.einsum("nik,nk,njk->nij", jac, tol2, jac)
    second = 0.5 * np.einsum("nakl,nl,nblk,nk->nab", hess, tol2, hess, tol2)
    return AngleErrorMoments(shift, first + second)
