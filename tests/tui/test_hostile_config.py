"""The TUI with a twin node: two devices answering as node 16 are an error modal.

(A hostile acceptance.toml never reaches the TUI: the shell reads the user's limits before
the app starts and refuses them in one line, tests/cli/test_hostile_input.py.)
"""

from __future__ import annotations

from pathlib import Path

import pytest

from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.modals import ErrorModal
from canimucal.tui.source import demo_source
from tests.support.pilot_steps import press, until

SIZE = (80, 24)
SEED = 20261127


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
