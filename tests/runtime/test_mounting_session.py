"""The wiring path words a session's instructions through the unit's mounting map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.errors import InputError
from canimucal.io.mounting import load_mounting, save_mounting
from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.runtime.wiring import demo_settings, instruction_mounting, open_devices
from canimucal.sim.truth import Truth

TURNED = MountingMap.parse("x=left,y=down,z=back")


def test_the_vehicle_plan_is_worded_for_the_vehicle_other_plans_only_when_asked() -> None:
    mounting, note = instruction_mounting("vehicle", 77, None, False)
    assert mounting == DEFAULT_MOUNTING and "no mounting map saved for serial 77" in note
    assert instruction_mounting("recommended", 77, None, False) == (None, "")
    assert instruction_mounting("recommended", 77, TURNED, False)[0] == TURNED
    assert instruction_mounting("vehicle", 77, "body", False)[0] is None
    assert load_mounting(77) == TURNED  # asked once, saved for the serial


def test_a_session_loads_the_map_saved_for_its_unit_and_words_the_first_pose(
    tmp_path: Path,
) -> None:
    truth = Truth.random(np.random.default_rng(8), cross_axis_max=0.0, tilt_max_deg=0.0)
    with open_devices(demo_settings([truth], time_scale=30.0, seed=3)) as rig:
        serial = rig.identities()[0x10].serial
        save_mounting(serial, TURNED)
        plan = builtin_plan("vehicle")
        session = rig.session(plan, tmp_path, plan_name="vehicle", warmup=False)
        config = session.procedure.config
        assert config.mounting == TURNED and f"serial {serial}" in config.mounting_note
        assert session.facts(0x10).mounting == config.mounting_note  # the certificate's line
        events = session.procedure.start()
        session.finish()
    first = next(e for e in events if isinstance(e, ev.PoseInstructed))
    assert (
        first.words
        == "park the vehicle level at the start heading,\nthen mark where its tyres stand"
    )
    with pytest.raises(InputError, match="mirror image"):
        instruction_mounting("vehicle", serial, "x=forward,y=left,z=down", False)
