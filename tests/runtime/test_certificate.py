"""The certificate's verdicts: verification against its limit, and escaped device text."""

from __future__ import annotations

import re

import numpy as np

from canimucal.analysis.acceptance import AcceptanceLimits, AcceptanceReport, Check
from canimucal.device.client import Identity
from canimucal.io.calibration import Conditions, Device, record_from_estimates
from canimucal.model.mounting import MountingMap
from canimucal.model.positions import PlannedPosition
from canimucal.model.vocabulary.units import QUANTITIES, Scales
from canimucal.procedure.events import LevelChecked, PoseVerified
from canimucal.runtime.certificate import (
    SessionFacts,
    certificate_html,
    certificate_markdown,
    mounting_text,
    verification_of,
)

G = 9.80665
LIMITS = AcceptanceLimits()


TILTED = PlannedPosition(float(np.deg2rad(10.0)), 0.0, 0.0)
TURNED = PlannedPosition(0.0, 0.0, float(np.deg2rad(90.0)))


def _after(norm_error_ms2: float, tilt_deg: float = 0.1) -> list[PoseVerified]:
    """Both verification poses re-read: the first with the given errors, the second clean."""
    return [
        PoseVerified(16, 0, 2, TILTED, "raise the rear wheels 10°", 0.1, norm_error_ms2, 1.0,
                     tilt_deg),
        PoseVerified(16, 1, 2, TURNED, "turn 90° right", 0.1, 0.0, 1.0, 0.05),
    ]  # fmt: skip


def test_verification_passes_within_its_limits_and_is_not_done_without_every_pose() -> None:
    ok = verification_of(_after(0.004 * G / 1000), True, LIMITS, G)  # 0.004 mg
    assert ok.done and ok.passed and ok.written
    assert ok.limits == {"max_verify_norm_error_mg": 5.0, "max_verify_tilt_error_deg": 2.0}
    assert np.isclose(ok.values["max_verify_tilt_error_deg"], 0.1)
    bad = verification_of(_after(-0.06), True, LIMITS, G)  # 6.1 mg > 5 mg
    assert bad.done and not bad.passed
    assert np.isclose(bad.values["max_verify_norm_error_mg"], 0.06 / G * 1000)
    tilted = verification_of(_after(0.0, tilt_deg=2.5), True, LIMITS, G)  # 2.5° > 2°
    assert tilted.done and not tilted.passed
    interrupted = verification_of([], True, LIMITS, G)  # written, then the session ended
    assert not interrupted.done and not interrupted.passed and interrupted.written
    one_of_two = verification_of(_after(0.0)[:1], True, LIMITS, G)
    assert not one_of_two.done and not one_of_two.passed
    unwritten = verification_of(_after(0.0), False, LIMITS, G)
    assert not unwritten.done and unwritten.written is False


def test_certificate_states_the_verdicts_and_escapes_device_text() -> None:
    record = record_from_estimates(
        ["accel.bias[0]", "accel.bias[1]", "accel.bias[2]"],
        [1.0, 2.0, 3.0],
        np.eye(3),
        device=Device(serial=7, node_id=16),
        plan="vehicle",
    )
    identity = Identity(1, 2, 3, 7, "<script>alert(1)</script> *imu*")
    report = AcceptanceReport((Check("worst bias σ", 8.2, 5.0, "mg", False, "max_bias_sigma_mg"),))
    facts = SessionFacts(
        operator="A. <b>Tester</b>",
        site="Bay 3",
        written=True,
        verification=verification_of([], True, LIMITS, G),
        warmup="skipped by the operator",
        mounting=mounting_text(MountingMap.parse("x=left,y=down,z=back"), "asked for *this* run"),
    )
    args = (record, identity, report, LIMITS, [])
    markdown = certificate_markdown(*args, warnings=["held at the stated prior"], facts=facts)
    page = certificate_html(*args, warnings=["held at the stated prior"], facts=facts)
    for text in (markdown, page):
        assert "k = 1" in text and "NOT PASSED" in text and "skipped by the operator" in text
        assert "NOT DONE" in text and "held at the stated prior" in text and "Bay 3" in text
    assert "Written to the device: yes" in markdown
    assert "Mounting: asked for \\*this\\* run" in markdown  # our own text, escaped too
    assert "<td>Mounting</td><td>asked for *this* run</td>" in page
    assert r"\*imu\*" in markdown and "&lt;script&gt;" in markdown and "<script>" not in markdown
    assert "<script>" not in page and "&lt;script&gt;" in page
    assert "&lt;b&gt;Tester&lt;/b&gt;" in page and "<b>" not in page


def test_the_mounting_line_is_empty_in_body_axes_and_says_bench() -> None:
    assert mounting_text(None, "anything") == ""
    turned = MountingMap.parse("x=left,y=down,z=back")
    assert mounting_text(turned) == "x=left,y=down,z=back"
    record = record_from_estimates(["accel.bias[0]"], [1.0], np.eye(1), device=Device(serial=7))
    text = certificate_markdown(
        record, Identity(1, 2, 3, 7, "imu"), AcceptanceReport(()), LIMITS, []
    )
    assert "- Mounting: unit axes (bench)" in text


def test_a_failed_acceptance_is_never_passed_beside_a_good_reread() -> None:
    """Issue 22: the verification printed PASSED beside a failed acceptance."""
    record = record_from_estimates(
        ["accel.bias[0]", "accel.bias[1]", "accel.bias[2]"],
        [1.0, 2.0, 3.0],
        np.eye(3),
        device=Device(serial=7, node_id=16),
        plan="vehicle",
    )
    identity = Identity(1, 2, 3, 7, "imu")
    reread = verification_of(_after(0.004 * G / 1000), True, LIMITS, G)  # within its limit
    failed = AcceptanceReport((Check("worst bias σ", 8.2, 5.0, "mg", False, "max_bias_sigma_mg"),))
    passed = AcceptanceReport((Check("worst bias σ", 1.2, 5.0, "mg", True, "max_bias_sigma_mg"),))
    facts = SessionFacts(written=True, verification=reread, verified=tuple(_after(0.0)))
    for report, ok in ((failed, False), (passed, True)):
        args = (record, identity, report, LIMITS, [])
        markdown = certificate_markdown(*args, facts=facts)
        page = certificate_html(*args, facts=facts)
        line = next(x for x in markdown.splitlines() if x.startswith("- Verification:"))
        assert ("PASSED" in line) is ok, line
        # what was verified, against which limits
        assert "re-read after the write: worst abs(f) − g 0.004 mg (limit 5 mg)" in line
        assert "worst tilt error 0.1° (limit 2°)" in line
        assert "| 1/2: alpha 10°, beta 0°, psi 0° |" in markdown  # each pose in the table
        assert "pose 1: raise the rear wheels 10°" in markdown and "turn 90° right" in page
        if not ok:
            assert "acceptance FAILED" in line and "acceptance FAILED" in page
            assert "PASSED:" not in page


UNIT_AFTER_NUMBER = re.compile(r"[-+]?\d[\d.]*(?:e[-+]?\d+)?(?: ± [\d.]+(?:e[-+]?\d+)?)? ?(\S+)")


def _bare_numbers(cell: str, units: set[str]) -> list[str]:
    """The numbers in ``cell`` not followed by one of ``units`` (a cell's unit check)."""
    return [m.group(0) for m in UNIT_AFTER_NUMBER.finditer(cell) if m.group(1) not in units]


def test_every_value_of_the_certificate_carries_its_unit() -> None:
    """Issue 22 item 6: values in the device's and the operator's units, never bare."""
    lsb, gyro_lsb = G / 2048.0, float(np.deg2rad(1.0 / 16.4))
    names = ["accel.bias[0]", "accel.bias[1]", "accel.bias[2]"]
    names += [f"accel.K[{i}][{i}]" for i in range(3)]
    names += ["gyro.bias[0]", "gyro.bias[1]", "gyro.bias[2]", "base_tilt.alpha0"]
    k = (1.0 + 120e-6) / lsb  # 120 ppm above nominal
    values = [2.0, -1.0, 0.5, k, k, k, 3.0, 0.0, -3.0, np.deg2rad(0.5)]
    sigmas = np.array([0.1] * 3 + [0.02] * 3 + [0.2] * 3 + [np.deg2rad(0.01)])
    record = record_from_estimates(
        names,
        values,
        np.diag(sigmas**2),
        device=Device(serial=7, node_id=16),
        plan="vehicle",
        conditions=Conditions(g=G, latitude_deg=None, temp_c=None),
    )
    report = AcceptanceReport((Check("worst bias σ", 0.1, 5.0, "mg", True, "max_bias_sigma_mg"),))
    level = LevelChecked(16, "before", 0.02, (0.1, -0.2), 0.001, (0.0, 0.01))
    facts = SessionFacts(
        scales=Scales(lsb, gyro_lsb, G),
        verified=tuple(_after(0.0012)),  # the verification table's cells are checked too
        plan_times="position 1 120 s (it measures the noise), then at most 60 s each",
    )
    text = certificate_markdown(
        record, Identity(1, 2, 3, 7, "imu"), report, LIMITS, [level], facts=facts
    )
    assert "| 1/2: alpha 10°, beta 0°, psi 0° | +10.20 mg | +0.12 mg | 1.00° | 0.10° |" in text
    units = {q.shown_unit for q in QUANTITIES.values()} | {
        q.operator_unit for q in QUANTITIES.values()
    }
    units |= {"m/s²", "°", "°,"}
    rows = [line for line in text.splitlines() if line.startswith("| ") and "---" not in line]
    values_rows = [r for r in rows if r.split("|")[1].strip().startswith(("accel", "gyro", "base"))]
    assert len(values_rows) == 3 + 9 + 3 + 9 + 9 + 2  # biases, K, S, G (held), tilt
    for row in rows[1:]:
        for cell in row.strip("|").split("|")[1:]:
            assert not _bare_numbers(cell.strip(), units), (row, cell)
    by_name = {r.split("|")[1].strip(): r.split("|")[2:4] for r in values_rows}
    device, operator = by_name["accel.bias[0]"]
    assert device.strip() == "2 ± 0.1 counts"
    assert operator.strip() == f"{2.0 * lsb / G * 1e3:.4g} ± {0.1 * lsb / G * 1e3:.2g} mg"
    assert by_name["accel.K[1][1]"][1].strip().startswith("120 ± ")  # ppm from nominal
    assert by_name["accel.K[1][1]"][1].strip().endswith(" ppm")
    assert by_name["base tilt alpha0"][0].strip() == "0.5 ± 0.01 deg"
    assert by_name["gyro.bias[2]"][1].strip().endswith(" °/s")
    assert "None" not in text and "latitude not given" in text
