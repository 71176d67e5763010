"""The calibration certificate: a Markdown page and a printable HTML page beside the JSON.

Identity, date, operator and site, conditions, units, every value ± σ (k = 1; null: held at
nominal), the acceptance limits and how the result met them, whether it was written, the
verification verdict, whether the warm-up was skipped, the level check before the write
(new parameters applied in software to the session's level position), the verification
poses re-read after it (:mod:`canimucal.procedure.verification`: |f| − g and the tilt error
of each, against their limits), and the warnings. Device text is escaped for Markdown and
HTML.
"""

from __future__ import annotations

import html
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from canimucal.analysis.acceptance import AcceptanceLimits, AcceptanceReport
from canimucal.io.calibration import Calibration, Verification, calibration_to_dict
from canimucal.model.mounting import MountingMap
from canimucal.model.sensor import STANDARD_GRAVITY
from canimucal.model.vocabulary.plans import PLANS
from canimucal.model.vocabulary.units import QUANTITIES, Scales, operator_value, with_unit
from canimucal.untrusted import markdown_text

if TYPE_CHECKING:
    # python-can and canopen load with a bus, not with a certificate; the procedure's events
    # and the plan forecast are annotations here (`solve` prints value_rows without them)
    from canimucal.device.client import Identity
    from canimucal.procedure.events import LevelChecked, PoseVerified
    from canimucal.runtime.plan_forecast import LimitForecast

K1_STATEMENT = (
    "Every ± is one standard uncertainty (k = 1, about 68 % coverage for a normal "
    "distribution); for about 95 % multiply by 2 (k = 2)."
)
UNITS = (
    "Units: "
    + "; ".join(f"{q.family} in {q.unit_words}" for q in QUANTITIES.values())
    + "; |f| − g in m/s². Beside them, in the operator's units: a scale factor's diagonal "
    "in ppm from nominal."
)


@dataclass(frozen=True)
class SessionFacts:
    """What the session knows beyond the record: who, where, what was done to the device."""

    operator: str | None = None
    site: str | None = None
    written: bool = False
    verification: Verification | None = None
    warmup: str = "not required"
    """``waited until stable``, ``skipped by the operator`` or ``not required``."""
    mounting: str = ""
    """How the unit sat in the vehicle (``x=forward,y=down,z=left``, where it came from); ""
    when the instructions were worded in the unit's own axes."""
    scales: Scales | None = None
    """The node's nominal LSBs and g: the values in the operator's units (mg, ppm, °, °/s)
    beside the device's (None: the device's only)."""
    plan_times: str = ""
    """The plan's times as the plan screen showed them before the first position
    (:meth:`~canimucal.procedure.averaging.PlanSchedule.words`; "" unknown)."""
    forecast: tuple[LimitForecast, ...] = ()
    """Each acceptance limit beside the σ the plan predicted before the first position
    (:func:`~canimucal.runtime.plan_forecast.forecast`; empty: not known)."""
    verified: tuple[PoseVerified, ...] = ()
    """The verification poses re-read after the write, in order (empty: none)."""
    trim_object: bool | None = None
    """Whether the node has the mounting-trim object 0x2122 (None: not known, nothing was
    written); a node without it was written without the trim."""


def mounting_text(mounting: MountingMap | None, note: str = "") -> str:
    """Return the certificate's mounting line: the map and its origin ("" in body axes)."""
    if mounting is None:
        return ""
    return note or mounting.text()


NORM_KEY, TILT_KEY = "max_verify_norm_error_mg", "max_verify_tilt_error_deg"
"""The verification's limits (:class:`AcceptanceLimits`), the keys of its values."""


def verification_of(
    verified: Sequence[PoseVerified], written: bool, limits: AcceptanceLimits, g: float
) -> Verification:
    """Judge the poses re-read after the write: each |f| − g and tilt error within its limit.

    ``values`` hold the worst of the poses. Not done (``done`` false, ``passed`` false) when
    nothing was written or the session ended before every verification pose was re-read.
    """
    limit = {NORM_KEY: limits.max_verify_norm_error_mg, TILT_KEY: limits.max_verify_tilt_error_deg}
    if not written or not verified or len(verified) < verified[0].total:
        return Verification(passed=False, done=False, written=written, limits=limit)
    norm_mg = max(abs(v.norm_error_calibrated_ms2) for v in verified) / g * 1000.0
    tilt_deg = max(v.tilt_error_calibrated_deg for v in verified)
    return Verification(
        passed=norm_mg <= limit[NORM_KEY] and tilt_deg <= limit[TILT_KEY],
        done=True,
        written=True,
        limits=limit,
        values={NORM_KEY: norm_mg, TILT_KEY: tilt_deg},
    )


def verification_verdict(v: Verification | None, acceptance_passed: bool) -> str:
    """Say what was verified; "PASSED" only when the calibration's acceptance passed too.

    The verification re-reads poses after the write: it shows the device applies the values
    and that they hold away from the level pose, not that their σ is good enough, so a failed
    acceptance is never "PASSED" beside it (issue 22).
    """
    if v is None or not v.done:
        return "NOT DONE (the session ended before the verification poses were re-read)"
    norm, tilt = v.values.get(NORM_KEY, float("nan")), v.values.get(TILT_KEY, float("nan"))
    what = (
        f"the verification poses re-read after the write: worst abs(f) − g {norm:.3g} mg "
        f"(limit {v.limits.get(NORM_KEY, float('nan')):g} mg), worst tilt error {tilt:.3g}° "
        f"(limit {v.limits.get(TILT_KEY, float('nan')):g}°)"
    )
    if not v.passed:
        return f"FAILED: {what}"
    if not acceptance_passed:
        return (
            f"re-read checked ({what}), but the calibration's acceptance FAILED: the device "
            "applies the values written, their uncertainty is beyond the limits"
        )
    return f"PASSED: {what}"


NOT_ESTIMATED = "nominal (not estimated)"


def _cells(
    family: str, value: Any, sigma: Any, scales: Scales | None, diagonal: bool
) -> tuple[str, str]:
    """``(12.3 ± 0.1 counts, 6.01 ± 0.05 mg)``: the file's unit and the operator's."""
    if value is None:
        return NOT_ESTIMATED, "—"
    quantity = QUANTITIES[family]
    device = with_unit(value, sigma, quantity.shown_unit)
    if scales is None:
        return device, "—"
    per_file = quantity.file_per_unit  # the file holds the base tilt in degrees
    shown = operator_value(family, value / per_file, scales, diagonal=diagonal)
    shown_sigma = None if sigma is None else abs(operator_value(family, sigma / per_file, scales))
    return device, with_unit(shown, shown_sigma, quantity.operator_unit, digits=4)


def _vector_rows(
    family: str, values: Any, sigmas: Any, scales: Scales | None
) -> list[tuple[str, str, str]]:
    if values is None:
        return []
    sig = sigmas or [None] * len(values)
    pairs = zip(values, sig, strict=False)
    return [
        (f"{family}[{i}]", *_cells(family, v, s, scales, False)) for i, (v, s) in enumerate(pairs)
    ]


def _matrix_rows(
    family: str, values: Any, sigmas: Any, scales: Scales | None
) -> list[tuple[str, str, str]]:
    if values is None:
        return []
    rows = []
    for i, row in enumerate(values):
        sig_row = sigmas[i] if sigmas else [None] * 3
        pairs = zip(row, sig_row, strict=False)
        rows += [
            (f"{family}[{i}][{j}]", *_cells(family, v, s, scales, i == j))
            for j, (v, s) in enumerate(pairs)
        ]
    return rows


def value_rows(d: dict[str, Any], scales: Scales | None) -> list[tuple[str, str, str]]:
    """Every value of a calibration document: name, value ± σ (device), (operator's units).

    The certificate's table and ``solve``'s text; a value held at nominal reads so.
    """
    accel, gyro = d["accel"], d.get("gyro") or {}
    rows = _vector_rows("accel.bias", accel.get("bias"), accel.get("bias_sigma"), scales)
    rows += _matrix_rows("accel.K", accel.get("K"), accel.get("K_sigma"), scales)
    rows += _vector_rows("gyro.bias", gyro.get("bias"), gyro.get("bias_sigma"), scales)
    rows += _matrix_rows("gyro.S", gyro.get("S"), gyro.get("S_sigma"), scales)
    rows += _matrix_rows("gyro.G", gyro.get("G"), gyro.get("G_sigma"), scales)
    tilt = d.get("base_tilt_deg")
    if tilt:
        sig = tilt.get("sigma") or [None, None]
        for k, key in enumerate(("alpha0", "beta0")):
            rows.append(
                (f"base tilt {key}", *_cells("base_tilt", tilt.get(key), sig[k], scales, False))
            )
    trim = d.get("mounting_trim_deg")
    if trim:
        sig = trim.get("sigma") or [None, None, None]
        for k, key in enumerate(("alpha", "beta", "psi")):
            cells = _cells("mounting_trim", trim.get(key), sig[k], scales, False)
            rows.append((f"mounting trim {key}", *cells))
    return rows


def _values_table(d: dict[str, Any], scales: Scales | None) -> list[str]:
    lines = [
        "| parameter | value ± σ (device) | value ± σ (operator's units) |",
        "|---|---|---|",
    ]
    return lines + [
        f"| {name} | {device} | {shown} |" for name, device, shown in value_rows(d, scales)
    ]


def trim_text(record: Calibration, facts: SessionFacts) -> str:
    """Say what became of the mounting trim: written (the alignment it applies), or not."""
    trim = record.mounting_trim_deg
    if trim is None:
        return "not determined by this plan (its K holds any rotation of the unit's axes); " + (
            "zero written to 0x2122" if facts.written and facts.trim_object else "none"
        )
    sigma = trim.sigma or (None, None, None)
    values = (trim.alpha, trim.beta, trim.psi)
    parts = ", ".join(
        f"{axis} {with_unit(v, s, '°', digits=3)}" if v is not None else f"{axis} not determined"
        for axis, v, s in zip(("alpha", "beta", "psi"), values, sigma, strict=True)
    )
    if not facts.written:
        return f"{parts}: not written"
    if facts.trim_object is False:
        return (
            f"{parts}: NOT written: the node has no mounting-trim object 0x2122 (a firmware "
            "before it, 39-object CRC); its output is not aligned"
        )
    return f"{parts}: written to 0x2122, the node's output is aligned to the vehicle"


def _or_not_given(value: Any, unit: str) -> str:
    """``48.1°``, ``12.5 °C``, or ``not given``: never ``None°``."""
    return "not given" if value is None else f"{value:g}{unit}"


def _fit_text(fit: dict[str, Any]) -> str:
    """``rms 0.0012 m/s², dof 30``, or ``not given`` for a record without a fit."""
    if fit.get("rms") is None:
        return "not given"
    return f"rms {fit['rms']:.3g} m/s², dof {fit.get('dof')}"


def _conditions(cond: dict[str, Any]) -> str:
    return (
        f"g = {_or_not_given(cond.get('g'), ' m/s²')}, "
        f"latitude {_or_not_given(cond.get('latitude_deg'), '°')}, "
        f"height {_or_not_given(cond.get('height_m'), ' m')}, "
        f"heading {_or_not_given(cond.get('heading_deg'), '°')}, "
        f"temperature {_or_not_given(cond.get('temp_c'), ' °C')}"
    )


def verified_line(event: PoseVerified, g: float = STANDARD_GRAVITY) -> str:
    """One verification pose in a line: |f| − g (mg) and the tilt error (°), nominal → new."""
    to_mg = 1000.0 / g
    return (
        f"node {event.node_id} verification {event.index + 1}/{event.total}: |f|−g nominal "
        f"{event.norm_error_nominal_ms2 * to_mg:+.2f} → calibrated "
        f"{event.norm_error_calibrated_ms2 * to_mg:+.2f} mg; tilt error nominal "
        f"{event.tilt_error_nominal_deg:.2f}° → calibrated {event.tilt_error_calibrated_deg:.2f}°"
    )


def verified_lines(verified: Sequence[PoseVerified], g: float) -> list[str]:
    """Return the verification poses as a table: |f| − g and tilt error, nominal and new."""
    if not verified:
        return ["No verification pose was re-read after the write."]
    lines = [
        "| pose | abs(f) − g nominal | abs(f) − g calibrated | tilt error nominal | "
        "tilt error calibrated |",
        "|---|---|---|---|---|",
    ]
    for v in verified:
        alpha, beta, psi = (float(np.rad2deg(x)) for x in v.position.angles)
        lines.append(
            f"| {v.index + 1}/{v.total}: alpha {alpha:g}°, beta {beta:g}°, psi {psi:g}° | "
            f"{v.norm_error_nominal_ms2 / g * 1000:+.2f} mg | "
            f"{v.norm_error_calibrated_ms2 / g * 1000:+.2f} mg | "
            f"{v.tilt_error_nominal_deg:.2f}° | {v.tilt_error_calibrated_deg:.2f}° |"
        )
    return lines


def _level_lines(checks: Sequence[LevelChecked]) -> list[str]:
    if not checks:
        return ["No level position was measured."]
    lines = [
        "| stage | parameters | abs(f) − g | tilt alpha, beta |",
        "|---|---|---|---|",
    ]
    for c in sorted(checks, key=lambda c: c.stage != "before"):
        stage = "before write (session data)" if c.stage == "before" else "after write (re-read)"
        lines.append(
            f"| {stage} | nominal | {c.norm_error_nominal_ms2:+.4f} m/s² | "
            f"{c.tilt_nominal_deg[0]:+.3f}°, {c.tilt_nominal_deg[1]:+.3f}° |"
        )
        lines.append(
            f"| {stage} | calibrated | {c.norm_error_calibrated_ms2:+.4f} m/s² | "
            f"{c.tilt_calibrated_deg[0]:+.3f}°, {c.tilt_calibrated_deg[1]:+.3f}° |"
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
    facts: SessionFacts | None = None,
) -> str:
    """Render the certificate of one node's calibration as Markdown."""
    facts = facts or SessionFacts()
    d = calibration_to_dict(record)
    verdict = "PASSED" if acceptance.passed else "NOT PASSED"
    lines = [
        *_head(d, identity, facts),
        "",
        "## Verdict",
        "",
        f"- Acceptance: {verdict}",
        f"- Written to the device: {'yes' if facts.written else 'no'}",
        f"- Mounting trim: {trim_text(record, facts)}",
        f"- Verification: {verification_verdict(facts.verification, acceptance.passed)}",
        f"- Warm-up: {facts.warmup}",
        "",
        "## Values",
        "",
        K1_STATEMENT,
        UNITS,
        "",
        *_values_table(d, facts.scales),
        "",
        f"## Acceptance limits: {verdict}",
        "",
        *[f"- {c.line()}" for c in acceptance.checks],
        f"- limits: bias σ ≤ {limits.max_bias_sigma_mg:g} mg, scale σ ≤ "
        f"{limits.max_scale_sigma_ppm:g} ppm, rms ≤ {limits.max_rms_ms2:g} m/s², "
        f"χ² p ≥ {limits.min_fit_p:g}; after the write, at each verification pose, "
        f"abs(f) − g ≤ {limits.max_verify_norm_error_mg:g} mg and tilt error ≤ "
        f"{limits.max_verify_tilt_error_deg:g}°",
    ]
    if acceptance.held_nominal:
        lines.append(f"- held at nominal: {', '.join(acceptance.held_nominal)}")
    lines += [f"- {line}" for line in _predicted_lines(facts)]
    lines += ["", "## Level check", "", *_level_lines(level_checks)]
    if facts.verified:
        lines += ["", "## Verification poses after the write", "", *_verified_table(facts)]
    if record.verification is not None and not record.verification.done:
        lines += [
            "",
            "## Verification: NOT DONE",
            "",
            "The calibration was written to the device, but the session ended before the "
            "verification poses were re-read: the device holds these values unverified.",
        ]
    if warnings:
        lines += ["", "## Warnings", "", *[f"- {w}" for w in warnings]]
    lines += ["", "## Sign-off", "", "Operator: ______________________  Date: ____________"]
    return "\n".join(lines) + "\n"


def _verified_table(facts: SessionFacts) -> list[str]:
    """Return the verification table, then each pose's wording."""
    g = facts.scales.g if facts.scales is not None else STANDARD_GRAVITY
    words = [f"- pose {v.index + 1}: {_one_line(v.words)}" for v in facts.verified]
    return [*verified_lines(facts.verified, g), "", *words]


def _one_line(words: str) -> str:
    return " ".join(words.split())


def _predicted_lines(facts: SessionFacts) -> list[str]:
    """``predicted before position 1: worst bias σ ≤ 12 mg: plan predicts 10.1 mg, …``."""
    return [f"predicted before position 1: {r.line()}" for r in facts.forecast if r.predicted]


def _times_text(d: dict[str, Any], facts: SessionFacts) -> str:
    """``planned: position 1 120 s, then …; averaged 120, 60, … s`` (the record's seconds)."""
    seconds = [p.get("seconds") for p in d.get("positions") or []]
    averaged = ", ".join(f"{s:.3g}" for s in seconds if isinstance(s, int | float))
    parts = [f"planned {facts.plan_times}"] if facts.plan_times else []
    if averaged:
        parts.append(f"averaged {averaged} s")
    return "; ".join(parts) or "not given"


def _plan_text(d: dict[str, Any], escape: Callable[[str], str]) -> str:
    """``recommended (two stands turned four ways: …)``: the plan and its registry wording."""
    name = str(d.get("plan", "unknown"))
    entry = PLANS.get(name)
    return escape(name) if entry is None else f"{escape(name)} ({escape(entry.description)})"


def _head(d: dict[str, Any], identity: Identity, facts: SessionFacts) -> list[str]:
    cond = d.get("conditions") or {}
    fit = d.get("fit") or {}
    name = markdown_text(identity.device_name or "IMU")
    return [
        f"# Calibration certificate — {name} serial {identity.serial}",
        "",
        f"- Date (UTC): {d.get('created', 'unknown')}",
        f"- Operator: {markdown_text(facts.operator) if facts.operator else 'not given'}",
        f"- Site: {markdown_text(facts.site) if facts.site else 'not given'}",
        f"- Device: node {d['device'].get('node_id')}, vendor 0x{identity.vendor_id:08X}, "
        f"product 0x{identity.product_code:08X}, revision 0x{identity.revision:08X}, "
        f"hardware {markdown_text(identity.hardware_version) or '—'}, "
        f"software {markdown_text(identity.software_version) or '—'}",
        f"- Plan: {_plan_text(d, markdown_text)}, {len(d.get('positions') or [])} positions",
        f"- Times: {_times_text(d, facts)}",
        f"- Mounting: {markdown_text(facts.mounting) if facts.mounting else 'unit axes (bench)'}",
        f"- Conditions: {_conditions(cond)}",
        f"- Fit: {_fit_text(fit)}",
    ]


_PAGE_STYLE = """
@page { size: A4; margin: 12mm; }
body { font: 9pt/1.25 sans-serif; margin: 0; }
h1 { font-size: 13pt; margin: 0 0 4pt; }
h2 { font-size: 10pt; margin: 8pt 0 3pt; border-bottom: 0.5pt solid #000; }
table { border-collapse: collapse; width: 100%; }
td, th { border: 0.5pt solid #888; padding: 1pt 4pt; text-align: left; vertical-align: top; }
.verdict td:first-child, .facts td:first-child { width: 30%; font-weight: bold; }
.pass { font-weight: bold; } .fail { font-weight: bold; text-decoration: underline; }
.columns { display: flex; gap: 8pt; } .columns > div { flex: 1; }
.small { font-size: 8pt; } .sign { margin-top: 14pt; }
"""


def certificate_html(
    record: Calibration,
    identity: Identity,
    acceptance: AcceptanceReport,
    limits: AcceptanceLimits,
    level_checks: Sequence[LevelChecked],
    *,
    warnings: Sequence[str] = (),
    facts: SessionFacts | None = None,
) -> str:
    """Render the certificate as one printable HTML page (A4, no scripts, no external files)."""
    facts = facts or SessionFacts()
    d = calibration_to_dict(record)
    e = html.escape
    cond = d.get("conditions") or {}
    fit = d.get("fit") or {}
    name = e(identity.device_name or "IMU")
    verdict = "PASSED" if acceptance.passed else "NOT PASSED"
    facts_rows = [
        ("Instrument", f"{name}, serial {identity.serial}, node {d['device'].get('node_id')}"),
        (
            "Identity",
            f"vendor 0x{identity.vendor_id:08X}, product 0x{identity.product_code:08X}, "
            f"revision 0x{identity.revision:08X}",
        ),
        ("Date (UTC)", e(str(d.get("created", "unknown")))),
        ("Operator", e(facts.operator) if facts.operator else "not given"),
        ("Site", e(facts.site) if facts.site else "not given"),
        ("Plan", f"{_plan_text(d, e)}, {len(d.get('positions') or [])} positions"),
        ("Times", e(_times_text(d, facts))),
        ("Mounting", e(facts.mounting) if facts.mounting else "unit axes (bench)"),
        ("Conditions", e(_conditions(cond))),
        ("Fit", e(_fit_text(fit))),
    ]
    verdict_rows = [
        ("Acceptance", _mark(verdict, acceptance.passed)),
        ("Written to the device", "yes" if facts.written else "no"),
        ("Mounting trim", e(trim_text(record, facts))),
        (
            "Verification",
            _mark(
                e(verification_verdict(facts.verification, acceptance.passed)),
                facts.verification is not None and facts.verification.passed and acceptance.passed,
            ),
        ),
        ("Warm-up", e(facts.warmup)),
    ]
    checks = "".join(f"<li>{e(c.line())}</li>" for c in acceptance.checks)
    checks += "".join(f"<li>{e(line)}</li>" for line in _predicted_lines(facts))
    level = _html_table(_level_lines(level_checks))
    if facts.verified:
        g = facts.scales.g if facts.scales is not None else STANDARD_GRAVITY
        level += "<h2>Verification poses after the write</h2>" + _html_table(
            verified_lines(facts.verified, g)
        )
        level += (
            '<ul class="small">'
            + "".join(
                f"<li>pose {v.index + 1}: {e(_one_line(v.words))}</li>" for v in facts.verified
            )
            + "</ul>"
        )
    values = _html_table(_values_table(d, facts.scales))
    warning_items = "".join(f"<li>{e(w)}</li>" for w in warnings) or "<li>none</li>"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>Calibration certificate {name} serial {identity.serial}</title>
<style>{_PAGE_STYLE}</style></head><body>
<h1>Calibration certificate — {name} serial {identity.serial}</h1>
<div class="columns"><div><table class="facts">{_rows(facts_rows)}</table></div>
<div><table class="verdict">{_rows(verdict_rows)}</table>
<ul class="small">{checks}</ul></div></div>
<h2>Values</h2>
<p class="small">{e(K1_STATEMENT)} {e(UNITS)}</p>
{values}
<h2>Level check</h2>
{level}
<h2>Warnings</h2>
<ul class="small">{warning_items}</ul>
<p class="sign">Operator signature: ______________________ &nbsp; Date: ____________</p>
</body></html>
"""


def _mark(text: str, passed: bool) -> str:
    return f'<span class="{"pass" if passed else "fail"}">{text}</span>'


def _rows(rows: Sequence[tuple[str, str]]) -> str:
    return "".join(f"<tr><td>{html.escape(k)}</td><td>{v}</td></tr>" for k, v in rows)


def _html_table(markdown_rows: Sequence[str]) -> str:
    """Turn the Markdown table rows above into an HTML table (cells escaped)."""
    if len(markdown_rows) < 2 or not markdown_rows[0].startswith("|"):
        return "<p>" + html.escape(" ".join(markdown_rows)) + "</p>"

    def cells(row: str) -> list[str]:
        return [html.escape(c.strip()) for c in row.strip().strip("|").split("|")]

    head = "".join(f"<th>{c}</th>" for c in cells(markdown_rows[0]))
    body = "".join(
        "<tr>" + "".join(f"<td>{c}</td>" for c in cells(r)) + "</tr>" for r in markdown_rows[2:]
    )
    return f"<table><tr>{head}</tr>{body}</table>"
