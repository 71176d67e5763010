"""Whole vehicle sessions over the virtual bus with a floor slope and a mounting trim drawn.

The simulated node (a canopen ``LocalNode`` on python-can's virtual bus) is a unit bolted in
with a trim of up to 2° about each axis, on a floor sloped by up to 3°; the automatic
operator follows the vehicle plan. Every session completes (no pose refused), solves slope
and trim within 4σ of the truth (and the gyro's S from the moves, in the unit's axes),
writes the calibration, and the trim the node holds (0x2122, read back over SDO) is the one
solved, to the bit of its REAL32 radians.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.calibrate import MISFIT_P, SiteConditions
from canimucal.device import od
from canimucal.model.layout import TRIM_NAMES
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.runtime.operator import run_automatic
from canimucal.runtime.wiring import demo_settings, open_devices
from canimucal.sim.truth import Truth

SEEDS = (21, 22)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_vehicle_session_with_slope_and_trim_writes_the_trim_it_solved(
    seed: int, tmp_path: Path
) -> None:
    rng = np.random.default_rng(seed)
    doc = Truth.random(rng, cross_axis_max=0.0, scale_error_max=0.0173).to_dict()
    del doc["base_tilt_deg"]
    doc["floor_slope_deg"] = rng.uniform(-3.0, 3.0, 2).tolist()
    doc["mounting_trim_deg"] = rng.uniform(-2.0, 2.0, 3).tolist()
    truth = Truth.from_dict(doc)
    with open_devices(demo_settings([truth], time_scale=100.0, seed=seed)) as rig:
        session = rig.session(
            builtin_plan("vehicle"),
            tmp_path,
            plan_name="vehicle",
            site=SiteConditions(g=9.80665),
            warmup=False,
            averaging=AveragingPolicy(fixed_s=10.0),
            verify_seconds=2.0,
        )
        history = run_automatic(session, write_anyway=True)
        client = rig.clients[0x10]
        trim_bytes = [client.read_raw(i, s, "f32") for i, s in od.TRIM_KEYS]
        readout = client.read_calibration_block()
    assert not [e for e in history if isinstance(e, ev.PoseRefused | ev.MoveRefused)]
    (written,) = [e for e in history if isinstance(e, ev.WriteFinished)]
    assert written.ok, written
    (solved,) = [e for e in history if isinstance(e, ev.Solved)]
    joint = solved.solutions[0x10].joint
    assert joint is not None
    # a clean unit on a sloped floor passes the vehicle plan's own acceptance (§3), which a
    # session opened without limits judges against. A clean session's fit p is uniform
    # (tests/runtime/test_vehicle_fit.py): below MISFIT_P, 1 % of sessions, the fit is called
    # rejected and every σ inflated by its Birge factor, which may then fail the σ limits by
    # design (CI once: p = 0.0079, bias σ 17.7 mg against 15). Then only σ limits may fail.
    checks = solved.acceptance[0x10].checks
    fit_p = next(c.value for c in checks if c.key == "min_fit_p")
    failed = [c.key for c in checks if not c.passed]
    if fit_p >= MISFIT_P:
        assert not failed, [c.line() for c in checks]
    else:
        assert set(failed) <= {"max_bias_sigma_mg", "max_scale_sigma_ppm"}, [
            c.line() for c in checks
        ]
    truths = {"base_tilt.alpha0": truth.alpha0, "base_tilt.beta0": truth.beta0}
    truths.update(zip(TRIM_NAMES, truth.trim, strict=True))
    for name, true in truths.items():
        assert abs(joint.value(name) - true) < 4 * joint.sigma(name), name
    solved_trim = [od.encode("f32", joint.value(n)) for n in TRIM_NAMES]
    assert trim_bytes == solved_trim  # what the node holds is what was solved
    assert readout.valid == 1 and readout.crc_ok and readout.trim
    record = session.links[0x10].record
    assert record is not None and record.readback is not None
    assert record.readback.mounting_trim_rad == pytest.approx(
        [od.decode("f32", b) for b in solved_trim], abs=0.0
    )
    # the gyro's S from the moves is the unit's own: the moves are the poses as the unit,
    # trimmed in the vehicle, turned (without the trim S would hold it: 20 counts, 10σ)
    assert record.gyro is not None and record.gyro.S is not None
    fitted = [(i, j) for i in range(3) for j in range(3) if record.gyro.S[i][j] is not None]
    assert fitted and record.gyro.S_sigma is not None, solved.solutions[0x10].warnings
    for i, j in fitted:
        value, sigma = record.gyro.S[i][j], record.gyro.S_sigma[i][j]
        assert value is not None and sigma is not None
        assert abs(value - truth.gyro.S[i, j]) < 4 * sigma, (i, j, value, sigma)
    # the verification poses predict the calibrated reading in the unit's axes, trim included
    # (without it a 2° trim read as ~2° of tilt error against the 2° limit)
    verified = [e for e in history if isinstance(e, ev.PoseVerified)]
    assert len(verified) >= 2
    for pose in verified:
        assert pose.tilt_error_calibrated_deg < 1.0, pose
        assert abs(pose.norm_error_calibrated_ms2) < 5e-3 * 9.80665, pose
    certificate = (tmp_path / "certificate.md").read_text()
    assert "written to 0x2122, the node's output is aligned" in certificate
