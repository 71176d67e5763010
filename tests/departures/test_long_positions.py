"""Long positions: `analyze` runs on any length `solve` takes (issue 21 item 12).

The issue's shape is the recommended plan at 200 Hz, 417 s a position (670 k rows; 10⁶ rows
at 625 s): ``benchmarks/long_positions.py`` runs it (over a minute). Here the same 417 s
positions at 50 Hz (168 k rows), a random unit (cross-axis up to 1 % of scale, base tilt up
to 1°), no tolerance in the header. Before, the replay's joint fit ran into its rank check
(``the plan cannot determine accel.bias[1], accel.K[0][0], …``: the accelerometer's weakest
combination below 1e-10 of the best-determined parameter once the means' noise shrank
beside the pose term) and `analyze` exited 2, at 200 Hz and at 50 Hz alike; the fit's rank
is now judged at each parameter's own precision (:func:`canimucal.model.joint.rank_scales`).

The pose scatter the selection whitens by is that of the model holding every candidate,
fitted exactly (:func:`canimucal.analysis.discrepancy._full_model_scatter`), and no smaller
model's REML may exceed its 95 % interval. Before, the first estimate came from the tilt-free
linearisation, where the tilt's second order (0.25 counts a position) has no other term to go
to once the means are this precise: τ ran to its 10° bound, every test was whitened at 10°,
and nothing was named although the unit has a tilt and cross-axis terms (named at 30 s
positions). Here both must be named, nothing else, with the scatter where the poses put it.
"""

from __future__ import annotations

import numpy as np

from canimucal.analysis.replay import replay
from canimucal.analysis.report import analyze
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.sim.truth import Truth

POSITION_S = 417.0
RATE_HZ = 50.0
TRUE_CAUSES = {"base_tilt", "cross_axis"}


def test_long_positions_analyse_and_replay() -> None:
    truth = Truth.random(np.random.default_rng(1))
    plan = RECOMMENDED.with_total_seconds(POSITION_S * len(RECOMMENDED.positions))
    rec = simulate_plan_recording(truth, plan, seed=1, sample_rate_hz=RATE_HZ)
    assert rec.n_rows > 160_000
    a = analyze(rec)
    rows = replay(a)
    assert rows, "the replay ran"
    named = {f.effect for f in a.result.findings}
    assert named == TRUE_CAUSES, named
    assert a.result.noise is not None
    assert a.result.noise.pose_scatter.value_deg < 0.5, a.result.noise.pose_scatter
