"""`canimucal tui`'s options, by parsing only: the TUI itself never starts here."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from canimucal.analysis.acceptance import AcceptanceConfig
from canimucal.cli.main import build_parser
from canimucal.cli.tui_cmd import device_source, plan_choice
from canimucal.errors import InputError
from canimucal.io.plans import plan_to_dict
from canimucal.model.mounting import MountingMap
from canimucal.model.vocabulary.plans import builtin_plan
from tests.support.user_dirs import UserDirs


def test_a_built_in_plan_keeps_its_name_and_a_file_is_custom(tmp_path: Path) -> None:
    plan, name = plan_choice("vehicle")
    assert name == "vehicle" and plan == builtin_plan("vehicle")
    assert plan_choice("two")[1] == "two"
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(plan_to_dict(builtin_plan("five"))))
    assert plan_choice(str(path))[1] == "custom"


def parse(*argv: str) -> Any:
    return build_parser("tui").parse_args(["tui", *argv])


def test_operator_site_and_seconds_go_to_the_source(tmp_path: Path) -> None:
    args = parse(
        "--sim", "--out", str(tmp_path), "--operator", "A. Tester", "--site", "Bay 3",
        "--seconds", "7.5", "--g", "9.81",
    )  # fmt: skip
    source = device_source(args)
    assert (source.operator, source.site_name, source.seconds) == ("A. Tester", "Bay 3", 7.5)
    assert source.devices is None and source.out_dir == tmp_path  # nothing opened yet
    plain = device_source(parse("--sim", "--g", "9.81"))
    assert (plain.operator, plain.site_name, plain.seconds) == (None, None, None)


@pytest.mark.parametrize("seconds", ["0", "-1", "nan"])
def test_seconds_must_be_positive(seconds: str) -> None:
    with pytest.raises(InputError, match="--seconds must be positive"):
        device_source(parse("--sim", "--g", "9.81", "--seconds", seconds))


def test_mount_goes_to_the_source_and_a_bad_map_is_refused_before_the_tui() -> None:
    source = device_source(parse("--sim", "--g", "9.81", "--mount", "x=left,y=down,z=back"))
    assert source.mount == MountingMap("left", "down", "back") and not source.replace_mount
    assert device_source(parse("--sim", "--g", "9.81", "--mount", "body")).mount == "body"
    assert device_source(parse("--sim", "--g", "9.81")).mount is None
    with pytest.raises(InputError, match="mirror image"):
        device_source(parse("--sim", "--g", "9.81", "--mount", "x=forward,y=left,z=down"))
    with pytest.raises(InputError, match="--replace-mount needs --mount"):
        device_source(parse("--sim", "--g", "9.81", "--replace-mount"))


def test_the_prior_on_k_flags_go_to_the_source_and_bad_ones_exit_2(tmp_path: Path) -> None:
    good = tmp_path / "factory.json"
    k = [[208.0, 0.5, 0.0], [0.0, 210.0, 0.0], [0.0, 0.0, 207.0]]
    head = {"schema": "canimucal.calibration/1", "device": {"serial": 1}}
    good.write_text(json.dumps({**head, "accel": {"bias": [0.0] * 3, "K": k}}))
    source = device_source(
        parse("--sim", "--g", "9.81", "--prior-k", str(good), "--prior-k-sigma", "0.02")
    )
    assert (source.prior_k, source.prior_k_sigma) == (str(good), 0.02)
    with pytest.raises(InputError, match="--prior-k-sigma must be > 0"):
        device_source(parse("--sim", "--g", "9.81", "--prior-k-sigma", "0"))
    partial = tmp_path / "partial.json"
    partial.write_text(json.dumps({**head, "accel": {"bias": [0.0] * 3, "K": [[None] * 3] * 3}}))
    with pytest.raises(InputError, match="partial.json"):
        device_source(parse("--sim", "--g", "9.81", "--prior-k", str(partial)))


def test_gyro_g_reaches_the_session_the_source_opens(tmp_path: Path) -> None:
    source = device_source(parse("--sim", "--g", "9.81", "--gyro-g", "--out", str(tmp_path)))
    assert source.gyro_g and not device_source(parse("--sim", "--g", "9.81")).gyro_g
    try:
        session = source.open(builtin_plan("five"), "five", "mems")
        assert session.procedure.config.spec.gyro_g
    finally:
        source.close()


def test_the_users_acceptance_limits_go_to_the_source(own_user_dirs: UserDirs) -> None:
    assert device_source(parse("--sim", "--g", "9.81")).acceptance == AcceptanceConfig()
    own_user_dirs.write_acceptance("max_rms_ms2 = 0.02\n[plan.vehicle]\nmax_bias_sigma_mg = 15\n")
    source = device_source(parse("--sim", "--g", "9.81"))
    assert source.acceptance.limits("vehicle").max_bias_sigma_mg == 15.0
    assert source.acceptance.limits("two").max_rms_ms2 == 0.02
    own_user_dirs.write_acceptance("max_rms = 1\n")
    with pytest.raises(InputError, match="unknown key 'max_rms'"):
        device_source(parse("--sim", "--g", "9.81"))  # before the TUI starts: exit 2


def test_without_site_flags_the_tui_asks_and_site_alone_is_refused() -> None:
    asked = device_source(parse("--sim"))
    assert asked.ask_site and asked.site is None and asked.last_site_file is not None
    told = device_source(parse("--sim", "--latitude-deg", "52"))
    assert not told.ask_site and told.site is not None and told.site.latitude is not None
    with pytest.raises(InputError, match="g is never assumed"):
        device_source(parse("--sim", "--site", "Bay 3"))
