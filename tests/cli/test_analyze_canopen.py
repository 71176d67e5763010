"""A hidden effect through the CANopen path (issue 5, item 8): simulated node → ImuClient → record.

``canimucal record --sim`` runs the simulated unit in-process on a python-can virtual bus;
the unit follows the recommended plan by itself (30 s per position, 200 Hz, default noise,
non-linear warm-up), ``record`` writes the CSV, and ``analyze --json -`` must name exactly
the hidden effect, and nothing on the clean unit. Seeds are fixed: the unit and the node's
noise ``SEED``; the effect's entry ``SEED`` too (:func:`hide_effect` with 8σ exactly, σ of
the entry's estimate under the recommended plan, as ``test_hidden_effects.reference_sigmas``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.analysis.discrepancy import effect_sigmas
from canimucal.cli.main import main
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.sim.effects import hide_effect, warm_up_profile
from canimucal.sim.truth import Truth
from tests.support.sessions import simulate_session

SEED = 1
REFERENCE_SEED = 999
SIZE_SIGMAS = 8.0
TIME_SCALE = "200"


def _clean_truth(seed: int) -> dict[str, Any]:
    doc = Truth.random(np.random.default_rng(seed), cross_axis_max=0.0, tilt_max_deg=0.0).to_dict()
    doc["temperature"] = {"profile": warm_up_profile()}
    return doc


def _findings(tmp_path: Path, doc: dict[str, Any], capsys: Any) -> list[str]:
    truth, out = tmp_path / "truth.json", tmp_path / "rec.csv"
    truth.write_text(json.dumps(doc))
    record = ["record", str(out), "--sim", "--truth", str(truth), "--plan", "recommended"]
    sim = ["--seconds", "30", "--time-scale", TIME_SCALE, "--seed", str(SEED)]
    assert main(record + sim) == 0
    capsys.readouterr()
    assert main(["analyze", str(out), "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    return [f["effect"] for f in report["findings"]]


@pytest.mark.parametrize("effect", ["cross_axis", None])
def test_recording_through_canopen_names_exactly_the_hidden_effect(
    tmp_path: Path, capsys: Any, effect: str | None
) -> None:
    doc = _clean_truth(SEED)
    if effect is not None:
        reference = simulate_session(
            Truth.from_dict(_clean_truth(REFERENCE_SEED)), RECOMMENDED, seed=REFERENCE_SEED
        )
        rng = np.random.default_rng(SEED)
        doc, _ = hide_effect(
            doc, effect, rng, effect_sigmas(reference), low=SIZE_SIGMAS, high=SIZE_SIGMAS
        )
    assert _findings(tmp_path, doc, capsys) == ([effect] if effect else [])
