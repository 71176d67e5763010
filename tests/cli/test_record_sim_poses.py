"""`record --sim` sets each pose as an operator would: off by a draw from the plan's 1σ.

The recording's header states the plan's ``tolerance_deg`` and the analysis takes it as the
pose-setting scatter, so the simulated unit on the bus must really scatter that much (it used
to follow the plan exactly, and a replay fitted better than its own header said it could).
The draw is seeded by ``--seed``: the frames on the bus put each position's mean specific
force where :func:`set_by_operator` put the pose, not at the nominal angles.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.cli.main import main
from canimucal.model.frames import position_dcm, specific_force_level
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.runtime.inputs import read_recording
from canimucal.sim.schedule import set_by_operator
from canimucal.sim.truth import Truth

SEED = 4


def test_simulated_unit_holds_the_drawn_poses(tmp_path: Path, capsys: Any) -> None:
    doc = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0, tilt_max_deg=0.0)
    truth = Truth.from_dict(doc.to_dict())
    path, out = tmp_path / "truth.json", tmp_path / "rec.csv"
    path.write_text(json.dumps(truth.to_dict()))
    argv = ["record", str(out), "--sim", "--truth", str(path), "--plan", "recommended",
            "--seconds", "20", "--time-scale", "200", "--seed", str(SEED)]  # fmt: skip
    assert main(argv) == 0
    capsys.readouterr()
    rec = read_recording(out)
    tolerance_deg = np.rad2deg(RECOMMENDED.positions[0].tolerance)
    assert rec.header["tolerance_deg"] == pytest.approx(tolerance_deg)
    placed = set_by_operator(RECOMMENDED, np.random.default_rng(SEED))
    level = specific_force_level(truth.g)
    off_nominal, off_drawn = [], []
    for i, (nominal, drawn) in enumerate(zip(RECOMMENDED.positions, placed.positions, strict=True)):
        rows = rec.position == i
        assert rows.sum() > 1000
        # labels stay nominal, as an operator's recording is
        assert np.allclose(rec.alpha_deg[rows], np.rad2deg(nominal.alpha))
        f = truth.accel.params().correct(rec.accel[rows].mean(axis=0))
        f_nominal = (
            position_dcm(
                *nominal.angles, alpha0=truth.alpha0, beta0=truth.beta0, tilt_model=truth.tilt_model
            )
            @ level
        )
        f_drawn = (
            position_dcm(
                *drawn.angles, alpha0=truth.alpha0, beta0=truth.beta0, tilt_model=truth.tilt_model
            )
            @ level
        )
        off_nominal.append(np.linalg.norm(f - f_nominal))
        off_drawn.append(np.linalg.norm(f - f_drawn))
    # 0.1° of pose error is g·1.7e-3 ≈ 0.017 m/s² per angle; 20 s of the default
    # 1.5e-3 m/s²/√Hz white noise average to 3.4e-4 m/s² per axis
    rms_nominal, rms_drawn = (
        np.sqrt(np.mean(np.square(off_nominal))),
        np.sqrt(np.mean(np.square(off_drawn))),
    )
    assert 0.008 < rms_nominal < 0.06, off_nominal
    assert rms_drawn < 0.2 * rms_nominal, (off_drawn, off_nominal)
