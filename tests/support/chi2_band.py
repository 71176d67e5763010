"""Acceptance bands of seed sweeps: where a sum of squared normalised errors must lie."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2 as chi2_dist


def chi2_ratio_band(
    dof: int, comparisons: int = 1, family_alpha: float = 1e-3
) -> tuple[float, float]:
    """Where ``χ²/dof`` lies for ``dof`` independent unit-variance Gaussian terms.

    Two-sided, Bonferroni over ``comparisons``: a right σ fails once in ``1/family_alpha``
    runs. For the Mahalanobis distances ``dᵀ C⁻¹ d`` of ``n`` sessions' 9 entries of S
    (``dof = 9n``), or the squared z of one entry over ``n`` seeds (``dof = n``: the truth is
    known, no mean is estimated).
    """
    a = family_alpha / comparisons / 2
    return float(chi2_dist.ppf(a, dof) / dof), float(chi2_dist.ppf(1 - a, dof) / dof)


def mahalanobis(error: np.ndarray, covariance: np.ndarray) -> float:
    """``dᵀ C⁻¹ d`` of an estimate's error against its reported covariance."""
    d = np.asarray(error, dtype=float).reshape(-1)
    return float(d @ np.linalg.solve(np.asarray(covariance, dtype=float), d))
