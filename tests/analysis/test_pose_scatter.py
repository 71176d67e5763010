"""`solve`'s σ rest on the pose scatter estimated from the data, so they are the real ones.

Fixed seeds 0..19: a random unit (cross-axis, tilt ≤ 1°) under the recommended plan with
exactly set poses and with 0.1° poses, no tolerance given; bias, full K and the rigid base
tilt are fitted. The spread (standard deviation) of (estimate − truth)/σ over all 14
parameters and 20 seeds must lie within 0.8–1.2 (issue 14). Measured: 0.96 (exact poses)
and 0.94 (0.1°) over seeds 0..29; the 0.1° assumption on exact poses gives 0.34, with
entries down to 0.02. 280 values correlated within a seed: the spread's sampling error is
about 0.05, so 0.8–1.2 sits 3–4 of them away from 1.
"""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.analysis.pose_scatter import fit_scatter
from canimucal.model.joint import solve_joint
from canimucal.model.layout import JointSpec
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.sim.truth import Truth
from tests.support.sessions import simulate_session

SPEC = JointSpec(accel_k="full", tilt="rigid", gyro="none")


def _plan(tolerance_deg: float) -> Plan:
    tol = float(np.deg2rad(tolerance_deg))
    return Plan(
        "recommended",
        tuple(
            PlannedPosition(p.alpha, p.beta, p.psi, tol, p.seconds) for p in RECOMMENDED.positions
        ),
    )


@pytest.mark.parametrize("tolerance_deg", [0.0, 0.1])
def test_errors_over_sigma_have_unit_spread(tolerance_deg: float) -> None:
    z, taus = [], []
    for seed in range(20):
        truth = Truth.random(np.random.default_rng(seed))
        session = simulate_session(truth, _plan(tolerance_deg), seed=seed)
        site = {
            "g": truth.g, "latitude": truth.latitude, "heading": truth.heading,
            "accel_lsb": session.accel_lsb, "gyro_lsb": session.gyro_lsb,
        }  # fmt: skip
        averages, used = fit_scatter(session.averages, SPEC, **site)
        est = used.estimate
        assert est is not None and used.basis == "estimated" and used.dof == 10
        taus.append(est.value_deg)
        assert est.ci95[0] <= est.value <= est.upper84 <= est.ci95[1]
        res = solve_joint(averages, SPEC, allow_undetermined=True, **site)
        true = np.concatenate(
            [truth.accel.bias, truth.accel.K.ravel(), [truth.alpha0, truth.beta0]]
        )
        z.append((res.values - true) / np.sqrt(np.diag(res.covariance)))
    spread = float(np.std(np.array(z)))
    assert 0.8 <= spread <= 1.2, spread
    assert abs(np.median(taus) - tolerance_deg) < 0.03
