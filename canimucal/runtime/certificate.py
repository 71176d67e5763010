"""The calibration certificate: a readable Markdown page saved beside the calibration JSON.

Identity, date, conditions, every value ± σ (null: held at nominal), the acceptance limits
and how the result met them, and the level check before (new parameters applied in software
to the session's level position) and after the write (raw data re-read at level).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from canimucal.analysis.acceptance import AcceptanceLimits, AcceptanceReport
from canimucal.device.client import Identity
from canimucal.io.calibration import Calibration, calibration_to_dict
from canimucal.procedure.events import LevelChecked
from canimucal.untrusted import markdown_text


def _fmt(value: Any, sigma: Any) -> str:
    if value is None:
        return "nominal (not estimated)"
    if sigma is None:
        return f"{value:.6g}"
    return f"{value:.6g} ± {sigma:.2g}"


def _vector_rows(name: str, values: Any, sigmas: Any) -> list[str]:
    if values is None:
        return []
    sig = sigmas or [None] * len(values)
    pairs = zip(values, sig, strict=False)
    return [f"| {name}[{i}] | {_fmt(v, s)} |" for i, (v, s) in enumerate(pairs)]


def _matrix_rows(name: str, values: Any, sigmas: Any) -> list[str]:
    if values is None:
        return []
    rows = []
    for i, row in enumerate(values):
        sig_row = sigmas[i] if sigmas else [None] * 3
        pairs = zip(row, sig_row, strict=False)
        rows += [f"| {name}[{i}][{j}] | {_fmt(v, s)} |" for j, (v, s) in enumerate(pairs)]
    return rows


def _values_table(d: dict[str, Any]) -> list[str]:
    accel, gyro = d["accel"], d.get("gyro") or {}
    lines = ["| parameter | value ± σ |", "|---|---|"]
    lines += _vector_rows("accel.bias (counts)", accel.get("bias"), accel.get("bias_sigma"))
    lines += _matrix_rows("accel.K (counts per m/s²)", accel.get("K"), accel.get("K_sigma"))
    lines += _vector_rows("gyro.bias (counts)", gyro.get("bias"), gyro.get("bias_sigma"))
    lines += _matrix_rows("gyro.S (counts per rad/s)", gyro.get("S"), gyro.get("S_sigma"))
    tilt = d.get("base_tilt_deg")
    if tilt:
        sig = tilt.get("sigma") or [None, None]
        lines.append(f"| base tilt alpha0 (deg) | {_fmt(tilt.get('alpha0'), sig[0])} |")
        lines.append(f"| base tilt beta0 (deg) | {_fmt(tilt.get('beta0'), sig[1])} |")
    return lines


def _level_lines(checks: Sequence[LevelChecked]) -> list[str]:
    if not checks:
        return ["No level position was measured."]
    lines = [
        "| stage | parameters | abs(f) − g (m/s²) | tilt alpha, beta (deg) |",
        "|---|---|---|---|",
    ]
    for c in sorted(checks, key=lambda c: c.stage != "before"):
        stage = "before write (session data)" if c.stage == "before" else "after write (re-read)"
        lines.append(
            f"| {stage} | nominal | {c.norm_error_nominal_ms2:+.4f} | "
            f"{c.tilt_nominal_deg[0]:+.3f}, {c.tilt_nominal_deg[1]:+.3f} |"
        )
        lines.append(
            f"| {stage} | calibrated | {c.norm_error_calibrated_ms2:+.4f} | "
            f"{c.tilt_calibrated_deg[0]:+.3f}, {c.tilt_calibrated_deg[1]:+.3f} |"
        )
    return lines


def certificate_markdown(
    record: Calibration,
    identity: Identity,
    acceptance: AcceptanceReport,
    limits: AcceptanceLimits,
    level_checks: Sequence[LevelChecked],
    *,
    warnings: Sequence[str] = (),
) -> str:
    """Render the certificate of one node's calibration."""
    d = calibration_to_dict(record)
    verdict = "PASSED" if acceptance.passed else "NOT PASSED"
    lines = [
        *_head(d, identity),
        "",
        "## Values",
        "",
        *_values_table(d),
        "",
        f"## Acceptance limits: {verdict}",
        "",
        *[f"- {c.line()}" for c in acceptance.checks],
        f"- limits: bias σ ≤ {limits.max_bias_sigma_mg:g} mg, scale σ ≤ "
        f"{limits.max_scale_sigma_ppm:g} ppm, rms ≤ {limits.max_rms_ms2:g} m/s², "
        f"χ² p ≥ {limits.min_fit_p:g}",
    ]
    if acceptance.held_nominal:
        lines.append(f"- held at nominal: {', '.join(acceptance.held_nominal)}")
    lines += ["", "## Level check", "", *_level_lines(level_checks)]
    if record.verification is not None and not record.verification.done:
        lines += [
            "",
            "## Verification: NOT DONE",
            "",
            "The calibration was written to the device, but the session ended before the "
            "level check after the write: the device holds these values unverified.",
        ]
    if warnings:
        lines += ["", "## Warnings", "", *[f"- {w}" for w in warnings]]
    return "\n".join(lines) + "\n"


def _head(d: dict[str, Any], identity: Identity) -> list[str]:
    cond = d.get("conditions") or {}
    fit = d.get("fit") or {}
    return [
        f"# Calibration certificate — {markdown_text(identity.device_name) or 'IMU'} serial "
        f"{identity.serial}",
        "",
        f"- Date (UTC): {d.get('created', 'unknown')}",
        f"- Device: node {d['device'].get('node_id')}, vendor 0x{identity.vendor_id:08X}, "
        f"product 0x{identity.product_code:08X}, revision 0x{identity.revision:08X}, "
        f"hardware {markdown_text(identity.hardware_version) or '—'}, "
        f"software {markdown_text(identity.software_version) or '—'}",
        f"- Plan: {d.get('plan', 'unknown')}, {len(d.get('positions') or [])} positions",
        f"- Conditions: g = {cond.get('g')} m/s², latitude {cond.get('latitude_deg')}°, "
        f"heading {cond.get('heading_deg')}°, temperature {cond.get('temp_c')} °C",
        f"- Fit: rms {fit.get('rms', float('nan')):.3g} m/s², dof {fit.get('dof')}",
    ]
