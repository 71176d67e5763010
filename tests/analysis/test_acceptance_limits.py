"""acceptance.toml: top-level limits for every calibration, ``[plan.NAME]`` for one plan's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.acceptance import AcceptanceLimits, acceptance_config_path, load_limits
from canimucal.errors import InputError
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.runtime.wiring import demo_settings, open_devices
from canimucal.sim.truth import Truth

VEHICLE_LIMITS = """\
max_bias_sigma_mg = 4.0

[plan.vehicle]
max_bias_sigma_mg = 15.0
max_scale_sigma_ppm = 12000

[plan.five]
min_fit_p = 0.001
"""


def _write(text: str) -> Path:
    path = acceptance_config_path()  # under the tests' own XDG_CONFIG_HOME (conftest)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def test_a_plan_table_overrides_the_top_level_limits_for_that_plan_only() -> None:
    _write(VEHICLE_LIMITS)
    default = AcceptanceLimits()
    vehicle = load_limits(plan="vehicle")
    assert (vehicle.max_bias_sigma_mg, vehicle.max_scale_sigma_ppm) == (15.0, 12000.0)
    assert vehicle.max_rms_ms2 == default.max_rms_ms2  # keys it does not name: defaults
    for plan in ("recommended", None):
        other = load_limits(plan=plan)
        assert other.max_bias_sigma_mg == 4.0  # the top level
        assert other.max_scale_sigma_ppm == default.max_scale_sigma_ppm
    assert load_limits(plan="five").min_fit_p == 0.001


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[plan.vehicle]\nmax_bias = 3\n", "unknown key 'plan.vehicle.max_bias'"),
        ("[plan.two]\nmax_rms_ms2 = -1\n", "plan.two.max_rms_ms2 must be a positive number"),
        ("plan = 3\n", "'plan' must hold tables [plan.NAME] of limits"),
        ("[plan]\nvehicle = 2\n", "'plan' must hold tables [plan.NAME] of limits"),
    ],
)
def test_a_bad_plan_table_is_refused_whichever_plan_runs(text: str, message: str) -> None:
    path = _write(text)
    with pytest.raises(InputError) as info:
        load_limits(plan="recommended")
    assert str(info.value).startswith(f"{path}: ") and message in str(info.value)


def test_a_session_judges_against_the_users_limits_for_its_plan(tmp_path: Path) -> None:
    _write(VEHICLE_LIMITS)
    truth = Truth.random(np.random.default_rng(8), cross_axis_max=0.0, tilt_max_deg=0.0)
    with open_devices(demo_settings([truth], time_scale=30.0, seed=3)) as rig:
        for name, bias_limit in (("vehicle", 15.0), ("recommended", 4.0)):
            session = rig.session(builtin_plan(name), tmp_path / name, plan_name=name)
            assert session.procedure.config.limits.max_bias_sigma_mg == bias_limit
            session.finish()
