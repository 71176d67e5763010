"""The registries of the vocabularies: plans, effects, parameter units, node constants."""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.device import objects
from canimucal.errors import ModelError
from canimucal.model.layout import JointSpec, ParameterLayout
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, STANDARD_GRAVITY
from canimucal.model.vocabulary.constants import COUNTER_MODULUS, OUTPUT_DATA_RATES_HZ
from canimucal.model.vocabulary.effects import EFFECTS, Effect, PoseInputs, column_effects
from canimucal.model.vocabulary.plans import (
    PLANS,
    PlanEntry,
    builtin_names,
    builtin_plan,
    plan_help,
    plan_named_by,
    plan_of_poses,
)
from canimucal.model.vocabulary.units import QUANTITIES, Scales, quantity_of, words

ONE = Plan("one", (PlannedPosition(0.0, 0.0),))


def test_the_plans_in_the_order_they_are_offered() -> None:
    assert list(PLANS) == ["two", "five", "recommended", "vehicle", "custom", "scalar"]
    assert builtin_names() == ("two", "five", "recommended", "vehicle")
    assert plan_help() == "two, five, recommended, vehicle or a plan file"
    codes = {name: entry.device_code for name, entry in PLANS.items()}
    assert codes == {"two": 1, "five": 2, "recommended": 3, "custom": 4, "scalar": 5, "vehicle": 6}
    assert [plan_named_by(c) for c in (0, 3, 99)] == [None, "recommended", None]
    with pytest.raises(ModelError, match="built-in plans: two, five"):
        builtin_plan("custom")


def test_a_plan_entry_refuses_what_would_clash() -> None:
    with pytest.raises(ModelError, match="device code 3 is 'recommended'"):
        PLANS.register(PlanEntry("one", ONE, 3, "clashes"))
    with pytest.raises(ModelError, match="TUI key 'r' is 'recommended'"):
        PLANS.register(PlanEntry("one", ONE, 9, "clashes", tui_key="r"))
    with pytest.raises(ModelError, match="already registered"):
        PLANS.register(PLANS["five"])
    with pytest.raises(ModelError, match="holds the plan 'one'"):
        PlanEntry("uno", ONE, 9, "misnamed")
    with pytest.raises(ModelError, match="device code must be 1..255"):
        PlanEntry("one", ONE, 0, "code 0 is the factory's")
    assert "one" not in PLANS


def test_a_registered_plan_is_seen_while_it_is_registered() -> None:
    with PLANS.added(PlanEntry("one", ONE, 9, "one pose")):
        assert builtin_names()[-1] == "one" and builtin_plan("one") is ONE
        assert plan_of_poses([[0.0, 0.0, 0.0]], 1e-6) == "one"
    assert "one" not in PLANS and plan_of_poses([[0.0, 0.0, 0.0]], 1e-6) is None


def test_plan_poses_are_recognised_in_order_only() -> None:
    five = np.array([p.angles for p in builtin_plan("five").positions])
    assert plan_of_poses(five + np.deg2rad(0.01), np.deg2rad(0.05)) == "five"
    assert plan_of_poses(five[::-1], np.deg2rad(0.05)) is None


def _inputs(channels: int, temperatures: bool = True) -> PoseInputs:
    angles = np.deg2rad([[0, 0, 0], [45, 45, 0], [45, 45, 90], [22.5, 2.5, 180]])
    return PoseInputs.at(
        angles, g=STANDARD_GRAVITY, k_matrix=np.eye(3) / DEFAULT_ACCEL_LSB,
        s_matrix=np.eye(3) / DEFAULT_GYRO_LSB, w_level=np.array([0.0, 5e-5, 4e-5]),
        channels=channels, temperatures=np.array([0.0, 1.0, 2.0, 3.0]) if temperatures else None,
    )  # fmt: skip


@pytest.mark.parametrize("channels", [3, 6])
def test_every_column_builder_gives_a_column_per_label(channels: int) -> None:
    inputs = _inputs(channels)
    for effect in column_effects():
        for sensor in effect.sensors:
            assert effect.known is not None
            cols = effect.known(inputs, sensor)
            if cols is None:  # gyro-only effects on an accelerometer-only fit
                assert channels == 3 and "gyro" in (sensor, *effect.sensors)
                continue
            assert cols.shape == (4, channels, len(effect.labels)), effect.name
            assert np.all(np.isfinite(cols)) and np.any(cols), effect.name


def test_the_temperature_columns_need_temperatures() -> None:
    known = EFFECTS["temperature_bias"].known
    assert known is not None and known(_inputs(6, temperatures=False), "accel") is None


def test_an_effect_names_where_the_simulator_holds_each_entry() -> None:
    assert EFFECTS["cross_axis"].truth_path("accel", 2) == "accel.K[1][0]"
    assert EFFECTS["temperature_bias"].truth_path("gyro", 1) == "gyro.temp_coeff[1]"
    assert EFFECTS["base_tilt"].truth_path("accel", 1) == "base_tilt_deg.beta0"
    assert EFFECTS["base_tilt"].truth_per_unit == pytest.approx(180.0 / np.pi)
    new = Effect(
        "new", ("gyro",), "a new one", "counts", labels=("a", "b"), known=lambda x, s: None
    )
    assert new.generic_truth and new.truth_path("gyro", 1) == "effects.gyro.new[1]"
    with pytest.raises(ModelError, match="a label per entry"):
        Effect("bad", ("accel",), "no labels", "counts", known=lambda x, s: None)
    with pytest.raises(ModelError, match="sensors"):
        Effect("bad", ("magnetometer",), "no", "counts")  # type: ignore[arg-type]


def test_every_parameter_has_a_quantity_with_its_units() -> None:
    spec = JointSpec(
        accel_k="full", tilt="rigid", gyro="nav", gyro_s="full", gyro_g=True, trim=True
    )
    families = {quantity_of(name).family for name in ParameterLayout.of(spec).names}
    assert families == set(QUANTITIES)
    assert quantity_of("mounting_trim.psi").shown_unit == "deg"
    assert quantity_of("gyro.S[2][1]").unit == "counts/(rad/s)"
    assert quantity_of("base_tilt.alpha0").shown_unit == "deg"
    assert words("counts/(m/s²)") == "counts per m/s²" and words("rad") == "rad"
    with pytest.raises(ModelError, match="unknown parameter family"):
        quantity_of("mag.bias[0]")


def test_operator_units_of_one_count_and_one_radian() -> None:
    scales = Scales(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, STANDARD_GRAVITY)
    assert QUANTITIES["accel.bias"].operator(1.0, scales) == pytest.approx(1000.0 / 2048.0)  # mg
    assert QUANTITIES["accel.K"].operator(1.0, scales) == pytest.approx(1e6 / 2048.0 * 9.80665)
    assert QUANTITIES["accel.bias"].si(2048.0, scales) == pytest.approx(STANDARD_GRAVITY)
    assert QUANTITIES["gyro.bias"].operator(16.4, scales) == pytest.approx(1.0)  # °/s
    assert QUANTITIES["base_tilt"].operator(np.pi, scales) == pytest.approx(180.0)


def test_node_constants_agree_with_the_object_table() -> None:
    counter = objects.BY_KEY[(objects.SAMPLE_INFO, 2)]
    assert counter.data_type == "u16" and COUNTER_MODULUS == 0xFFFF + 1
    assert str(COUNTER_MODULUS) in counter.name
    rate = objects.BY_KEY[(objects.NOMINAL, 3)]
    ctx = objects.RangeContext(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB)
    assert [rate.problem(r, ctx) for r in OUTPUT_DATA_RATES_HZ] == [None] * 6
    assert rate.problem(300, ctx) is not None


def test_a_new_plans_device_code_passes_the_range_check() -> None:
    code = objects.BY_KEY[(objects.CAL_INFO, objects.CAL_PLAN_SUB)]
    ctx = objects.RangeContext(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB)
    assert code.problem(9, ctx) is not None
    with PLANS.added(PlanEntry("one", ONE, 9, "one pose")):
        assert code.problem(9, ctx) is None
