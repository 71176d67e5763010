"""The operator's units in ``solve`` and ``analyze`` (issue 22 item 6): mg, ppm, °, °/s.

Every value line of ``solve`` and every cell of ``analyze``'s estimates and residual table
carries its unit (:func:`tests.support.bare_numbers.bare_numbers` fails on a bare number),
the operator's value beside the device's converted by the units registry's factors at the
recording's LSBs and g. ``allan`` has its own check (``test_plan_allan.py``).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Sequence
from typing import Any

import pytest

from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.model.vocabulary.units import QUANTITIES, Scales
from canimucal.runtime.inputs import read_recording
from tests.support.bare_numbers import bare_numbers

Cli = Callable[[Sequence[Any]], Any]
PARAMETER = re.compile(r"^(accel|gyro)\.[A-Za-z]+(\[\d\])+|^base tilt (alpha0|beta0)|^gyro\.G")


def _scales(path: Any) -> Scales:
    header = read_recording(path).header
    return Scales(
        float(header.get("accel_lsb", DEFAULT_ACCEL_LSB)),
        float(header.get("gyro_lsb", DEFAULT_GYRO_LSB)),
        float(header["g"]),
    )


def test_solve_prints_each_value_in_the_devices_and_the_operators_units(
    cli: Cli, simulated: Callable[[str, str, float], Any]
) -> None:
    sim = simulated("five", "diag", 10.0)
    run = cli(["solve", sim.path, "--tilt", "--no-check"])
    assert run.code == 0, run.err
    lines = [x for x in run.out.splitlines() if PARAMETER.match(x)]
    assert len(lines) >= 8  # biases, diagonal K, tilt at least
    labels = [re.match(r"\S+( alpha0| beta0)?", x).group(0) for x in lines]  # type: ignore[union-attr]
    for line, label in zip(lines, labels, strict=True):
        assert not bare_numbers(line, labels=[label]), line
    doc = json.loads(cli(["solve", sim.path, "--tilt", "--no-check", "--json", "-"]).out)
    scales = _scales(sim.path)
    bias = next(x for x in lines if x.startswith("accel.bias[0]"))
    mg = QUANTITIES["accel.bias"].to_operator(scales) * doc["accel"]["bias"][0]
    assert re.search(rf"{mg:.4g} ± \S+ mg$", bias), bias
    scale = next(x for x in lines if x.startswith("accel.K[1][1]"))
    ppm = doc["accel"]["K"][1][1] * abs(scales.accel_lsb) * 1e6 - 1e6  # ppm from nominal
    assert float(re.findall(r"([-+0-9.e]+) ± \S+ ppm$", scale)[0]) == pytest.approx(ppm, abs=1.0)
    assert any(x.startswith("base tilt alpha0") and x.endswith("°") for x in lines)


def test_analyze_gives_its_estimates_and_residuals_in_mg_and_deg_per_s(
    cli: Cli, simulated: Callable[[str, str, float], Any]
) -> None:
    sim = simulated("recommended", "diag", 10.0)
    run = cli(["analyze", sim.path])
    assert run.code == 0, run.err
    text = run.out
    estimates = text.split("Base-model estimates:\n", 1)[1].split("\n\n", 1)[0].splitlines()
    for line in estimates:
        label = line.split()[0]
        assert not bare_numbers(line, labels=[label]), line
        unit = "°/s" if label.startswith("gyro") else "ppm" if ".K[" in label else "mg"
        assert line.rstrip().endswith(f"{unit})"), line
    table = text.split("gets wrong", 1)[1].split("\n  lack of fit", 1)[0].splitlines()[1:]
    head, rows = table[0].split(), table[1:]
    assert head == ["pos", "accel.x", "accel.y", "accel.z", "gyro.x", "gyro.y", "gyro.z"]
    assert len(rows) == 8
    for row in rows:
        index, *cells = row.split(maxsplit=1)
        assert not bare_numbers(cells[0]), row
        units = re.findall(r"[-+][0-9.e+-]+ (\S+)", cells[0])
        assert units == ["mg"] * 3 + ["°/s"] * 3, row
