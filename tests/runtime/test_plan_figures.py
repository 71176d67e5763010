"""One source for a plan's times and σ: the plan screen, ``plan``, the guide and a session agree.

Issue 22: the field guide said 60 s a position and about 32 minutes, the TUI averaged
120 s then 108 s each, and the same plan showed other σ in the TUI than in ``plan``. Every
figure now comes from :mod:`canimucal.runtime.plan_forecast` (the plan registry's seconds
under the session's averaging rule): these tests read each place that shows them and fail
when one drifts from that source. The certificate's copy is checked on every headless demo
(``tests/cli/test_demo_headless.py``).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.acceptance import AcceptanceConfig
from canimucal.cli.main import main
from canimucal.model.layout import JointSpec
from canimucal.model.sensor import DEFAULT_ACCEL_LSB
from canimucal.model.vocabulary.plans import builtin_names, builtin_plan
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.runtime.plan_forecast import (
    field_guide_pages,
    forecast,
    forecast_lines,
    plan_bounds,
    schedule,
    session_spec,
    table_cells,
    trim_forecast,
)
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.screens.plan import PlanScreen
from tests.support.procedure_bench import Bench, of
from tests.support.tui_fakes import FakeSource, node_status

DOCS = Path(__file__).resolve().parents[2] / "docs"
PLANS = builtin_names()


def _words(text: str) -> str:
    """Text with its line breaks and runs of spaces as single spaces (a wrapped screen)."""
    return " ".join(text.split())


def _plan_command(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    assert main(["plan", *argv]) == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("name", PLANS)
def test_plan_prints_the_sources_times_bounds_and_forecast(
    capsys: pytest.CaptureFixture[str], name: str
) -> None:
    plan, times = builtin_plan(name), schedule(builtin_plan(name))
    assert times.seconds[0] == max(120.0, plan.positions[0].seconds)  # it measures the noise
    assert times.seconds[1:] == tuple(p.seconds for p in plan.positions[1:])  # the registry's
    doc = json.loads(_plan_command(capsys, "--plan", name, "--json", "-"))
    assert doc["seconds_per_position"] == list(times.seconds)
    assert doc["total_seconds"] == times.total_seconds
    assert doc["operator_minutes"] == pytest.approx(times.operator_minutes, rel=1e-12)
    table = plan_bounds(plan, session_spec(name))
    assert [r["sigma"] for r in doc["parameters"]] == [r.sigma for r in table.rows]
    rows = forecast(plan, AcceptanceConfig().limits(name), session_spec(name))
    assert [r["predicted"] for r in doc["acceptance"]] == [r.predicted for r in rows]
    text = _plan_command(capsys, "--plan", name)
    assert text.startswith(f"plan {name}: {times.totals_words()}\n")
    assert f"times: {times.times_words()}" in _words(text)
    trim = trim_forecast(plan, session_spec(name))
    for line in forecast_lines(rows, name, trim=trim):
        assert line in text


def test_the_field_guide_states_the_sources_times_and_sigma() -> None:
    guide = (DOCS / "field-guide.md").read_text(encoding="utf-8")
    assert guide == field_guide_pages()[0]  # and it is what the generator writes
    for name in PLANS:
        plan, times = builtin_plan(name), schedule(builtin_plan(name))
        section = guide.split(f"\n## {name}\n", 1)[1].split("\n## ", 1)[0]
        assert (
            f"{len(plan.positions)} positions, {times.total_seconds:g} s of averaging, about "
            f"{times.operator_minutes:.0f} minutes of the operator's time" in section
        )
        assert f"Times: {times.times_words()}." in section
        seconds = [float(s) for s in re.findall(r"; ([0-9.]+) s; ±", section)]
        assert seconds == list(times.seconds)
        rows = forecast(plan, AcceptanceConfig().limits(name), session_spec(name))
        for r in rows:
            if r.predicted is not None:
                assert r.line() in section


@pytest.mark.asyncio
async def test_the_plan_screen_shows_the_sources_times_bounds_and_forecast(
    tmp_path: Path,
) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=(100, 40)) as pilot:
        screen = PlanScreen([node_status()], app.plans)
        await app.push_screen(screen)
        for name in PLANS:
            screen.action_plan(name)
            await pilot.pause()
            plan, times = builtin_plan(name), schedule(builtin_plan(name))
            assert f"times: {times.words()}" in _words(str(screen.summary.render()))
            table = plan_bounds(plan, session_spec(name), accel_lsb=DEFAULT_ACCEL_LSB)
            shown = [
                tuple(str(c) for c in screen.table.get_row_at(i))
                for i in range(screen.table.row_count)
            ]
            assert shown == table_cells(table)
            rows = forecast(plan, AcceptanceConfig().limits(name), session_spec(name))
            trim = trim_forecast(plan, session_spec(name), accel_lsb=DEFAULT_ACCEL_LSB)
            lines = forecast_lines(rows, name, trim=trim)
            assert str(screen.forecast.render()) == "\n".join(lines)


def test_the_session_averages_each_position_as_the_schedule_says() -> None:
    """The position screen's "average N s once still" is the procedure's time: the schedule's.

    The first position's time is the schedule's; the later ones are the plan's seconds,
    shortened only as far as the first position's noise chose (white noise fitted on 120 s
    sometimes shows a little walk), never longer: "at most" on the plan screen.
    """
    truth = Truth.random(np.random.default_rng(3), cross_axis_max=0.0)
    plan = builtin_plan("two")
    spec = JointSpec(accel_k="diag", tilt="none", gyro="mems")
    bench = Bench([truth], plan, averaging=AveragingPolicy(), spec=spec)
    instructed = of(bench.events, ev.PoseInstructed)
    bench.position()
    accepted = bench.do("accept")
    instructed += of(accepted, ev.PoseInstructed)
    chosen = of(accepted, ev.AveragingTimeChosen)[0]
    times = schedule(plan).seconds
    assert chosen.source == "noise" and instructed[0].seconds == times[0]
    assert instructed[1].seconds == min(chosen.seconds, times[1]) <= times[1]
