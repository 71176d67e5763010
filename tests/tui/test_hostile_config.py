"""The TUI with a hostile acceptance.toml or a twin node (issue 25, items 3 and 8).

The session opens on the position screen's worker, where the acceptance limits are read: a
5001-digit integer or arrays nested 5000 deep made the TUI die with a full-screen traceback.
Now the one-line error is shown in the error modal and the app stays up; likewise two
devices answering as node 16 on the connection screen.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.modals import ErrorModal
from canimucal.tui.position import PositionScreen
from canimucal.tui.source import demo_source
from tests.support.pilot_steps import press, until

SIZE = (80, 24)
SEED = 20261127


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("max_bias_sigma_mg = " + "9" * 5001 + "\n", "more than 4300 digits"),
        ("x = " + "[" * 5000 + "]" * 5000 + "\n", "nested"),
    ],
    ids=["huge-integer", "deep-arrays"],
)
async def test_a_hostile_acceptance_toml_is_an_error_modal_not_a_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, text: str, fragment: str
) -> None:
    config = tmp_path / "config" / "canimucal"
    config.mkdir(parents=True)
    (config / "acceptance.toml").write_text(text)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0)
    source = demo_source([truth], tmp_path / "out", time_scale=20.0, seed=SEED, seconds=5.0)
    app = make_app(source, plan_name="two")
    async with app.run_test(size=SIZE) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        await press(pilot, "enter")  # plan two -> position: the session opens, and fails
        await until(pilot, lambda: isinstance(app.screen, ErrorModal), "the error modal")
        modal = app.screen
        assert isinstance(modal, ErrorModal)
        assert "acceptance.toml" in modal.message and fragment in modal.message
        assert "\n" not in modal.message
        await press(pilot, "enter")
        await until(pilot, lambda: isinstance(app.screen, PositionScreen), "the screen again")
        await press(pilot, "q")
    assert app.return_code in (0, 130)


@pytest.mark.asyncio
async def test_two_devices_as_node_16_are_an_error_modal(tmp_path: Path) -> None:
    truth = Truth.from_dict({"serial": 4242, "faults": {"twin_serial": 5555}})
    source = demo_source([truth], tmp_path / "out", time_scale=20.0, seed=SEED, seconds=5.0)
    app = make_app(source, plan_name="two")
    async with app.run_test(size=SIZE) as pilot:
        await until(pilot, lambda: isinstance(app.screen, ErrorModal), "the error modal")
        modal = app.screen
        assert isinstance(modal, ErrorModal)
        assert modal.message == (
            "two devices answer as node 16 (serials 4242 and 5555): nothing read, the session "
            "does not start"
        )
        await press(pilot, "enter")
        await press(pilot, "q")
