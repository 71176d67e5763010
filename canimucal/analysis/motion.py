"""Motion inside a position: the accelerometer's direction turning while ``|f|`` stays steady.

Within position p the least-squares slope ``s_p`` (counts/s, one per axis, with its white
standard error ``σ_pc``; :func:`~.drift.slope`) splits along the position's mean direction
``u_p = m_p/|m_p|`` and across it. A unit that turns during the position (a stand creeping,
a vehicle settling on its jacks, a hand letting go) turns ``f`` and keeps ``|f|``: to first
order its slope ``K (ω × f)`` lies across ``u_p``. A bias that moves has no such preference.
With ``e₁, e₂`` unit vectors across ``u_p``:

    z_k = (e_k · s_p) / √(Σ_c e_kc² σ_pc²),   k = 1, 2      (across: χ² on 2 dof)
    z_r = (u_p · s_p) / √(Σ_c u_pc² σ_pc²)                  (along: χ² on 1 dof)

(the axes' white errors are independent, so each projection's variance is the weighted sum;
the cross term between ``e₁`` and ``e₂`` is dropped: with near-equal ``σ_pc`` it vanishes).
Position p *moved* when the across part is significant at ``alpha / P`` (Bonferroni over
the P positions) and the along part is not; it turned by ``θ_p ≈ |s_⊥| T_p / |m_p|`` rad over
its window of ``T_p`` seconds (``|m_p|`` stands for ``|K f|``; a bias of 2 % of it moves θ by
as much). A bias walk on an axis across gravity looks alike in one position, so the loop
(:mod:`.discrepancy`) claims motion only when the other positions, taken alone, no longer
trend: a walk trends in every position.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.data import Samples
from canimucal.analysis.drift import drift_test, slope
from canimucal.model.chi2_tail import chi2_sf

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PositionMotion:
    """One position that moved: its index (0-based), the turn over its window and its z."""

    index: int
    angle_deg: float
    across_chi2: float
    along_z: float
    seconds: float

    def line(self, name: str | None = None) -> str:
        """Say it: ``the unit moved 0.3° during position 3 (…)``; ``name`` for "3"."""
        return (
            f"the unit moved {self.angle_deg:.2g}° during position {name or self.index + 1} (its "
            f"direction turned over {self.seconds:.3g} s, across-gravity slope χ² = "
            f"{self.across_chi2:.1f} on 2 dof, |f| steady: along z = {self.along_z:+.1f})"
        )


def _across(u: Array) -> tuple[Array, Array]:
    """Two unit vectors completing ``u`` to a right-handed orthonormal basis."""
    seed = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, seed)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def positions_that_moved(
    windows: Sequence[tuple[Array, Samples]], alpha: float, walk: Array | None = None
) -> tuple[PositionMotion, ...]:
    """Return the positions whose accelerometer direction turned (module doc).

    ``windows`` are each position's ``(t_s (n,), accel (n, 3))`` counts; ``alpha`` the level
    of the whole test (Bonferroni over the positions inside). ``walk``: a bias random walk
    ``q`` per axis (counts/√s) whose slopes count as noise: a window of ``T`` s then has
    slope variance ``σ_pc² + 6 q_c² / (5 T)`` (:func:`~.drift.walk_estimate`'s).
    """
    level = alpha / max(len(windows), 1)
    moved = []
    for i, (t, samples) in enumerate(windows):
        x = np.asarray(samples, dtype=np.float64)  # before any sum (float32 windows)
        keep = np.all(np.isfinite(x), axis=1)
        if keep.sum() < 8:
            continue
        s, e = slope(t[keep], x[keep])
        if walk is not None:
            seconds = max(float(t[keep][-1] - t[keep][0]), 1e-300)
            e = np.sqrt(e * e + 6.0 * np.asarray(walk) ** 2 / (5.0 * seconds))
        mean = x[keep].mean(axis=0)
        size = float(np.linalg.norm(mean))
        if not size > 0 or not np.all(e > 0):
            continue
        u = mean / size
        e1, e2 = _across(u)
        z1, z2 = (float(v @ s) / float(np.sqrt((v * v) @ (e * e))) for v in (e1, e2))
        z_r = float(u @ s) / float(np.sqrt((u * u) @ (e * e)))
        across = z1 * z1 + z2 * z2
        if chi2_sf(2, across) < level and chi2_sf(1, z_r * z_r) >= level:
            seconds = float(t[keep][-1] - t[keep][0])
            perp = s - (u @ s) * u
            angle = float(np.rad2deg(np.linalg.norm(perp) * seconds / size))
            moved.append(PositionMotion(i, angle, across, z_r, seconds))
    return tuple(moved)


def moved_alone(
    windows: Sequence[tuple[Array, Samples]],
    level: float,
    temperature_rates: Array | None = None,
) -> tuple[PositionMotion, ...]:
    """Return the positions that moved, when they alone carry the accelerometer's trends.

    Positions whose direction turned while ``|f|`` stayed steady
    (:func:`positions_that_moved` at ``level``) are taken out and the drift test
    (:func:`~.drift.drift_test`) run on the others: when these no longer trend at ``level``
    the trends were the unit moving, not a wandering bias (a bias walk trends in every
    position, along gravity as much as across it); else nothing is said of motion. A moved
    position must also stay significant beside the random walk the others' slopes allow
    (their :func:`~.drift.walk_estimate`, taken as slope noise): a mild walk too weak to
    trend in the others still turns one position's direction by chance (~0.04° in 10 s
    positions, on 5 of 40 bias-walk seeds at 10⁻⁴ before this check, none after).
    ``temperature_rates``: °C/s per window, as the drift test takes them.
    """
    moved = positions_that_moved(windows, level)
    taken = {m.index for m in moved}
    still = [i for i in range(len(windows)) if i not in taken]
    if not moved or len(still) < 2:
        return ()
    rates = None if temperature_rates is None else np.asarray(temperature_rates)[still]
    rest = drift_test([windows[i] for i in still], rates)
    if rest.p_value < level:
        return ()
    beyond = {m.index for m in positions_that_moved(windows, level, walk=rest.random_walk)}
    return tuple(m for m in moved if m.index in beyond)
