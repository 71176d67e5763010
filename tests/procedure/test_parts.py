"""The procedure's parts: pose check and words, stillness, warm-up slope, acceptance."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canimucal.analysis.acceptance import AcceptanceLimits, check_acceptance
from canimucal.model.positions import Pose
from canimucal.procedure.posecheck import check_pose, describe_pose, predicted_force
from canimucal.procedure.stillness import StillnessDetector
from canimucal.procedure.warmup import WarmupTracker

G = 9.81
DEG = float(np.deg2rad(1.0))


def test_pose_words_follow_design_directions() -> None:
    assert describe_pose(Pose(0.0, 0.0)) == "set the unit level on the base"
    words = describe_pose(Pose(45 * DEG, 5 * DEG, 90 * DEG))
    assert "lower the +x end" in words and "raise the +z end" in words
    assert "turn the unit 90°" in words
    assert "raise the +x end" in describe_pose(Pose(-10 * DEG, 0.0))


def test_predicted_force_matches_design_anchors() -> None:
    # docs/design.md §2: C(90°,0,0) f_L = [-g, 0, 0]; C(0,90°,0) f_L = [0, 0, +g]
    assert predicted_force(Pose(90 * DEG, 0.0), G) == pytest.approx([-G, 0, 0], abs=1e-9)
    assert predicted_force(Pose(0.0, 90 * DEG), G) == pytest.approx([0, 0, G], abs=1e-9)


@settings(derandomize=True, deadline=None, max_examples=60)
@given(
    alpha=st.floats(-45, 45),
    beta=st.floats(-45, 45),
    psi=st.sampled_from([0.0, 90.0, 180.0, 270.0]),
)
def test_a_pose_is_accepted_where_it_is_and_refused_mirrored(
    alpha: float, beta: float, psi: float
) -> None:
    pose = Pose(alpha * DEG, beta * DEG, psi * DEG)
    f = predicted_force(pose, G)
    right = check_pose(pose, f, G, 3.0)
    assert right.passed and right.error_deg < 1e-9
    assert right.measured_deg == pytest.approx((alpha, beta), abs=1e-6)
    if max(abs(alpha), abs(beta)) > 2.0:
        mirrored = Pose(-alpha * DEG, -beta * DEG, psi * DEG)
        assert not check_pose(pose, predicted_force(mirrored, G), G, 3.0).passed


def test_stillness_sees_rest_and_motion() -> None:
    rng = np.random.default_rng(1)
    det = StillnessDetector(200.0, 9.80665 / 2048)
    rest = rng.normal(0.0, 4.0, (400, 3))
    assert det.update(rest[:200], 200) and det.update(rest[200:], 200)
    assert det.still_for_s == pytest.approx(2.0)  # both blocks ended still
    # a 45° turn over 1 s: |Δf| ~ 7 m/s² ≈ 1500 counts
    ramp = np.linspace(0.0, 1500.0, 200)[:, None] * np.array([[1.0, -0.3, 0.0]])
    assert not det.update(rest[:200] + ramp, 200)
    assert det.still_for_s == 0.0
    det.learn_noise(np.full(3, 4.0))
    assert np.all(det.threshold_counts == 16.0)


def test_warmup_slope_and_threshold() -> None:
    w = WarmupTracker(window_s=30.0, threshold_c_per_min=0.1)
    for t in np.arange(0.0, 40.0, 0.1):
        w.add(float(t), 25.0 + 0.5 * t / 60.0)  # 0.5 °C/min
    assert w.slope_c_per_min == pytest.approx(0.5, rel=1e-6) and not w.warm
    for t in np.arange(40.0, 80.0, 0.1):
        w.add(float(t), 25.5)
    assert w.warm
    silent = WarmupTracker(window_s=5.0)
    for t in range(10):
        silent.add(float(t), float("nan"))
    assert silent.warm  # nothing to wait for without a temperature


def test_acceptance_limits_name_what_failed(diag_truth: object) -> None:
    from canimucal.model.vocabulary.plans import builtin_plan
    from canimucal.procedure import events as ev
    from tests.support.procedure_bench import Bench, of

    bench = Bench([diag_truth], builtin_plan("five"))  # type: ignore[list-item]
    bench.whole_plan()
    solution = of(bench.do("solve"), ev.Solved)[0].solutions[0x10]
    lsb = 9.80665 / 2048
    loose = check_acceptance(solution, AcceptanceLimits(), lsb, G)
    names = [c.name for c in loose.checks]
    assert names[:3] == ["worst bias σ", "worst scale σ", "fit rms"]
    strict = check_acceptance(
        solution, AcceptanceLimits(max_bias_sigma_mg=0.01, max_scale_sigma_ppm=1e6), lsb, G
    )
    assert not strict.passed
    failed = [c for c in strict.checks if not c.passed]
    assert [c.name for c in failed] == ["worst bias σ"] and "FAILED" in failed[0].line()
