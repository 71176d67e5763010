"""acceptance.toml: top-level limits for every calibration, ``[plan.NAME]`` for one plan's.

The file is read by the shells and passed in; a session given a config judges each plan by
its own table. That the library never reads the user's file is shown in
tests/cli/test_public_api.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.acceptance import (
    AcceptanceConfig,
    AcceptanceLimits,
    limits_for,
    read_acceptance_config,
)
from canimucal.errors import InputError
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.truth import Truth
from canimucal.tui.source import demo_source
from tests.support.user_dirs import UserDirs

VEHICLE_LIMITS = """\
max_bias_sigma_mg = 4.0

[plan.vehicle]
max_bias_sigma_mg = 15.0
max_scale_sigma_ppm = 12000

[plan.five]
min_fit_p = 0.001
"""


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_a_plan_table_overrides_the_top_level_limits_for_that_plan_only(tmp_path: Path) -> None:
    config = read_acceptance_config(_write(tmp_path / "acceptance.toml", VEHICLE_LIMITS))
    default = AcceptanceLimits()
    vehicle = config.limits("vehicle")
    assert (vehicle.max_bias_sigma_mg, vehicle.max_scale_sigma_ppm) == (15.0, 12000.0)
    assert vehicle.max_rms_ms2 == 0.1  # keys it does not name: the vehicle plan's own
    for plan in ("recommended", None):
        other = config.limits(plan)
        assert other.max_bias_sigma_mg == 4.0  # the top level
        assert other.max_scale_sigma_ppm == default.max_scale_sigma_ppm
    assert config.limits("five").min_fit_p == 0.001
    assert limits_for(config, "vehicle") == vehicle and limits_for(vehicle, "five") == vehicle
    assert limits_for(None, "five") == default  # nothing given: the built-in limits
    own = AcceptanceLimits(max_bias_sigma_mg=15.0, max_scale_sigma_ppm=10000.0, max_rms_ms2=0.1)
    assert limits_for(None, "vehicle") == own  # with the vehicle plan's own (design §3)


def test_a_byte_order_mark_is_skipped(tmp_path: Path) -> None:
    path = tmp_path / "acceptance.toml"
    path.write_bytes(b"\xef\xbb\xbf" + VEHICLE_LIMITS.encode())
    assert read_acceptance_config(path).limits("vehicle").max_bias_sigma_mg == 15.0


def test_no_file_is_the_built_in_limits(tmp_path: Path) -> None:
    config = read_acceptance_config(tmp_path / "absent.toml")
    assert config == AcceptanceConfig() and config.limits("five") == AcceptanceLimits()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[plan.vehicle]\nmax_bias = 3\n", "unknown key 'plan.vehicle.max_bias'"),
        ("[plan.two]\nmax_rms_ms2 = -1\n", "plan.two.max_rms_ms2 must be a positive number"),
        ("plan = 3\n", "'plan' must hold tables [plan.NAME] of limits"),
        ("[plan]\nvehicle = 2\n", "'plan' must hold tables [plan.NAME] of limits"),
    ],
)
def test_a_bad_plan_table_is_refused_whichever_plan_runs(
    tmp_path: Path, text: str, message: str
) -> None:
    path = _write(tmp_path / "acceptance.toml", text)
    with pytest.raises(InputError) as info:
        read_acceptance_config(path)
    assert str(info.value).startswith(f"{path}: ") and message in str(info.value)


def test_a_session_judges_against_the_limits_of_its_plan(
    tmp_path: Path, own_user_dirs: UserDirs
) -> None:
    own_user_dirs.write_acceptance("max_bias_sigma_mg = 0.5\n")  # never read by a session
    config = read_acceptance_config(_write(tmp_path / "acceptance.toml", VEHICLE_LIMITS))
    truth = Truth.random(np.random.default_rng(8), cross_axis_max=0.0, tilt_max_deg=0.0)
    source = demo_source([truth], tmp_path / "out", time_scale=30.0, seed=3)
    source.acceptance = config
    try:
        for name, bias_limit in (("vehicle", 15.0), ("recommended", 4.0)):
            session = source.open(builtin_plan(name), name, "mems")
            assert session.procedure.config.limits.max_bias_sigma_mg == bias_limit
            session.finish()
        assert source.devices is not None
        session = source.devices.session(builtin_plan("two"), tmp_path / "two", plan_name="two")
        assert session.procedure.config.limits == AcceptanceLimits()  # none given: built-in
        session.finish()
    finally:
        source.close()
