"""A picture of a pose: the unit drawn in the level frame, as SVG text (no plotting library).

The unit is a box (long along body x, flat along body y, mid along body z) with its body
axes drawn as arrows and labelled; the level frame L (x East, y Down, z North, docs/design.md §2) is
drawn in an oblique projection: screen right = East, screen up = up, North recedes up and to
the right at 30°, foreshortened by half. The box's faces are painted far to near. Gravity is
the arrow beside it. The pose's DCM is :func:`canimucal.model.frames.position_dcm` (body ←
L), so a body vector ``e`` lies along ``Cᵀ e`` in L.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from xml.sax.saxutils import escape

import numpy as np
from numpy.typing import NDArray

from canimucal.model.frames import position_dcm
from canimucal.model.mounting import DEFAULT_MOUNTING
from canimucal.model.positions import Plan, Pose
from canimucal.model.vocabulary.plans import worded_for_vehicle
from canimucal.procedure.averaging import PlanSchedule, plan_schedule
from canimucal.procedure.posecheck import describe_pose

Array = NDArray[np.float64]

HALF_SIZE = np.array([1.6, 0.45, 1.0])
"""Half the box's extent along body x, y, z (drawing units)."""
SCALE = 42.0
"""Pixels per drawing unit."""
WIDTH, HEIGHT = 320, 240
_ORIGIN = np.array([150.0, 130.0])
_RECEDE = 0.5 * np.array([np.cos(np.deg2rad(30.0)), np.sin(np.deg2rad(30.0))])
_AXIS_COLOURS = {"x": "#c0392b", "y": "#27ae60", "z": "#2455a4"}
_FACES = (  # corner sign patterns of each face of the box
    ((1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)),
    ((-1, -1, -1), (-1, 1, -1), (-1, 1, 1), (-1, -1, 1)),
    ((-1, 1, -1), (1, 1, -1), (1, 1, 1), (-1, 1, 1)),
    ((-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)),
    ((-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)),
    ((-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1)),
)


def to_screen(v_level: Array) -> Array:
    """Screen pixels (y down) of a point given in L (x East, y Down, z North)."""
    east, down, north = (float(c) for c in v_level)
    right = east + _RECEDE[0] * north
    up = -down + _RECEDE[1] * north
    return _ORIGIN + SCALE * np.array([right, -up])


def _depth(v_level: Array) -> float:
    """Distance into the picture (North recedes), for painting far faces first."""
    return float(v_level[2])


def body_axes_in_level(pose: Pose) -> Array:
    """Rows: the unit's body x, y, z unit vectors expressed in L (``Cᵀ`` columns)."""
    c = position_dcm(pose.alpha, pose.beta, pose.psi)
    return np.asarray(c, dtype=float)  # row i of C is body axis i in L


def pose_svg(pose: Pose, title: str = "") -> str:
    """Draw ``pose`` as a standalone SVG document (the module doc says how)."""
    axes = body_axes_in_level(pose)
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" '
        f'viewBox="0 0 {WIDTH} {HEIGHT}" font-family="sans-serif" font-size="12">',
        f'<rect width="{WIDTH}" height="{HEIGHT}" fill="white"/>',
    ]
    if title:
        parts.append(f'<text x="8" y="16" font-weight="bold">{escape(title)}</text>')
    ground = [to_screen(np.array([x, 1.6, z])) for x, z in ((-3, -2), (3, -2), (3, 2), (-3, 2))]
    parts.append(_polygon(ground, "#eeeeee", "#bbbbbb"))
    faces = []
    for face in _FACES:
        corners = [np.array(sign) * HALF_SIZE @ axes for sign in face]
        faces.append((np.mean([_depth(c) for c in corners]), corners))
    for _, corners in sorted(faces, key=lambda f: -f[0]):
        parts.append(_polygon([to_screen(c) for c in corners], "#d9d9d9", "#555555", 0.85))
    for name, axis, half in zip("xyz", axes, HALF_SIZE, strict=True):
        start, end = to_screen(np.zeros(3)), to_screen(axis * (half + 0.9))
        colour = _AXIS_COLOURS[name]
        parts.append(_arrow(start, end, colour))
        label = to_screen(axis * (half + 1.15))
        parts.append(
            f'<text x="{label[0]:.1f}" y="{label[1] + 4:.1f}" fill="{colour}" '
            f'text-anchor="middle" font-weight="bold">+{name}</text>'
        )
    g_start, g_end = np.array([282.0, 60.0]), np.array([282.0, 120.0])
    parts.append(_arrow(g_start, g_end, "#000000"))
    middle = (g_start + g_end) / 2
    parts.append(f'<text x="{middle[0] + 8:.0f}" y="{middle[1] + 4:.0f}">g</text>')
    parts.append(
        '<text x="8" y="232" fill="#555555" font-size="10">East →, up ↑, North into the '
        "page ↗ (docs/design.md §2 level frame)</text>"
    )
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


def _polygon(points: Sequence[Array], fill: str, stroke: str, opacity: float = 1.0) -> str:
    coords = " ".join(f"{p[0]:.1f},{p[1]:.1f}" for p in points)
    return (
        f'<polygon points="{coords}" fill="{fill}" fill-opacity="{opacity:g}" '
        f'stroke="{stroke}" stroke-width="1"/>'
    )


def _arrow(start: Array, end: Array, colour: str) -> str:
    direction = end - start
    length = float(np.hypot(*direction))
    if length < 1e-6:
        return ""
    unit = direction / length
    normal = np.array([-unit[1], unit[0]])
    head = [end, end - 9 * unit + 4 * normal, end - 9 * unit - 4 * normal]
    coords = " ".join(f"{p[0]:.1f},{p[1]:.1f}" for p in head)
    return (
        f'<line x1="{start[0]:.1f}" y1="{start[1]:.1f}" x2="{end[0]:.1f}" y2="{end[1]:.1f}" '
        f'stroke="{colour}" stroke-width="2"/><polygon points="{coords}" fill="{colour}"/>'
    )


def field_guide(
    plans: Sequence[Plan], notes: Mapping[str, Sequence[str]] | None = None
) -> tuple[str, dict[str, str]]:
    """Return the field guide's Markdown and its pictures ``{file name: SVG}``, one per pose.

    Each position's seconds and the operator's minutes are the session's
    (:func:`~canimucal.procedure.averaging.plan_schedule`); ``notes`` adds lines under a
    plan's summary, by plan name (the σ it predicts).
    """
    pictures: dict[str, str] = {}
    lines = [
        "# Field guide: the poses of each plan",
        "",
        "Generated by `python scripts/make_field_guide.py` from the built-in plans; do not",
        "edit by hand. Each picture shows the unit at the pose in the level frame (East to",
        "the right, up, North into the page), its body axes +x (red), +y (green, down when",
        "level) and +z (blue), and gravity g. Angles: alpha about body z, then beta about",
        "the new x, then the turn psi about the unit's own y (docs/design.md §2).",
        "",
        "The vehicle plan's poses are also worded for the vehicle, through the mounting map",
        f"`{DEFAULT_MOUNTING.text()}` (the unit flat, +x to the front: the TUI's default",
        "when no map is saved for the unit's serial; `canimucal tui --mount MAP` sets it).",
        "",
    ]
    for plan in plans:
        times = plan_schedule(plan)
        lines += [f"## {plan.name}", "", *_plan_summary(plan, times), ""]
        note = (notes or {}).get(plan.name)
        lines += [*note, ""] if note else []
        for k, (position, seconds) in enumerate(
            zip(plan.positions, times.seconds, strict=True), start=1
        ):
            name = f"{plan.name}-{k}.svg"
            alpha, beta, psi = (float(x) for x in np.rad2deg(position.angles))
            heading = f"{plan.name} {k}: alpha {alpha:g}°, beta {beta:g}°, psi {psi:g}°"
            pictures[name] = pose_svg(position, heading)
            lines += [
                f"### Position {k}: alpha {alpha:g}°, beta {beta:g}°, psi {psi:g}°",
                "",
                f"![{plan.name} position {k}](field-guide/{name})",
                "",
                f"{_one_line(describe_pose(position))}; {seconds:g} s; "
                f"±{np.rad2deg(position.tolerance):g}° 1σ"
                + (
                    f" (turn ±{np.rad2deg(position.psi_tolerance):g}°)"
                    if position.psi_tolerance is not None
                    else ""
                )
                + ".",
                "",
            ]
            if worded_for_vehicle(plan.name):
                words = _one_line(describe_pose(position, DEFAULT_MOUNTING))
                lines += [f"For the vehicle: {words}.", ""]
    return "\n".join(lines).rstrip() + "\n", pictures


def _one_line(words: str) -> str:
    """Put an instruction's steps on one line (the TUI shows one step a line)."""
    return words.replace("\n", " ")


def _plan_summary(plan: Plan, times: PlanSchedule) -> list[str]:
    text = (
        f"{len(plan.positions)} positions, {times.total_seconds:g} s of averaging, about "
        f"{times.operator_minutes:.0f} minutes of the operator's time "
        f"({plan.setup_seconds:g} s to set up each position). Times: {times.times_words()}."
    )
    if plan.prior_k_sigma is not None:
        text += (
            f" What these poses cannot separate is held at the factory K with a stated "
            f"{plan.prior_k_sigma:.0%} 1σ (a prior), which the σ and the certificate include."
        )
    return [text]
