"""The Linux reference node's synthetic sensor (``firmware/linux/sensor.c``) against Python.

The node must follow a pose schedule exactly as ``canimucal sim --poses`` does, or
``record --follow-schedule`` labels the wrong samples: the same plan file through the C
reader and schedule and through :class:`~canimucal.sim.schedule.PoseTrajectory` gives the
same position index and motion flag at every 200 Hz sample time, the same angles, and the
same specific force as :func:`~canimucal.model.frames.position_dcm` (base tilt included).
"""

from __future__ import annotations

import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canimucal.io.plans import write_plan
from canimucal.model.frames import position_dcm, specific_force_level
from canimucal.model.plan import builtin_plan
from canimucal.model.positions import Plan
from canimucal.sim.schedule import PoseTrajectory
from tests.firmware.conftest import FIRMWARE, MODULE, Compile

HARNESS = r"""
#include <stdio.h>
#include <stdlib.h>
#include "sensor.h"
int main(int argc, char** argv) {
    sensor_t s;
    char err[160] = "usage: harness PLAN TRANSIENT ALPHA0 BETA0";
    double t, angles[3], f[3];
    int index, moving;
    sensor_defaults(&s);
    s.transient_s = atof(argv[2]);
    s.base_tilt[0] = atof(argv[3]);
    s.base_tilt[1] = atof(argv[4]);
    if (argc != 5 || sensor_read_plan(&s, argv[1], err, sizeof err) < 0) { puts(err); return 1; }
    while (scanf("%lf", &t) == 1) {
        sensor_pose_at(&s, t, angles, &index, &moving);
        sensor_force(&s, angles, f);
        printf("%d %d %.17g %.17g %.17g %.17g %.17g %.17g\n", index, moving, angles[0], angles[1],
               angles[2], f[0], f[1], f[2]);
    }
    return 0;
}
"""


@pytest.fixture(scope="module")
def harness(compile_c: Compile, tmp_path_factory: pytest.TempPathFactory) -> Path:
    source = tmp_path_factory.mktemp("sensor") / "harness.c"
    source.write_text(HARNESS)
    linux = FIRMWARE / "linux"
    return compile_c([source, linux / "sensor.c"], "sensor_harness", [f"-I{linux}", f"-I{MODULE}"])


def _plan(name: str, seconds: float) -> Plan:
    plan = builtin_plan(name)
    plan = plan.with_total_seconds(seconds * len(plan.positions))
    wrapped = [replace(p, psi=float(np.angle(np.exp(1j * p.psi)))) for p in plan.positions]
    return Plan(plan.name, tuple(wrapped))


@pytest.mark.parametrize(
    ("name", "transient_s", "tilt_deg"),
    [("recommended", 1.0, (0.0, 0.0)), ("five", 0.5, (1.5, -0.8)), ("vehicle", 2.0, (0.3, 0.2))],
)
def test_schedule_and_force_equal_python(
    harness: Path, tmp_path: Path, name: str, transient_s: float, tilt_deg: tuple[float, float]
) -> None:
    plan = _plan(name, 3.0)
    path = write_plan(tmp_path / "poses.json", plan, overwrite=False)
    trajectory = PoseTrajectory()
    trajectory.follow(0.0, plan, transient_s)
    assert trajectory.end_s is not None
    times = np.arange(-0.01, trajectory.end_s + 1.0, 1.0 / 200.0)
    alpha0, beta0 = np.deg2rad(tilt_deg)
    run = subprocess.run(
        [str(harness), str(path), str(transient_s), repr(float(alpha0)), repr(float(beta0))],
        input="\n".join(repr(float(t)) for t in times),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    got = np.array([line.split() for line in run.stdout.splitlines()], dtype=float)
    assert got.shape == (times.size, 8)
    want = trajectory.sample(times)
    times_before = times < 0.0  # before the schedule: the start pose, no plan index
    assert np.array_equal(got[~times_before, 0], want.index[~times_before])
    assert np.array_equal(got[:, 1].astype(bool), want.moving)
    np.testing.assert_allclose(got[:, 2:5], want.angles, atol=1e-12)
    g_level = specific_force_level(9.80665)
    forces = np.array([position_dcm(a, b, p, alpha0, beta0) @ g_level for a, b, p in want.angles])
    np.testing.assert_allclose(got[:, 5:8], forces, atol=1e-9)
    assert set(got[:, 0].astype(int)) >= set(range(len(plan.positions)))
