"""`canimucal solve` on simulated recordings: the calibration JSON, accuracy, bad input."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.io.calibration import read_calibration
from canimucal.sim.truth import Truth

# the fixtures of conftest.py: cli(argv) -> CliRun(code, out, err); simulated(plan, kind,
# seconds) -> Simulated(path, truth)
Cli = Callable[[Sequence[Any]], Any]
Sim = Callable[..., Any]

MAX_DEVIATION_SIGMA = 4.0
"""|estimate − truth| ≤ 4σ per parameter: for ~20 Gaussian estimates the chance that any one
exceeds it is about 20 × 6.3e-5 ≈ 1e-3 (and the seeds are fixed)."""

_NAME = re.compile(r"(accel|gyro)\.(bias|K|S|G)\[(\d)\](?:\[(\d)\])?")


def estimates(doc: dict[str, Any]) -> dict[str, tuple[float | None, float | None]]:
    """``{name: (value, sigma)}`` for every entry of the document (tilt in degrees)."""
    out: dict[str, tuple[float | None, float | None]] = {}
    for sensor, blocks in (("accel", ("bias", "K")), ("gyro", ("bias", "S", "G"))):
        for block in blocks:
            values = (doc.get(sensor) or {}).get(block)
            sigmas = (doc.get(sensor) or {}).get(f"{block}_sigma")
            if values is None:
                continue
            for i, row in enumerate(values):
                if isinstance(row, list):
                    for j, v in enumerate(row):
                        s = None if sigmas is None else sigmas[i][j]
                        out[f"{sensor}.{block}[{i}][{j}]"] = (v, s)
                else:
                    out[f"{sensor}.{block}[{i}]"] = (row, None if sigmas is None else sigmas[i])
    tilt = doc.get("base_tilt_deg")
    if tilt is not None:
        sig = tilt.get("sigma") or [None, None]
        out["base_tilt.alpha0"] = (tilt["alpha0"], sig[0])
        out["base_tilt.beta0"] = (tilt["beta0"], sig[1])
    return out


def truth_value(truth: Truth, name: str) -> float:
    """The true value of parameter ``name`` (tilt in degrees, like the JSON)."""
    if name == "base_tilt.alpha0":
        return float(np.rad2deg(truth.alpha0))
    if name == "base_tilt.beta0":
        return float(np.rad2deg(truth.beta0))
    m = _NAME.fullmatch(name)
    assert m, name
    sensor, block, i, j = m.groups()
    part = truth.accel if sensor == "accel" else truth.gyro
    table = {"bias": part.bias, "K": getattr(part, "K", None), "S": getattr(part, "S", None)}
    table["G"] = getattr(part, "G", None)
    arr = np.asarray(table[block])
    return float(arr[int(i)] if j is None else arr[int(i), int(j)])


def deviations(doc: dict[str, Any], truth: Truth) -> dict[str, float]:
    """(estimate − truth)/σ for every parameter in the covariance order."""
    est = estimates(doc)
    out = {}
    for name in doc["covariance"]["order"]:
        value, sigma = est[name]
        assert value is not None and sigma is not None and sigma > 0, name
        out[name] = (value - truth_value(truth, name)) / sigma
    return out


def solve_json(cli: Cli, path: Path, *flags: str) -> tuple[dict[str, Any], Any]:
    run = cli(["solve", str(path), *flags, "--no-check", "--json", "-"])
    assert run.code == 0, run.err
    return json.loads(run.out), run


# ----------------------------------------------------------------------- the JSON document


def test_two_positions_json_document(cli: Cli, simulated: Sim, tmp_path: Path) -> None:
    sim = simulated("two", "level")
    target = tmp_path / "cal.json"
    run = cli(["solve", sim.path, "--json", target])
    # two positions see K_zz only through sin 5°: σ 4 % fails the 3000 ppm limit; the
    # JSON is written first, with the verdict, and the exit status says it failed
    assert run.code == 3, run.err
    assert "worst scale σ" in run.out and "FAILED" in run.out
    assert run.err.strip().endswith("--no-check to exit 0)")
    assert f"wrote {target}" in run.out
    record = read_calibration(target)  # validates schema, keys, shapes, covariance
    doc = json.loads(target.read_text())
    assert record.acceptance is not None and record.acceptance.passed is False
    assert doc["acceptance"]["limits"]["max_scale_sigma_ppm"] == 3000.0
    assert doc["acceptance"]["values"]["max_scale_sigma_ppm"] > 3000.0
    assert record.plan == "two" and doc["plan"] == "two"
    assert record.device.serial == sim.truth.serial
    est = estimates(doc)
    order = doc["covariance"]["order"]
    expected = [f"accel.bias[{i}]" for i in range(3)] + [f"accel.K[{i}][{i}]" for i in range(3)]
    expected += [f"gyro.bias[{i}]" for i in range(3)]
    assert order == expected
    for name in order:  # σ for every estimated parameter
        value, sigma = est[name]
        assert value is not None and sigma is not None and sigma > 0, name
    held = [f"accel.K[{i}][{j}]" for i in range(3) for j in range(3) if i != j]
    held += [f"gyro.S[{i}][{j}]" for i in range(3) for j in range(3)]
    for name in held:  # held fixed: no σ (and no row in the covariance)
        assert est[name][1] is None, name
        assert name not in order
    assert all(v is None for row in doc["gyro"]["S"] for v in row)
    assert "base_tilt_deg" not in doc or doc["base_tilt_deg"] is None
    matrix = np.array(doc["covariance"]["matrix"])
    assert matrix.shape == (len(order), len(order))
    np.testing.assert_allclose(matrix, matrix.T, rtol=1e-9, atol=0)
    sigmas = np.array([est[n][1] for n in order])
    np.testing.assert_allclose(np.sqrt(np.diag(matrix)), sigmas, rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(matrix / np.outer(sigmas, sigmas)) > 0)
    dev = deviations(doc, sim.truth)
    assert max(abs(d) for d in dev.values()) < MAX_DEVIATION_SIGMA, dev
    assert len(doc["positions"]) == 2 and doc["fit"]["dof"] >= 0


def test_five_with_tilt_agrees_with_truth_and_warns_bias_z_beta0(cli: Cli, simulated: Sim) -> None:
    sim = simulated("five", "diag")
    doc, run = solve_json(cli, sim.path, "--tilt")
    assert doc["plan"] == "five"
    dev = deviations(doc, sim.truth)
    assert "base_tilt.beta0" in dev and "accel.bias[2]" in dev
    assert max(abs(d) for d in dev.values()) < MAX_DEVIATION_SIGMA, dev
    warnings = [line for line in run.err.splitlines() if line.startswith("warning:")]
    named = [w for w in warnings if "accel.bias[2]" in w and "base_tilt.beta0" in w]
    assert named, run.err
    assert re.search(r"correlation -0\.999\d", named[0]), named[0]
    # the poorly separable pair keeps its value and its (large) σ
    cov = np.array(doc["covariance"]["matrix"])
    order = doc["covariance"]["order"]
    i, j = order.index("accel.bias[2]"), order.index("base_tilt.beta0")
    assert cov[i, j] < 0


def test_recommended_full_model_recovers_cross_axis_and_tilt(cli: Cli, simulated: Sim) -> None:
    sim = simulated("recommended", "full")
    doc, run = solve_json(cli, sim.path, "--model", "full", "--tilt")
    assert doc["plan"] == "recommended"
    dev = deviations(doc, sim.truth)
    off = [f"accel.K[{i}][{j}]" for i in range(3) for j in range(3) if i != j]
    assert set(off) | {"base_tilt.alpha0", "base_tilt.beta0"} <= set(dev)
    assert max(abs(d) for d in dev.values()) < MAX_DEVIATION_SIGMA, dev
    est = estimates(doc)
    true_off = np.array([truth_value(sim.truth, n) for n in off])
    got_off = np.array([est[n][0] for n in off], dtype=float)
    # the cross-axis terms are seen: much closer to the truth than to the nominal zero
    assert np.linalg.norm(got_off - true_off) < 0.5 * np.linalg.norm(true_off)
    tilt_true = np.array(
        [truth_value(sim.truth, n) for n in ("base_tilt.alpha0", "base_tilt.beta0")]
    )
    tilt_sigma = np.array([est[n][1] for n in ("base_tilt.alpha0", "base_tilt.beta0")], float)
    assert np.all(tilt_sigma < 0.1)  # degrees: a 1° tilt is resolved
    assert np.max(np.abs(tilt_true)) > 5 * np.max(tilt_sigma)
    assert "does not fit" not in run.err


def test_two_positions_full_model_is_null_with_reason(cli: Cli, simulated: Sim) -> None:
    sim = simulated("two", "level")
    run = cli(["solve", sim.path, "--model", "full", "--no-check"])
    assert run.code == 0, run.err
    off = [f"accel.K[{i}][{j}]" for i in range(3) for j in range(3) if i != j]
    for name in off:
        line = next(x for x in run.out.splitlines() if x.startswith(f"not determined: {name}:"))
        assert "not identifiable" in line
    k_lines = [x.split() for x in run.out.splitlines() if x.startswith("accel.K")]
    assert k_lines == [["accel.K", "nominal", "(not", "estimated)", "—"]]  # one row for all
    doc, _ = solve_json(cli, sim.path, "--model", "full")
    est = estimates(doc)
    for name in off:
        assert est[name] == (None, None), name
        assert name not in (doc.get("covariance") or {}).get("order", [])


# ------------------------------------------------------------------------------ the outputs


def test_json_dash_prints_only_json(cli: Cli, simulated: Sim) -> None:
    sim = simulated("two", "level")
    run = cli(["solve", sim.path, "--json", "-", "--no-check"])
    assert run.code == 0
    assert run.out.startswith("{") and run.out.rstrip().endswith("}")
    doc = json.loads(run.out)
    assert doc["schema"] == "canimucal.calibration/1"
    read_calibration(json.dumps(doc))


def test_existing_json_target_needs_overwrite(cli: Cli, simulated: Sim, tmp_path: Path) -> None:
    sim = simulated("two", "level")
    target = tmp_path / "cal.json"
    target.write_text("keep me\n")
    run = cli(["solve", sim.path, "--json", target])
    assert run.code == 2
    assert target.read_text() == "keep me\n"
    assert run.err.count("\n") == 1 and run.err.startswith("error: ")
    assert run.out == ""
    run = cli(["solve", sim.path, "--json", target, "--overwrite", "--no-check"])
    assert run.code == 0, run.err
    read_calibration(target)


# ------------------------------------------------------------------------------- bad input


def _rewrite(source: Path, target: Path, edit: Callable[[list[str], list[str]], list[str]]) -> Path:
    lines = source.read_text().splitlines(keepends=True)
    n_head = sum(1 for line in lines if line.startswith("#"))
    target.write_text("".join(edit(lines[: n_head + 1], lines[n_head + 1 :])))
    return target


def _only_first_position(head: list[str], rows: list[str]) -> list[str]:
    return head + [r for r in rows if r.split(",")[2] in ("", "0")]


def _all_level(head: list[str], rows: list[str]) -> list[str]:
    def level(row: str) -> str:
        f = row.split(",")
        if f[2] != "":
            f[3] = f[4] = f[5] = "0"
        return ",".join(f)

    return head + [level(r) for r in rows]


def _nan_cell(head: list[str], rows: list[str]) -> list[str]:
    f = rows[500].split(",")
    f[6] = "nan"
    return head + rows[:500] + [",".join(f)] + rows[501:]


def _time_backwards(head: list[str], rows: list[str]) -> list[str]:
    rows = list(rows)
    rows[100], rows[101] = rows[101], rows[100]
    return head + rows


def _missing_column(head: list[str], rows: list[str]) -> list[str]:
    head = head[:-1] + [head[-1].replace(",temp_c", "")]
    return head + [r.rsplit(",", 1)[0] + "\n" for r in rows]


def _missing_schema(head: list[str], rows: list[str]) -> list[str]:
    return [h for h in head if not h.startswith("# schema")] + rows


BAD_INPUTS = [
    ("one_position", _only_first_position, "need at least 2 positions, got 1"),
    ("degenerate", _all_level, "degenerate plan"),
    ("nan", _nan_cell, "'nan' in column ax"),
    ("backwards", _time_backwards, "t goes backwards"),
    ("no_temp_c", _missing_column, "missing columns temp_c"),
    ("no_schema", _missing_schema, "missing header line '# schema"),
]


@pytest.mark.parametrize(("label", "edit", "message"), BAD_INPUTS, ids=[b[0] for b in BAD_INPUTS])
def test_bad_input_is_one_line_and_exit_2(
    cli: Cli, simulated: Sim, tmp_path: Path, label: str, edit: Any, message: str
) -> None:
    path = _rewrite(simulated("two", "level").path, tmp_path / f"{label}.csv", edit)
    run = cli(["solve", path])
    assert run.code == 2
    assert run.out == ""
    assert run.err.count("\n") == 1, run.err
    assert run.err.startswith("error: ") and message in run.err, run.err
    assert "Traceback" not in run.err


def test_nonexistent_file(cli: Cli, tmp_path: Path) -> None:
    run = cli(["solve", tmp_path / "absent.csv"])
    assert run.code == 2
    assert run.err.startswith("error: cannot read ") and run.err.count("\n") == 1


def test_python_dash_m_runs_solve(simulated: Sim) -> None:
    sim = simulated("two", "level")
    proc = subprocess.run(
        [sys.executable, "-m", "canimucal", "solve", str(sim.path), "--json", "-", "--no-check"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["plan"] == "two"
    assert "Traceback" not in proc.stderr


DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
IMUCAL_CSV = DATA / "imucal_example_ferraris_session.csv"
IMUCAL_SECTIONS = DATA / "imucal_example_ferraris_session_list.json"
IMUCAL_KG_RG = np.array(
    [
        [1.0279030921108503, -0.00046689722733542574, -0.006590606955485163],
        [-0.00021830076271155843, 0.982423943314377, -0.0027347345695309115],
        [0.009697592565938506, 0.0076281835698891395, 0.9982342394732935],
    ]
)
"""imucal 2.6.0's own K_g·R_g on its example session (FerrarisCalibration defaults, 102.4 Hz)."""


@pytest.mark.skipif(not IMUCAL_CSV.is_file(), reason=f"imucal example absent at {DATA}")
def test_imucal_session_gyro_moves_agree_with_imucal(cli: Cli, tmp_path: Path) -> None:
    """``|ΔS_ij| · 3 / tr S ≤ 0.005``, each matrix normalised by its own trace."""
    out = tmp_path / "imucal.json"
    run = cli(
        [
            "solve",
            "--format",
            "imucal",
            IMUCAL_CSV,
            IMUCAL_SECTIONS,
            "--sample-rate-hz",
            "102.4",
            "--gyro",
            "moves",
            "--model",
            "full",
            "--no-check",  # imucal's hand-held poses fail the accelerometer's limits
            "--json",
            out,
        ]
    )
    assert run.code == 0, run.err
    doc = json.loads(out.read_text())
    s = np.array(doc["gyro"]["S"]) * np.pi / 180.0  # counts are deg/s: S per (deg/s)
    ours = s * 3.0 / np.trace(s)
    theirs = IMUCAL_KG_RG * 3.0 / np.trace(IMUCAL_KG_RG)
    assert np.max(np.abs(ours - theirs)) <= 0.005, ours - theirs
    assert all(v is not None for row in doc["gyro"]["S_sigma"] for v in row)


def _drop_angles(head: list[str], rows: list[str]) -> list[str]:
    def plain(row: str) -> str:
        f = row.split(",")
        f[3] = f[4] = f[5] = ""
        return ",".join(f)

    return head + [plain(r) for r in rows]


def test_gyro_moves_on_a_recording_without_angles_is_refused(
    cli: Cli, simulated: Sim, tmp_path: Path
) -> None:
    path = _rewrite(simulated("two", "level").path, tmp_path / "plain.csv", _drop_angles)
    run = cli(["solve", path, "--gyro", "moves"])
    assert run.code == 2
    assert "--gyro moves needs labelled positions with angles" in run.err


def test_gyro_scale_left_unchecked_is_said(cli: Cli, simulated: Sim) -> None:
    run = cli(["solve", simulated("two", "level").path, "--no-check"])
    assert run.code == 0
    assert "warning: gyro scale and misalignment were not checked" in run.err


def test_acceptance_limits_come_from_the_user_config(
    cli: Cli, simulated: Sim, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    sim = simulated("recommended", "full")
    run = cli(["solve", sim.path, "--model", "full", "--tilt", "--json", "-"])
    assert run.code == 0, run.err  # the recommended plan meets the built-in limits
    assert json.loads(run.out)["acceptance"]["passed"] is True
    config = tmp_path / "xdg"
    (config / "canimucal").mkdir(parents=True)
    (config / "canimucal" / "acceptance.toml").write_text("max_bias_sigma_mg = 0.001\n")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(config))
    run = cli(["solve", sim.path, "--model", "full", "--tilt", "--json", "-"])
    assert run.code == 3
    doc = json.loads(run.out)
    assert doc["acceptance"]["passed"] is False
    assert doc["acceptance"]["limits"]["max_bias_sigma_mg"] == 0.001
    assert doc["acceptance"]["limits"]["max_scale_sigma_ppm"] == 3000.0  # default kept
    (config / "canimucal" / "acceptance.toml").write_text("max_bias_sigma = 1\n")
    run = cli(["solve", sim.path])
    assert run.code == 2 and "unknown key 'max_bias_sigma'" in run.err
    assert run.err.count("\n") == 1


def test_vehicle_recording_with_a_factory_k_holds_it_as_a_stated_prior(
    cli: Cli, simulated: Sim, tmp_path: Path
) -> None:
    sim = simulated("vehicle", "diag")
    factory = tmp_path / "factory.json"
    k = np.asarray(sim.truth.accel.K, dtype=float)  # the maker's K, known to 0.1 %
    factory.write_text(
        json.dumps(
            {
                "schema": "canimucal.calibration/1",
                "device": {"serial": 1},
                "accel": {"bias": [0.0, 0.0, 0.0], "K": k.tolist()},
            }
        )
    )
    prior = ("--prior-k", str(factory), "--prior-k-sigma", "0.001")
    flags = ("--tilt", "--tolerance-deg", "0.5", *prior)  # no header: say the tolerance
    doc, run = solve_json(cli, sim.path, *flags)
    priors = {p["name"]: p for p in doc["priors"]}
    assert set(priors) == {f"accel.K[{i}][{i}]" for i in range(3)}
    assert priors["accel.K[1][1]"]["mean"] == pytest.approx(k[1, 1])
    assert priors["accel.K[1][1]"]["source"] == "K from factory.json"
    assert "held at the stated prior (K from factory.json" in run.err
    dev = deviations(doc, sim.truth)
    assert max(abs(d) for d in dev.values()) < MAX_DEVIATION_SIGMA, dev
    # with bias y tied to K_yy, its σ is about g·σ(K_yy): 0.1 % of 2048 counts
    bias_y_sigma = estimates(doc)["accel.bias[1]"][1]
    assert bias_y_sigma is not None and 1.0 < bias_y_sigma < 4.0
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "canimucal.calibration/1", "device": {"serial": 1}}')
    run = cli(["solve", sim.path, "--prior-k", bad])
    assert run.code == 2 and run.err.count("\n") == 1


def _with_tolerance_header(head: list[str], rows: list[str]) -> list[str]:
    return [head[0], "# tolerance_deg: 0.05\n", *head[1:], *rows]


def test_pose_scatter_from_header_else_estimated(cli: Cli, simulated: Sim, tmp_path: Path) -> None:
    """No header: the scatter is estimated (recommended plan, dof ≥ 10), its one-sided 84 %
    upper bound carries the σ with few residuals (five positions, 7 dof), or with none (two
    positions) it is assumed; `solve` says which in its notes, its fit line and the JSON's
    ``fit``; a header is used silently."""
    doc, run = solve_json(cli, simulated("recommended", "diag").path)
    assert "pose-setting scatter" in run.err and "estimated from the data (REML" in run.err
    assert doc["fit"]["pose_scatter_basis"] == "estimated"
    doc, run = solve_json(cli, simulated("five", "diag").path, "--tilt")
    assert "its one-sided 84 % upper bound, only 7 accelerometer residual dof" in run.err
    assert doc["fit"]["pose_scatter_basis"] == "upper bound"
    run = cli(["solve", simulated("five", "diag").path, "--tilt", "--no-check"])
    used = doc["fit"]["pose_scatter_deg"]
    assert f"and the pose scatter ({used:.3g}°, upper bound)" in run.out
    doc, run = solve_json(cli, simulated("two", "level").path)
    assert "assumed (the plans' default tolerance): no accelerometer residual dof" in run.err
    assert doc["fit"]["pose_scatter_basis"] == "assumed"
    assert doc["fit"]["pose_scatter_deg"] == pytest.approx(0.1)
    assert "warning: only 3 residual degrees of freedom" in run.err
    path = _rewrite(simulated("two", "level").path, tmp_path / "hdr.csv", _with_tolerance_header)
    run = cli(["solve", path, "--no-check"])
    assert run.code == 0, run.err
    assert "pose-setting scatter" not in run.err


IMUTK_ACC, IMUTK_GYRO = DATA / "imutk_xsens_acc.mat", DATA / "imutk_xsens_gyro.mat"


@pytest.mark.skipif(not IMUTK_GYRO.is_file(), reason=f"imu_tk example absent at {DATA}")
def test_imutk_session_gyro_moves_matched_on_gravity(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "imutk.json"
    run = cli(
        ["solve", "--format", "imutk", IMUTK_ACC, IMUTK_GYRO, "--model", "full",
         "--gyro", "moves", "--g", "9.81744", "--no-check", "--json", out]
    )  # fmt: skip
    assert run.code == 0, run.err
    assert "matched on gravity (rotations about the vertical unseen)" in run.err
    gyro = read_calibration(out).gyro
    assert gyro is not None and gyro.S is not None and gyro.S_sigma is not None
    scale = np.diag(np.array(gyro.S, dtype=float))
    np.testing.assert_allclose(scale, [4778.0, 4758.0, 4766.0], rtol=0.01)  # Xsens factory
    assert np.all(np.array(gyro.S_sigma, dtype=float) < 0.005 * scale.mean())


@pytest.mark.parametrize("extra", [[], ["--tilt", "--model", "full"]])
def test_solve_runs_without_loading_scipy(simulated: Sim, tmp_path: Path, extra: list[str]) -> None:
    """`solve` fits, checks and writes with numpy alone (docs/performance.md: scipy's import
    was most of a small session's time); the fit still converges and the JSON is written."""
    sim = simulated("recommended", "full")
    out = tmp_path / "cal.json"
    code = (
        "import sys, json, contextlib, io\n"
        "from canimucal.cli.main import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    rc = main(['solve', {str(sim.path)!r}, '--json', {str(out)!r}, *{extra!r}])\n"
        "print(json.dumps([rc, sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')]))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    rc, loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert rc in (0, 3), done.stderr  # 3: acceptance (the simulated unit), the work all done
    assert loaded == []
    assert read_calibration(out).accel is not None
