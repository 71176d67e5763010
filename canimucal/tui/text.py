"""Plain-text pieces of the TUI (no Textual): the pose drawing and the formatted numbers.

Kept apart from the widgets so they can be tested and reused by the benchmark; every
function returns ``str`` or rows of ``str``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from canimucal.device.client import CalibrationReadout
from canimucal.model.plan import BoundTable
from canimucal.procedure import events as ev
from canimucal.runtime.plan_forecast import table_cells

Array = NDArray[np.float64]

DRAW_ROWS = 5
DRAW_COLS = 17
MIN_DRAWN_DEG = 12.0


TARGET_MARK = "○"
"""The target bar's marker (5 columns from the centre towards the labelled end)."""
UNIT_MARK = "●"
"""The unit's measured attitude: its marker, drawn over the target's when they coincide."""
UNIT_BAR = "·"
"""The unit's bar, where the target's does not cover it."""
MARK_T = 5


def _shown(screen_angle_deg: float) -> float:
    """Return the target's screen angle: a small tilt (0.5° to 12°) is drawn at 12°."""
    if 0.5 <= abs(screen_angle_deg) < MIN_DRAWN_DEG:
        return float(np.copysign(MIN_DRAWN_DEG, screen_angle_deg))
    return screen_angle_deg


def _cell(theta: float, t: float) -> tuple[int, int]:
    half = DRAW_COLS // 2
    return int(round(half + t * np.cos(theta))), int(round(DRAW_ROWS // 2 - t * np.sin(theta) / 2))


def _segment(target_deg: float, end_label: str, unit_deg: float | None = None) -> list[str]:
    """Rasterize the target bar at ``target_deg`` (up-right positive) and the unit's bar.

    The unit is drawn at the target's shown angle plus its real difference from the target,
    so the two coincide exactly when the unit is at the target.
    """
    grid = [[" "] * DRAW_COLS for _ in range(DRAW_ROWS)]
    shown = _shown(target_deg)
    theta = np.deg2rad(shown)
    half = DRAW_COLS // 2
    if abs(shown) < 8.0:
        char = "─"
    else:
        char = "/" if shown > 0 else "\\"
    last = (DRAW_ROWS // 2, half)
    for t in np.linspace(-half, half, 4 * DRAW_COLS):
        col, row = _cell(theta, t)
        if 0 <= row < DRAW_ROWS and 0 <= col < DRAW_COLS:
            grid[row][col] = char
            if t > 0:
                last = (row, col)
    row, col = last
    label_col = min(col + 1, DRAW_COLS - len(end_label))
    for k, c in enumerate(end_label):
        grid[row][label_col + k] = c
    col, row = _cell(theta, MARK_T)
    grid[row][col] = TARGET_MARK
    if unit_deg is not None:
        unit = np.deg2rad(shown + unit_deg - target_deg)
        for t in np.linspace(-MARK_T, MARK_T, 4 * MARK_T):
            col, row = _cell(unit, t)
            if 0 <= row < DRAW_ROWS and 0 <= col < DRAW_COLS and grid[row][col] == " ":
                grid[row][col] = UNIT_BAR
        col, row = _cell(unit, MARK_T)
        if 0 <= row < DRAW_ROWS and 0 <= col < DRAW_COLS:
            grid[row][col] = UNIT_MARK
    return ["".join(r) for r in grid]


def pose_drawing(
    alpha_deg: float,
    beta_deg: float,
    psi_deg: float = 0.0,
    measured: tuple[float, float] | None = None,
) -> str:
    """Two side views of the target tilt and, with ``measured``, of the unit's (docs/design.md §2).

    Left: seen from the +z end, +x to the right; positive alpha lowers the +x end.
    Right: seen from the −x side, +z to the right; positive beta raises the +z end.
    ``measured`` is the unit's (alpha, beta) in degrees from the live accelerometer: drawn
    as a dotted bar marked ``●`` beside the target's ``○``, with a legend line.
    """
    unit_alpha, unit_beta = (None, None) if measured is None else measured
    left = _segment(-alpha_deg, "+x", None if unit_alpha is None else -unit_alpha)
    right = _segment(beta_deg, "+z", unit_beta)
    head = f"{'alpha ' + format(alpha_deg, '+.1f') + '°':<{DRAW_COLS}}   "
    head += f"beta {beta_deg:+.1f}°"
    lines = [head]
    lines += [f"{a}   {b}" for a, b in zip(left, right, strict=True)]
    ground = "▔" * DRAW_COLS
    lines.append(f"{ground}   {ground}")
    turn = psi_deg % 360.0
    lines.append(f"turned {turn:g}° on its face" if turn > 1e-9 else "not turned (psi 0°)")
    if measured is None:
        lines.append(f"{TARGET_MARK} target   {UNIT_MARK} unit: no samples yet")
    else:
        lines.append(
            f"{TARGET_MARK} target   {UNIT_MARK} unit α {measured[0]:+.1f}° β {measured[1]:+.1f}°"
        )
    return "\n".join(lines)


def vector(values: Array | None, fmt: str = "+8.4f") -> str:
    """Three numbers in a row (``—`` when missing)."""
    if values is None:
        return "—"
    return " ".join("     nan" if not np.isfinite(v) else format(float(v), fmt) for v in values)


def live_line(event: ev.SamplesReceived) -> str:
    """Format the live readout of one node (four short lines)."""
    tilt = event.tilt_error_deg
    tilt_text = "—" if tilt is None else f"α {tilt[0]:+6.2f}° β {tilt[1]:+6.2f}°"
    motion = event.moving_std_counts
    motion_text = f"{motion:.1f}" if np.isfinite(motion) else "—"
    return (
        f"node {event.node_id} · {event.time_s:.1f} s · {event.temp_c:.1f} °C · "
        f"lost {event.lost_total}\n"
        f"f m/s²  {vector(event.accel_ms2)}\n"
        f"ω rad/s {vector(event.gyro_rads, '+8.5f')}\n"
        f"tilt−target {tilt_text}\n"
        f"motion σ {motion_text} counts"
    )


def short_live_line(event: ev.SamplesReceived) -> str:
    """Format one more node's readout in a single line (several nodes on one body)."""
    tilt = event.tilt_error_deg
    tilt_text = "—" if tilt is None else f"α{tilt[0]:+.1f}° β{tilt[1]:+.1f}°"
    return f"node {event.node_id} {tilt_text} lost {event.lost_total}"


def bound_rows(table: BoundTable) -> list[tuple[str, str, str, str]]:
    """Rows of the Cramér–Rao table: parameter, σ, unit, effect at 1 g (counts), as ``plan``."""
    return table_cells(table)


def findings_text(table: BoundTable) -> str:
    """Say what the plan cannot determine or separate, one line each."""
    lines = [f.message for f in table.separability.findings]
    worst = table.worst_case_counts
    worst_text = f"{worst:.3g} counts" if np.isfinite(worst) else "unbounded"
    lines.insert(0, f"worst-case bound {worst_text} ({table.worst_parameter})")
    if not table.separability.findings:
        lines.append("every parameter is identifiable and separable under this plan")
    return "\n".join(lines)


def device_values(readout: CalibrationReadout | None) -> dict[str, float]:
    """Return the device's current values by name (accel bias, K = M⁻¹, gyro bias, tilt, trim)."""
    if readout is None:
        return {}
    block = readout.block
    out: dict[str, float] = {}
    k = np.linalg.inv(np.asarray(block.accel_correction, dtype=float))
    for i in range(3):
        out[f"accel.bias[{i}]"] = float(block.accel_bias[i])
        out[f"gyro.bias[{i}]"] = float(block.gyro_bias[i])
        for j in range(3):
            out[f"accel.K[{i}][{j}]"] = float(k[i, j])
    out["base_tilt.alpha0"] = float(block.base_tilt_rad[0])
    out["base_tilt.beta0"] = float(block.base_tilt_rad[1])
    if block.mounting_trim_rad is not None:  # a node with 0x2122
        for name, value in zip(("alpha", "beta", "psi"), block.mounting_trim_rad, strict=True):
            out[f"mounting_trim.{name}"] = float(value)
    return out


def calibration_summary(readout: CalibrationReadout | None) -> str:
    """One line: is a calibration active on the device."""
    if readout is None:
        return "not read"
    if readout.valid and readout.crc_ok:
        return "valid, CRC ok"
    if readout.valid:
        return "CRC MISMATCH (nominal in use)"
    return "none (nominal)"


def level_line(event: ev.LevelChecked) -> str:
    """|f| − g and tilt at level, nominal against calibrated."""
    return (
        f"node {event.node_id} {event.stage:<6} |f|−g nominal {event.norm_error_nominal_ms2:+.4f}"
        f" → calibrated {event.norm_error_calibrated_ms2:+.4f} m/s²\n"
        f"    tilt nominal {event.tilt_nominal_deg[0]:+.3f}°, {event.tilt_nominal_deg[1]:+.3f}°"
        f" → calibrated {event.tilt_calibrated_deg[0]:+.3f}°, {event.tilt_calibrated_deg[1]:+.3f}°"
    )
