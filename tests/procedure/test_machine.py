"""The procedure state machine fed with injected sample blocks (no CAN, no wall time).

Seeds are fixed (truth 20261121, noise 11 + node). The statistical margins are stated where
a threshold is used; the disturbance test's false-alarm rate is far below one in a million
per chunk at k = 6 (see canimucal.model.static.detect_disturbance).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canimucal.model.positions import Plan, PlannedPosition, Pose
from canimucal.model.samples import SampleBlock
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.sim.truth import Truth
from tests.support.procedure_bench import Bench, of

FIVE = builtin_plan("five")


def test_five_positions_end_to_end_recover_the_truth(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE)
    bench.whole_plan()
    events = bench.do("solve")
    solved = of(events, ev.Solved)[0]
    joint = solved.solutions[0x10].joint
    assert joint is not None
    names = list(joint.names)
    sigma = np.sqrt(np.diag(joint.covariance))
    for i in range(3):
        k = names.index(f"accel.bias[{i}]")
        assert abs(joint.values[k] - diag_truth.accel.bias[i]) < 4 * sigma[k]
        k = names.index(f"accel.K[{i}][{i}]")
        assert abs(joint.values[k] - diag_truth.accel.K[i, i]) < 4 * sigma[k]
    assert bench.proc.phase is Phase.REVIEW
    before = of(events, ev.LevelChecked)[0]
    assert before.stage == "before"
    # nominal |f| - g is off by the scale errors (up to 3 %: ~0.3 m/s²); calibrated ~ noise
    assert abs(before.norm_error_calibrated_ms2) < 0.01


def test_each_position_records_n_mean_std_lost_and_temperature(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE)
    bench.position()
    average = of(bench.events, ev.PositionAveraged)[0].averages[0x10]
    assert average.n >= 3.0 * bench.fs
    assert average.lost == 0
    assert average.temp_c == pytest.approx(25.0, abs=0.5)
    # per-sample accel std ≈ noise density · √fs in counts (1.5e-3 m/s²/√Hz · √200 / lsb ≈ 4.4)
    expected = 1.5e-3 * np.sqrt(bench.fs) / diag_truth.accel.nominal_lsb
    assert np.all(np.abs(average.std_accel / expected - 1.0) < 0.15)
    assert average.std_gyro is not None and np.all(average.std_gyro > 0)


def _drop(lose_halves: int, gap: int) -> object:
    """Alter blocks: ``lose_halves`` rows lose their gyro half, plus ``gap`` counter gaps."""

    def alter(node_id: int, block: SampleBlock) -> SampleBlock:
        gyro = block.gyro.copy()
        gyro[:lose_halves] = np.nan
        return replace(block, gyro=gyro, lost_gyro=lose_halves, lost_samples=gap)

    return alter


def test_lost_samples_are_counted_and_left_out(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE)
    bench.move(bench.proc.target)
    bench.run(1.5)
    bench.do("confirm_pose")
    alter = _drop(lose_halves=2, gap=1)  # per 20-row block: 2 half-lost rows + 1 gap
    bench.run_until(ev.PositionAveraged, 30.0, alter=alter)
    average = of(bench.events, ev.PositionAveraged)[0].averages[0x10]
    attempt_blocks = average.n / 20  # every accel row is finite: n counts 20 rows a block
    assert average.lost == pytest.approx(3 * attempt_blocks, abs=3)
    assert average.std_gyro is not None and np.all(np.isfinite(average.std_gyro))
    # the clock counts the gaps: 3 s of samples is reached with fewer rows (20 of every 21)
    assert average.n < 3.0 * bench.fs


def _bump(start_s: float, size_counts: float, fs: float) -> object:
    """Alter blocks: add ``size_counts`` to accel x for 0.2 s from ``start_s`` (a knock)."""
    seen = {"n": 0}

    def alter(node_id: int, block: SampleBlock) -> SampleBlock:
        i0 = seen["n"]
        seen["n"] += block.n
        idx = np.arange(i0, i0 + block.n) / fs
        hit = (idx >= start_s) & (idx < start_s + 0.2)
        if not hit.any():
            return block
        accel = block.accel.copy()
        accel[hit, 0] += size_counts * np.sin(2 * np.pi * 10 * idx[hit])
        return replace(block, accel=accel)

    return alter


def test_a_disturbance_rejects_the_attempt_and_it_is_never_averaged_in(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE)
    bench.move(bench.proc.target)
    bench.run(1.5)
    bench.do("confirm_pose")
    bench.run_until(ev.AveragingStarted, 10.0)
    # a 10 Hz knock of ±30 counts (±0.15 m/s²) for 0.2 s, 1 s into the averaging
    knock = _bump(1.0, 30.0, bench.fs)
    events = bench.run_until(ev.PositionAveraged, 30.0, alter=knock)
    rejected = of(events, ev.PositionRejected)
    assert len(rejected) == 1 and rejected[0].restarting
    assert "motion" in rejected[0].reason
    # the accepted attempt restarted after the knock: its mean is the clean level mean
    average = of(events, ev.PositionAveraged)[0].averages[0x10]
    se = average.std_accel / np.sqrt(average.n)
    clean = Bench([diag_truth], FIVE, seed=99)
    clean.position()
    ref = of(clean.events, ev.PositionAveraged)[0].averages[0x10]
    ref_se = ref.std_accel / np.sqrt(ref.n)
    # two independent means of the same pose: |Δ| < 5 σ_Δ (two-sided p ≈ 6e-7 per axis)
    assert np.all(np.abs(average.mean_accel - ref.mean_accel) < 5 * np.hypot(se, ref_se))
    bench.do("accept")
    rows = bench.proc.take_rows(0x10)
    labels = np.concatenate([np.full(p.block.n, p.position) for p in rows])
    # the rejected attempt's rows stay unlabelled; the labelled ones are the accepted attempt
    assert np.sum(labels == 0) == sum(p.block.n for p in rows if p.position == 0)
    assert np.sum(labels == 0) <= average.n + 20
    assert np.sum(labels == -1) > 0


def test_redo_discards_the_attempt_and_measures_again(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE)
    bench.position()
    first = of(bench.events, ev.PositionAveraged)[0].averages[0x10]
    events = bench.do("redo")
    assert of(events, ev.PositionRejected)[0].reason == "redo by the operator"
    instructed = of(events, ev.PoseInstructed)
    assert instructed and instructed[0].index == 0 and bench.proc.phase is Phase.INSTRUCT
    bench.position()
    second = of(bench.events, ev.PositionAveraged)[1].averages[0x10]
    assert not np.array_equal(first.mean_accel, second.mean_accel)
    bench.do("accept")
    assert bench.proc.accepted[0x10][0] is second
    assert bench.proc.index == 1
    rows = bench.proc.take_rows(0x10)
    n_labelled = sum(p.block.n for p in rows if p.position == 0)
    assert second.n <= n_labelled < second.n + 20  # only the second attempt is labelled


def test_a_pose_of_the_wrong_sign_is_refused(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE)
    bench.position()
    bench.do("accept")  # level done; target (22.5°, 0°)
    target = bench.proc.target
    bench.move(Pose(-target.alpha, target.beta))  # raised instead of lowered
    bench.run(1.5)
    bench.do("confirm_pose")
    events = bench.run_until(ev.PoseRefused, 10.0)
    refused = of(events, ev.PoseRefused)[0]
    assert refused.target_deg == pytest.approx((22.5, 0.0))
    assert refused.measured_deg[0] == pytest.approx(-22.5, abs=2.0)
    assert "sign" in refused.message and bench.proc.phase is Phase.INSTRUCT
    assert not of(events, ev.AveragingStarted)
    bench.position()  # set right: averaged
    assert of(bench.events, ev.PositionAveraged)[-1].index == 1


def test_a_beta_of_the_wrong_sign_is_refused_at_the_small_tilts_of_five(
    diag_truth: Truth,
) -> None:
    bench = Bench([diag_truth], FIVE)
    for _ in range(2):
        bench.position()
        bench.do("accept")
    target = bench.proc.target  # (22.5°, 2.5°): -2.5° is 5° off, tolerance 3°
    bench.move(Pose(target.alpha, -target.beta))
    bench.run(1.5)
    bench.do("confirm_pose")
    refused = of(bench.run_until(ev.PoseRefused, 10.0), ev.PoseRefused)[0]
    assert refused.error_deg == pytest.approx(5.0, abs=1.0)


def test_warmup_waits_for_the_temperature_slope() -> None:
    # 20 -> 30 °C over the first 60 s (10 °C/min), flat afterwards; window 30 s, 0.1 °C/min
    truth = Truth.random(
        np.random.default_rng(3),
        cross_axis_max=0.0,
        temperature={"profile": [[0.0, 20.0], [60.0, 30.0], [10000.0, 30.0]]},
    )
    bench = Bench([truth], FIVE, warmup=True, warmup_window_s=30.0)
    events = bench.run_until(ev.PoseInstructed, 200.0, block_n=50)
    progress = of(bench.events, ev.WarmupProgressed)
    early = [p for p in progress if 30.0 <= p.elapsed_s <= 55.0]
    assert early and all(not p.warm and p.slope_c_per_min > 5.0 for p in early)
    final = of(events, ev.WarmupProgressed)[-1]
    assert final.warm and abs(final.slope_c_per_min) <= 0.1
    # flat from 60 s: the 30 s window's fitted slope falls below 0.1 °C/min only when the
    # ramp has (almost) left it, 60 + 30 s, less the last ~2 s of ramp it tolerates
    assert 85.0 <= final.elapsed_s <= 95.0


def test_warmup_can_be_skipped(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE, warmup=True)
    bench.run(2.0)
    assert bench.proc.phase is Phase.WARMUP
    events = bench.do("skip_warmup")
    assert of(events, ev.WarmupProgressed)[0].skipped
    assert bench.proc.phase is Phase.INSTRUCT


def _short_plan(seconds: float = 30.0) -> Plan:
    level = PlannedPosition(0.0, 0.0, 0.0, seconds=seconds)
    tilted = PlannedPosition(float(np.deg2rad(45.0)), float(np.deg2rad(5.0)), seconds=seconds)
    return Plan("two", (level, tilted))


@pytest.mark.parametrize(
    ("random_walk", "low", "high"),
    [
        # white noise only: no ADEV minimum, the upper clip: the plan's 120 s
        (0.0, 120.0, 120.0),
        # q = 0.2 counts/√s with N = 0.31 counts·√s: τ* = √3·N/q ≈ 2.7 s on every axis,
        # far below the 15 s clip even when the fit on 120 s misses q by a factor 4
        (0.2, 15.0, 15.0),
    ],
)
def test_averaging_time_follows_the_noise_of_the_first_position(
    random_walk: float, low: float, high: float
) -> None:
    from canimucal.model.layout import JointSpec
    from canimucal.procedure.averaging import AveragingPolicy

    truth = Truth.random(
        np.random.default_rng(5),
        cross_axis_max=0.0,
        accel={"random_walk": [random_walk] * 3},
    )
    # no gyro model: the accelerometer's axes alone decide (test_averaging_rule has the gyro)
    spec = JointSpec(accel_k="diag", tilt="rigid", gyro="none")
    bench = Bench([truth], _short_plan(120.0), averaging=AveragingPolicy(), spec=spec)
    assert bench.proc.seconds_for(0) == 120.0
    assert bench.proc.seconds_for(1) == 120.0  # until the noise is known: the plan's
    bench.position()
    events = bench.do("accept")
    chosen = of(events, ev.AveragingTimeChosen)[0]
    assert chosen.source == "noise"
    assert low <= chosen.seconds <= high
    assert bench.proc.seconds_for(1) == chosen.seconds
    assert of(events, ev.PoseInstructed)[0].seconds == chosen.seconds


def test_a_user_averaging_time_overrides_the_noise(diag_truth: Truth) -> None:
    from canimucal.procedure.averaging import AveragingPolicy

    bench = Bench([diag_truth], _short_plan(), averaging=AveragingPolicy(user_s=20.0))
    assert bench.proc.seconds_for(0) == 120.0  # max(120 s, the user's value)
    assert bench.proc.seconds_for(1) == 20.0
    plain = Bench([diag_truth], _short_plan(), averaging=AveragingPolicy())
    assert plain.proc.seconds_for(0) == 120.0  # max(120 s, the plan's 30 s): the noise
    assert plain.proc.seconds_for(1) == 30.0  # the plan's, a budget the noise may shorten
    policy = AveragingPolicy(user_s=150.0)
    assert policy.first_seconds() == 150.0
    assert AveragingPolicy(fixed_s=4.0).first_seconds() == 4.0


def test_several_nodes_share_the_poses_and_each_gets_its_result() -> None:
    rng = np.random.default_rng(77)
    truths = [Truth.random(rng, cross_axis_max=0.0) for _ in range(2)]
    bench = Bench(truths, FIVE)
    # a knock seen only by the second node rejects the position for both
    bench.move(bench.proc.target)
    bench.run(1.5)
    bench.do("confirm_pose")
    bench.run_until(ev.AveragingStarted, 10.0)
    knock = _bump(0.8, 40.0, bench.fs)

    def second_only(node_id: int, block: SampleBlock) -> SampleBlock:
        return knock(node_id, block) if node_id == 0x11 else block  # type: ignore[operator]

    events = bench.run_until(ev.PositionAveraged, 30.0, alter=second_only)
    rejected = of(events, ev.PositionRejected)
    assert len(rejected) == 1 and rejected[0].node_id == 0x11
    assert set(of(events, ev.PositionAveraged)[0].averages) == {0x10, 0x11}
    bench.do("accept")
    bench.whole_plan()
    solved = of(bench.do("solve"), ev.Solved)[0]
    assert set(solved.solutions) == {0x10, 0x11}
    for node_id, truth in zip((0x10, 0x11), truths, strict=True):
        joint = solved.solutions[node_id].joint
        assert joint is not None
        k = list(joint.names).index("accel.K[0][0]")
        assert abs(joint.values[k] - truth.accel.K[0, 0]) < 4 * np.sqrt(joint.covariance[k, k])


def test_write_and_verification_flow(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE, verify_seconds=2.0)
    bench.whole_plan()
    bench.do("solve")
    assert bench.proc.begin_write() == [] or bench.proc.phase is Phase.WRITING
    if bench.proc.phase is not Phase.WRITING:
        bench.proc.begin_write(override=True)
    events = bench.proc.write_finished(0x10, True, "written")
    # two poses other than the fit's level one: five's most tilted, then level turned 90°
    first = of(events, ev.PoseInstructed)[0]
    assert first.verification and (first.index, first.total) == (0, 2)
    assert np.rad2deg(first.position.angles).round(6).tolist() == [45.0, 5.0, 0.0]
    assert first.words.startswith("verification 1/2: tilt 45° about z")
    bench.position()
    second = of(bench.events, ev.PoseInstructed)[-1]
    assert second.verification and (second.index, second.total) == (1, 2)
    assert np.rad2deg(second.position.angles).round(6).tolist() == [0.0, 0.0, 90.0]
    assert bench.proc.phase is Phase.INSTRUCT
    assert bench.proc.skip() == []  # a verification pose is never skipped
    bench.position()
    assert [c.stage for c in of(bench.events, ev.LevelChecked)] == ["before"]
    verified = of(bench.events, ev.PoseVerified)
    assert [v.index for v in verified] == [0, 1]
    for v in verified:  # within the limits (five cannot tell bias z from beta0: the turn shows
        # it, a few tenths of a degree; the level pose the fit started from would not)
        assert abs(v.norm_error_calibrated_ms2) < 0.005 and v.tilt_error_calibrated_deg < 2.0
    assert verified[1].tilt_error_calibrated_deg < verified[1].tilt_error_nominal_deg
    assert bench.proc.phase is Phase.DONE
    assert of(bench.events, ev.ProcedureFinished)


def test_cancel_ends_and_keeps_the_rows(diag_truth: Truth) -> None:
    bench = Bench([diag_truth], FIVE)
    bench.move(bench.proc.target)
    bench.run(1.0)
    bench.do("confirm_pose")
    bench.run_until(ev.AveragingStarted, 10.0)
    bench.run(0.5)
    events = bench.do("cancel")
    assert of(events, ev.ProcedureFinished)[0].cancelled
    rows = bench.proc.take_rows(0x10)
    assert sum(p.block.n for p in rows) == bench.counters[0x10]
    assert all(p.position == -1 for p in rows)
