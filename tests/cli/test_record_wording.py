"""``record --plan`` words each pose for the vehicle as the TUI does (issue 22 item 6).

The vehicle plan (or any plan with ``--mount``) is prompted through the unit's mounting map;
``--wheelbase``/``--track`` word its tilts as heights and are saved with the map for the
unit's serial, so the next recording of that unit words them alike without the flags.
"""

from __future__ import annotations

import argparse
import io

import numpy as np
import pytest

from canimucal.cli.record_cmd import _prompter, _wording
from canimucal.device.client import Identity
from canimucal.io.mounting import load_mounting, load_vehicle_size
from canimucal.model.mounting import DEFAULT_MOUNTING
from canimucal.model.vehicle_size import VehicleSize
from canimucal.model.vocabulary.plans import builtin_plan
from tests.support.user_dirs import UserDirs

SERIAL = 4711


class _Unit:
    """The one call ``_wording`` makes of the open devices: each node's identity."""

    def identities(self) -> dict[int, Identity]:
        return {0x10: Identity(1, 2, 3, SERIAL, "imu")}


def _args(**flags: object) -> argparse.Namespace:
    return argparse.Namespace(**{"mount": None, "wheelbase": None, "track": None, **flags})


def _prompts(plan: str, args: argparse.Namespace, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    prompt = _prompter(*_wording(args, _Unit(), builtin_plan(plan)))  # type: ignore[arg-type]
    shown = []
    for index, position in enumerate(builtin_plan(plan).positions):
        monkeypatch.setattr("sys.stdin", io.StringIO("\n"))  # the operator presses Enter
        out = io.StringIO()
        monkeypatch.setattr("sys.stdout", out)
        prompt(index, position)
        shown.append(out.getvalue().splitlines()[-1])
    return shown


def test_record_prompts_the_vehicle_plan_as_heights_and_tyre_marks(
    monkeypatch: pytest.MonkeyPatch, own_user_dirs: UserDirs
) -> None:
    rise, side = (f"{x * np.sin(np.deg2rad(10.0)):.2f}" for x in (3.5, 1.8))
    shown = _prompts("vehicle", _args(wheelbase=3.5, track=1.8), monkeypatch)
    assert shown[0].startswith("position 0: park the vehicle level at the start heading, then")
    assert "mark where its tyres stand (alpha 0 beta 0 psi 0 deg)" in shown[0]
    for line in shown[1:4]:  # the turns on the spot
        assert "then come back to the same tyre marks" in line, line
    assert f"raise the rear wheels {rise} m (10°) (alpha 10 beta 0 psi 0 deg)" in shown[4]
    assert f"raise the front wheels {rise} m (10°)" in shown[5]
    assert f"raise the left side {side} m (10°)" in shown[6]
    assert all(line.endswith("press Enter (60 s)") for line in shown)
    # saved with the unit's mounting: the next recording words it alike without the flags
    assert load_vehicle_size(SERIAL) == VehicleSize(3.5, 1.8)
    again = _prompts("vehicle", _args(), monkeypatch)
    assert again == shown


def test_a_bench_plan_is_prompted_in_angles_unless_a_mount_is_given(
    monkeypatch: pytest.MonkeyPatch, own_user_dirs: UserDirs
) -> None:
    bench = _prompts("two", _args(), monkeypatch)
    assert bench[1] == "position 1: put the unit at alpha 45 beta 5 psi 0 deg, press Enter (30 s)"
    mounted = _prompts("two", _args(mount=DEFAULT_MOUNTING.text()), monkeypatch)
    assert "raise the " in mounted[1] and "(alpha 45 beta 5 psi 0 deg)" in mounted[1]
    assert _prompts("vehicle", _args(mount="body"), monkeypatch)[4].startswith(
        "position 4: put the unit at alpha 10"
    )
    assert load_mounting(SERIAL) == DEFAULT_MOUNTING  # --mount is saved for the serial
