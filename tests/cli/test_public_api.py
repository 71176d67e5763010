"""The public API of ``canimucal`` (docs/design.md §1) against the CLI on the same recording.

The README's three lines are run as written; their calibration must equal the JSON of
``canimucal solve PATH --model full --tilt --json -`` in every numeric field, to the last digit.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import canimucal as cm
from tests.cli.conftest import Simulated
from tests.support.cli_run import CliRun
from tests.support.user_dirs import UserDirs

Cli = Callable[[list[str]], CliRun]
Sim = Callable[..., Simulated]


def fields(document: dict[str, Any]) -> dict[str, Any]:
    """Every field but the creation time, by path."""
    return {k: v for k, v in leaves(document) if k != "created"}


def leaves(tree: Any, path: str = "") -> Iterator[tuple[str, Any]]:
    """Every scalar of a JSON tree with its path (``accel.K[0][1]``)."""
    if isinstance(tree, dict):
        for key, value in tree.items():
            yield from leaves(value, f"{path}.{key}" if path else key)
    elif isinstance(tree, list):
        for i, value in enumerate(tree):
            yield from leaves(value, f"{path}[{i}]")
    else:
        yield path, tree


def test_readme_lines_equal_solve_in_every_field(cli: Cli, simulated: Sim, tmp_path: Path) -> None:
    path = simulated("recommended", "full").path
    run = cli(["solve", str(path), "--model", "full", "--tilt", "--json", "-"])
    assert run.code == 0, run.err
    from_cli = fields(json.loads(run.out))

    # the README's three lines
    cal = cm.calibrate(cm.read_recording(path), model="full", tilt=True)
    cal.to_json(tmp_path / "calibration.json")

    from_api = fields(cal.to_dict())
    # a Recording object carries no file reference; the path form does (checked below)
    assert {k for k in from_cli if not k.startswith("recording.")} == set(from_api)
    numeric = [k for k, v in from_api.items() if isinstance(v, float | int)]
    assert len(numeric) > 100  # values, σ, covariance, positions, acceptance
    for key in from_api:
        assert from_api[key] == from_cli[key], key
    assert cal.acceptance is not None and "max_bias_sigma_mg" in cal.acceptance.values

    by_path = cm.calibrate(path, model="full", tilt=True)
    assert fields(by_path.to_dict()) == from_cli
    assert cm.Calibration.from_json(tmp_path / "calibration.json") == cal


def test_calibration_applies_itself(simulated: Sim) -> None:
    sim = simulated("recommended", "full")
    rec = cm.read_recording(sim.path)
    cal = cm.calibrate(rec, model="full", tilt=True)
    g = float(rec.header["g"])
    for label in np.unique(rec.position[rec.position >= 0]):
        rows = rec.position == label
        f = cal.accel.correct(rec.accel[rows])
        assert f.shape == (int(rows.sum()), 3)
        # corrected specific force has magnitude g (noise averages out over the position)
        assert abs(np.linalg.norm(f.mean(axis=0)) - g) < 2e-3 * g
    one = cal.accel.correct(rec.accel[0])
    assert one.shape == (3,)


def test_numpy_arrays_without_a_recording(simulated: Sim) -> None:
    """``average_position`` + ``Pose.from_deg`` give the recording's numbers from plain arrays."""
    rec = cm.read_recording(simulated("recommended", "full").path)
    averages = []
    for label in np.unique(rec.position[rec.position >= 0]):
        rows = np.flatnonzero(rec.position == label)
        first = rows[0]
        pose = cm.Pose.from_deg(rec.alpha_deg[first], rec.beta_deg[first], rec.psi_deg[first])
        averages.append(
            cm.average_position(pose, rec.accel[rows], rec.gyro[rows], rec.sample_rate_hz)
        )
    latitude, g = float(rec.header["latitude_deg"]), float(rec.header["g"])
    from_arrays = cm.calibrate(averages, model="full", tilt=True, g=g, latitude_deg=latitude)
    # the poses carry 0.1° (Pose.from_deg's default): the recording solved with that tolerance
    from_recording = cm.calibrate(rec, model="full", tilt=True, tolerance_deg=0.1)
    assert from_arrays.accel is not None and from_recording.accel is not None
    np.testing.assert_allclose(
        from_arrays.accel.K_matrix(), from_recording.accel.K_matrix(), rtol=1e-12
    )
    np.testing.assert_allclose(
        from_arrays.accel.bias_counts(), from_recording.accel.bias_counts(), rtol=1e-12
    )


def test_plan_bounds_and_pose_from_degrees() -> None:
    table = cm.plan_bounds("recommended", model="full", tilt=True)
    assert table.plan == "recommended"
    assert all(r.sigma is not None and r.sigma > 0 for r in table.rows)
    two = cm.plan_bounds("two", model="full")
    assert any(r.sigma is None for r in two.rows)  # two positions cannot see cross-axis terms
    pose = cm.Pose.from_deg(90.0, -45.0, 180.0, tolerance=0.2)
    np.testing.assert_allclose(pose.angles, np.deg2rad([90.0, -45.0, 180.0]))
    assert pose.tolerance == pytest.approx(np.deg2rad(0.2))


def test_errors_have_one_root_and_unknown_names_fail() -> None:
    assert issubclass(cm.InputError, cm.CanimucalError)
    assert issubclass(cm.DeviceError, cm.CanimucalError)
    with pytest.raises(cm.InputError, match="no position averages"):
        cm.calibrate([])
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        _ = cm.nonsense  # type: ignore[attr-defined]
    assert set(cm.__all__) <= set(dir(cm))


def test_import_is_light() -> None:
    """``import canimucal`` loads neither numpy-heavy modules nor textual until a name is used."""
    code = (
        "import sys, canimucal; print(sorted(m for m in sys.modules if m.startswith('canimucal')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['canimucal', 'canimucal.version']"


def test_dir_lists_the_api_only() -> None:
    assert dir(cm) == sorted(cm.__all__)
    assert not {"Any", "importlib", "TYPE_CHECKING", "annotations"} & set(dir(cm))


STRICT = "max_bias_sigma_mg = 0.001\n[plan.recommended]\nmax_rms_ms2 = 1e-9\n"


def test_calibrate_never_reads_the_users_acceptance_file(
    cli: Cli, simulated: Sim, own_user_dirs: UserDirs
) -> None:
    """Same verdict with and without a strict user file; the CLI honours the file."""
    path = simulated("recommended", "full").path
    before = cm.calibrate(path, model="full", tilt=True)
    assert before.acceptance is not None and before.acceptance.passed
    own_user_dirs.write_acceptance(STRICT)
    after = cm.calibrate(path, model="full", tilt=True)
    assert after.acceptance == before.acceptance
    assert after.acceptance is not None
    assert after.acceptance.limits == cm.AcceptanceLimits().as_dict()
    # given explicitly, the same limits fail it
    config = cm.AcceptanceConfig({"max_bias_sigma_mg": 0.001})
    given = cm.calibrate(path, model="full", tilt=True, limits=config)
    assert given.acceptance is not None and not given.acceptance.passed
    # the command line reads the file; this recording's header names no plan, but its poses
    # are the recommended plan's, which its calibration names: that plan's table applies too
    run = cli(["solve", str(path), "--model", "full", "--tilt", "--json", "-"])
    assert run.code == 3
    document = json.loads(run.out)
    assert document["plan"] == "recommended"
    limits = document["acceptance"]["limits"]
    assert (limits["max_bias_sigma_mg"], limits["max_rms_ms2"]) == (0.001, 1e-9)


def test_every_public_name_resolves() -> None:
    assert set(cm.__all__) == {"__version__", *cm._PUBLIC}
    for name in cm.__all__:
        assert getattr(cm, name) is not None


def test_one_version_source(capsys: pytest.CaptureFixture[str]) -> None:
    """pyproject.toml reads canimucal/version.py: the installed metadata and --version agree."""
    from importlib.metadata import version

    from canimucal.cli.main import main

    assert version("canimucal") == cm.__version__
    with pytest.raises(SystemExit):
        main(["--version"])
    assert capsys.readouterr().out == f"canimucal {cm.__version__}\n"
