"""The prior on K a plan holds comes from the device when no file is given (docs/design.md §3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal import calibrate
from canimucal.analysis.calibrate import solve_positions
from canimucal.analysis.session_model import ModelChoice
from canimucal.analysis.solve import solve_recording
from canimucal.device.factory_k import device_k
from canimucal.errors import DeviceError, InputError
from canimucal.flag_words import worded_for_flags
from canimucal.io.calibration import read_calibration
from canimucal.io.recording import normalise_header
from canimucal.model.plan import plan_prior
from canimucal.model.sensor import DEFAULT_ACCEL_LSB
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.operator import run_automatic
from canimucal.runtime.wiring import DeviceSettings, SimSettings, open_devices
from canimucal.sim.truth import Truth
from tests.support.device_state import readout, state_file

LSB = DEFAULT_ACCEL_LSB
NODE = 0x10


def test_the_device_k_is_the_inverse_of_an_active_correction_else_the_nominal_lsb() -> None:
    k = np.diag([1.03, 0.96, 1.05]) / LSB + 0.2
    held = device_k(readout(np.linalg.inv(k)), LSB, NODE)
    np.testing.assert_allclose(held.k, k, rtol=1e-5)  # M as REAL32
    assert held.calibrated and "0x2101" in held.source and "node 16" in held.source
    inactive = device_k(readout(np.linalg.inv(k), valid=0), LSB, NODE)
    np.testing.assert_array_equal(inactive.k, np.eye(3) / LSB)
    assert not inactive.calibrated and "valid = 0" in inactive.source
    assert "0x2010:01" in inactive.source


@pytest.mark.parametrize(
    ("m", "words"),
    [
        (np.diag([LSB, np.nan, LSB]), "non-finite"),
        (np.array([[LSB, 0, 0], [LSB, 0, 0], [0, 0, LSB]]), "singular"),
    ],
)
def test_a_non_finite_or_singular_device_correction_is_refused(m: np.ndarray, words: str) -> None:
    with pytest.raises(DeviceError, match=f"node 16 .*0x2101:01.*{words}") as info:
        device_k(readout(m), LSB, NODE)
    assert "\n" not in str(info.value) and "give prior_k, a file," in str(info.value)
    assert "give --prior-k, a file," in worded_for_flags(info.value)  # as the shells say it


def _truth() -> Truth:
    """A unit 12 % off nominal on K_yy, which ≤ 10° tilts barely tell from bias y."""
    rng = np.random.default_rng(21)
    k = (np.eye(3) + np.diag([0.03, -0.12, 0.04]) + rng.uniform(-0.004, 0.004, (3, 3))) / LSB
    base = Truth.random(rng, cross_axis_max=0.0, tilt_max_deg=0.3).to_dict()
    base["accel"]["K"] = k.tolist()
    return Truth.from_dict(base)


def test_a_vehicle_session_holds_k_at_the_value_the_device_holds(tmp_path: Path) -> None:
    truth = _truth()
    k_true = np.asarray(truth.accel.K)
    factory = k_true * (1 + np.random.default_rng(4).normal(0.0, 0.003, (3, 3)))
    state = state_file(tmp_path / "node.json", np.linalg.inv(factory))
    settings = DeviceSettings(
        node_ids=(NODE,), sim=SimSettings((truth,), state=state, time_scale=30.0, seed=5)
    )
    plan = builtin_plan("vehicle")
    with open_devices(settings) as rig:
        client = rig.clients[NODE]
        before = client.read_calibration_block()
        held = np.linalg.inv(before.block.accel_correction)
        session = rig.session(
            plan,
            tmp_path / "out",
            plan_name="vehicle",
            warmup=False,
            averaging=AveragingPolicy(fixed_s=3.0),
            verify_seconds=2.0,
        )
        run_automatic(session, write_anyway=True)
        averages = [session.procedure.accepted[NODE][i] for i in range(len(plan.positions))]
        site = session.procedure.config.site
    record = read_calibration(tmp_path / "out" / "calibration.json")
    priors = {p.name: p for p in record.priors or ()}
    assert len(priors) == 9
    for i in range(3):
        for j in range(3):
            prior = priors[f"accel.K[{i}][{j}]"]
            assert prior.mean == pytest.approx(held[i, j], rel=1e-12, abs=1e-12)
            assert prior.sigma == pytest.approx(0.01 / LSB)
            assert "0x2101" in prior.source and "vehicle plan's default" in prior.source
    assert "0x2101" in (tmp_path / "out" / "certificate.md").read_text()
    replayed = calibrate(read_recording(tmp_path / "out" / "recording.csv"))  # as solve
    assert replayed.priors == record.priors
    recording = read_recording(tmp_path / "out" / "recording.csv")
    wider = solve_recording(recording, ModelChoice(prior_k_sigma=0.02)).record.priors or ()
    assert {p.mean for p in wider} == {p.mean for p in priors.values()}
    assert all(p.sigma == pytest.approx(0.02 / LSB) for p in wider)
    assert all("0x2101" in p.source and "--prior-k-sigma" in p.source for p in wider)
    k_est = np.array(record.accel.K, dtype=float)
    k_sigma = np.array(record.accel.K_sigma, dtype=float)
    assert np.all(np.abs(k_est - k_true) < 3 * k_sigma), (k_est - k_true) / k_sigma
    b_est, b_sigma = np.array(record.accel.bias), np.array(record.accel.bias_sigma)
    b_true = np.asarray(truth.accel.bias)
    assert np.all(np.abs(b_est - b_true) < 3 * b_sigma), (b_est - b_true) / b_sigma
    # the nominal K at the same σ puts K_yy and bias y 6 σ off: the device's value matters
    spec = session.procedure.config.spec
    nominal = solve_positions(
        averages, spec, site, record.device, prior=plan_prior(plan, spec, site.accel_lsb)
    )
    k_nominal = np.array(nominal.record.accel.K, dtype=float)
    b_nominal = np.array(nominal.record.accel.bias, dtype=float)
    assert abs(k_nominal[1, 1] - k_true[1, 1]) > 4 * k_sigma[1, 1]
    assert abs(b_nominal[1] - b_true[1]) > 4 * b_sigma[1]


def test_a_session_refuses_a_device_whose_correction_is_singular(tmp_path: Path) -> None:
    m = np.array([[LSB, 0, 0], [LSB, 0, 0], [0, 0, LSB]])
    state = state_file(tmp_path / "node.json", m)
    settings = DeviceSettings(node_ids=(NODE,), sim=SimSettings((_truth(),), state=state))
    with open_devices(settings) as rig, pytest.raises(DeviceError, match="singular"):
        rig.session(builtin_plan("vehicle"), tmp_path / "out", plan_name="vehicle")
    assert not (tmp_path / "out" / "calibration.json").exists()


def test_a_resumed_session_keeps_the_prior_its_recording_holds(tmp_path: Path) -> None:
    truth, out, plan = _truth(), tmp_path / "out", builtin_plan("vehicle")
    factory = np.asarray(truth.accel.K) * 1.002
    first_state = state_file(tmp_path / "first.json", np.linalg.inv(factory))
    with open_devices(
        DeviceSettings(
            node_ids=(NODE,), sim=SimSettings((truth,), state=first_state, time_scale=30.0, seed=5)
        )
    ) as rig:
        held = np.linalg.inv(rig.clients[NODE].read_calibration_block().block.accel_correction)
        session = rig.session(
            plan, out, plan_name="vehicle", warmup=False, averaging=AveragingPolicy(fixed_s=1.0)
        )
        confirm, calls = session.confirm_pose, []

        def confirm_then_quit() -> list[object]:
            calls.append(1)
            if len(calls) > 2:
                raise KeyboardInterrupt  # the operator leaves after two positions
            return confirm()  # type: ignore[return-value]

        session.confirm_pose = confirm_then_quit  # type: ignore[method-assign,assignment]
        with pytest.raises(KeyboardInterrupt):
            run_automatic(session)
    # the unit comes back with another calibration: the session goes on with the first prior
    other = state_file(tmp_path / "other.json", np.eye(3) * LSB * 1.01)
    with open_devices(
        DeviceSettings(
            node_ids=(NODE,), sim=SimSettings((truth,), state=other, time_scale=30.0, seed=6)
        )
    ) as rig:
        resumed = rig.session(plan, out, plan_name="vehicle", resume=True, warmup=False)
        kept = resumed.procedure.config.k_priors[NODE]
        resumed.finish()
    assert kept.mean is not None and np.array_equal(kept.mean, held)
    assert kept.mean_source.startswith("K = M⁻¹ read from node 16")


def test_a_prior_k_header_needs_nine_finite_numbers() -> None:
    assert normalise_header({"prior_k": "1 0 0 0 1 0 0 0 1"})["prior_k"] == "1 0 0 0 1 0 0 0 1"
    for bad in ("1 0 0 0 1 0 0 0", "1 0 0 0 nan 0 0 0 1", "1 0 0 0 x 0 0 0 1"):
        with pytest.raises(InputError, match="prior_k"):
            normalise_header({"prior_k": bad})
