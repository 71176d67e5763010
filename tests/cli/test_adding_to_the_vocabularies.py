"""How to add a plan and a candidate effect: one registration each, and the tool knows them.

A plan is one :class:`PlanEntry` in ``PLANS`` (``canimucal/model/vocabulary/plans.py``): its
positions with their tolerances and seconds, the model they determine, its device code
(0x2121:02), its key on the TUI's plan screen and a line of description. An effect is one
:class:`Effect` in ``EFFECTS`` (``canimucal/model/vocabulary/effects.py``): its sensors,
wording, unit, the labels of its entries and its model columns, a pure numpy function of the
poses. The fixtures below register a plan ``tumble`` and an effect ``cross_product`` for one
test each, and nothing else in the code base changes: ``plan``, ``solve``, ``analyze`` and
``demo``, the TUI's plan screen, the simulator (its truth and its recordings), the device
write, the certificate and the JSON outputs all know them.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from canimucal.analysis.discrepancy import effect_sigmas
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.io.recording_writer import write_recording
from canimucal.io.truth import write_truth
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.vocabulary.effects import EFFECTS, Effect, PoseInputs, Sensor, per_channel
from canimucal.model.vocabulary.plans import PLANS, PlanEntry
from canimucal.sim.effects import hide_effect
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.screens.plan import PlanScreen
from tests.support.sessions import simulate_session
from tests.support.tui_fakes import FakeSource, node_status, screen_text

Cli = Callable[[Sequence[Any]], Any]  # the ``cli`` fixture of tests/cli/conftest.py
SERIAL = 777
TRUTH_SEED = 20_260_007
NOISE_SEED = 11


def _tumble() -> Plan:
    """Two stands, level and a 30° double wedge, the unit turned by 0/90/180/270° on each."""
    poses = []
    for psi in (0, 90, 180, 270):
        stands = [(0, 0), (30, 30)] if psi in (0, 180) else [(30, 30), (0, 0)]
        poses += [(a, b, psi) for a, b in stands]
    return Plan(
        "tumble",
        tuple(PlannedPosition(*np.deg2rad(p).tolist(), seconds=20.0) for p in poses),
    )


TUMBLE = PlanEntry(
    "tumble", _tumble(), device_code=7, tui_key="t", accel_k="full", tilt="rigid",
    description="a level stand and a 30° wedge, each turned four ways",
    # its own defaults over the built-in 5 mg and 3000 ppm: its y axis is never turned to
    # face gravity, so y's bias and scale are barely apart (correlation ≈ 1)
    acceptance={"max_bias_sigma_mg": 8.0, "max_scale_sigma_ppm": 6000.0},
)  # fmt: skip


def _cross_product(inputs: PoseInputs, sensor: Sensor) -> NDArray[np.float64]:
    """Each accelerometer axis sees the product of the other two axes' specific force."""
    f = inputs.f
    return per_channel(
        inputs, [(0, f[:, 1] * f[:, 2]), (1, f[:, 0] * f[:, 2]), (2, f[:, 0] * f[:, 1])]
    )


CROSS_PRODUCT = Effect(
    "cross_product", ("accel",), "each axis sees the product of the other two",
    "counts per (m/s²)²", labels=("yz[0]", "xz[1]", "xy[2]"), known=_cross_product,
)  # fmt: skip


@pytest.fixture
def tumble() -> Iterator[PlanEntry]:
    """The plan ``tumble``, registered for one test."""
    with PLANS.added(TUMBLE) as entry:
        yield entry


@pytest.fixture
def cross_product() -> Iterator[Effect]:
    """The effect ``cross_product``, registered for one test."""
    with EFFECTS.added(CROSS_PRODUCT) as effect:
        yield effect


def _truth(**changes: Any) -> dict[str, Any]:
    doc = Truth.random(np.random.default_rng(TRUTH_SEED), cross_axis_max=0.0).to_dict()
    return {**doc, "serial": SERIAL, **changes}


def _recording(tmp_path: Path, truth: Truth, name: str) -> Path:
    rec = simulate_plan_recording(truth, TUMBLE.plan, seed=NOISE_SEED)  # type: ignore[arg-type]
    return write_recording(tmp_path / name, rec, overwrite=False)


def test_plan_bounds_and_compares_the_new_plan(
    cli: Cli, capsys: pytest.CaptureFixture[str], tumble: PlanEntry
) -> None:
    run = cli(["plan", "--plan", "tumble", "--json", "-"])
    assert run.code == 0, run.err
    document = json.loads(run.out)
    assert document["plan"] == "tumble" and document["description"] == tumble.description
    assert len(document["positions"]) == 8 and document["worst_case_counts"] is not None
    run = cli(["plan", "--compare", "--json", "-"])
    assert run.code == 0, run.err
    assert "tumble" in [p["plan"] for p in json.loads(run.out)["plans"]]
    with pytest.raises(SystemExit):
        cli(["plan", "--help"])
    assert "recommended, vehicle, tumble or a plan file" in " ".join(
        capsys.readouterr().out.split()
    )


@pytest.mark.asyncio
async def test_the_plan_screen_offers_the_new_plan_on_its_key(
    tmp_path: Path, tumble: PlanEntry
) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    assert "tumble" in app.plans
    async with app.run_test(size=(120, 30)) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans))
        await pilot.pause()
        assert "t Tumble" in screen_text(app).splitlines()[-1]
        await pilot.press("t")
        await pilot.pause()
        text = screen_text(app)
        assert "plan tumble: 8 positions" in text
        assert "position 1 120 s (it measures the noise), then at most 20 s each" in text


def test_a_recording_of_the_new_plan_is_solved_and_written_under_its_own_code(
    cli: Cli, tmp_path: Path, tumble: PlanEntry
) -> None:
    truth = Truth.from_dict(_truth())
    recording = _recording(tmp_path, truth, "tumble.csv")
    run = cli(["solve", recording, "--tilt", "--json", tmp_path / "cal.json"])
    assert run.code == 0, run.err
    assert run.out.startswith("plan tumble;")
    assert json.loads((tmp_path / "cal.json").read_text())["plan"] == "tumble"
    truth_file = write_truth(tmp_path / "truth.json", truth, overwrite=False)
    flags = ["--sim", "--truth", truth_file, "--state", tmp_path / "state.json"]
    run = cli(["write-params", tmp_path / "cal.json", *flags, "--backup-dir", tmp_path / "bk"])
    assert run.code == 0, run.err
    run = cli(["read-params", *flags, "--json", tmp_path / "read.json"])
    assert run.code == 0, run.err
    held = json.loads((tmp_path / "read.json").read_text())["calibration"]
    assert held["objects"]["0x2121:02"] == 7  # not 4, custom
    assert held["plan"] == "tumble"


def test_analyze_names_the_new_effect_and_writes_it_for_the_simulator(
    cli: Cli, tmp_path: Path, tumble: PlanEntry, cross_product: Effect
) -> None:
    clean = _truth()
    session = simulate_session(Truth.from_dict(clean), TUMBLE.plan, seed=1)  # type: ignore[arg-type]
    sigmas = effect_sigmas(session)
    assert np.isfinite(sigmas["accel.cross_product"]).sum() == 1  # xz on y: what the poses show
    doc, hidden = hide_effect(clean, "cross_product", np.random.default_rng(3), sigmas,
                              low=15.0, high=20.0)  # fmt: skip
    assert doc["effects"] == {"accel": {"cross_product": [0.0, hidden.size, 0.0]}}
    recording = _recording(tmp_path, Truth.from_dict(doc), "hidden.csv")
    out, truth_out = tmp_path / "analysis.json", tmp_path / "extended.json"
    run = cli(["analyze", recording, "--json", out, "--truth-out", truth_out])
    assert run.code == 0, run.err
    analysis = json.loads(out.read_text())
    (finding,) = [f for f in analysis["findings"] if f["effect"] == "cross_product"]
    assert finding["units"] == "counts per (m/s²)²"
    assert "cross_product" in analysis["sensors"]["accel"]["extended_model"]["terms"]
    assert "cross_product (accel)" in run.out
    match = re.search(r"xz\[1\] = (\S+) ± (\S+)", finding["evidence"])
    assert match is not None, finding["evidence"]
    value, sigma = float(match.group(1)), float(match.group(2))
    assert abs(value - hidden.size) < 4.0 * sigma, (value, hidden.size, sigma)
    extended = Truth.from_dict(json.loads(truth_out.read_text()))  # the simulator reads it back
    written = extended.effects["accel.cross_product"]  # refitted on the entries that stand out
    assert written[0] == written[2] == 0.0
    assert abs(written[1] - hidden.size) < 4.0 * sigma, (written[1], hidden.size, sigma)


def test_a_demo_session_of_the_new_plan_certifies_it(
    cli: Cli, tmp_path: Path, tumble: PlanEntry
) -> None:
    out = tmp_path / "demo-out"
    fast = ["--headless", "--seconds", "4", "--time-scale", "30", "--seed", "2031"]
    run = cli(["demo", *fast, "--plan", "tumble", "--out", out, "--json", tmp_path / "cal.json"])
    assert run.code == 0, run.err
    record = json.loads((tmp_path / "cal.json").read_text())
    assert record["plan"] == "tumble" and len(record["positions"]) == 8
    assert "accel.K[0][1]" in record["covariance"]["order"]  # the plan's model: full K
    assert record["readback"]["valid"] == 1 and record["readback"]["crc_ok"] is True
    assert record["acceptance"]["limits"]["max_bias_sigma_mg"] == 8.0
    for page in ("certificate.md", "certificate.html"):
        assert f"tumble ({tumble.description}), 8 positions" in (out / page).read_text()
