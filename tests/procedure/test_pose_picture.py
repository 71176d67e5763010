"""Pose pictures (SVG) and the field guide generated from them."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from canimucal.model.positions import Pose
from canimucal.model.vocabulary.plans import builtin_names, builtin_plan
from canimucal.procedure.pose_picture import body_axes_in_level, pose_svg, to_screen
from canimucal.runtime.plan_forecast import field_guide_pages

DOCS = Path(__file__).resolve().parents[2] / "docs"
SVG = "{http://www.w3.org/2000/svg}"


def _arrow_ends(svg: str) -> dict[str, tuple[float, float, float, float]]:
    """Each body axis arrow's line (x1, y1, x2, y2), by its colour."""
    root = ET.fromstring(svg)
    colours = {"#c0392b": "x", "#27ae60": "y", "#2455a4": "z"}
    out = {}
    for line in root.iter(f"{SVG}line"):
        name = colours.get(line.get("stroke", ""))
        if name:
            out[name] = tuple(float(line.get(k, "nan")) for k in ("x1", "y1", "x2", "y2"))
    return out


def test_level_unit_has_y_down_and_x_right_on_screen() -> None:
    ends = _arrow_ends(pose_svg(Pose(0.0, 0.0), "level"))
    x1, y1, x2, y2 = ends["y"]
    assert abs(x2 - x1) < 1e-6 and y2 > y1 + 30  # body +y points down (L y is Down)
    x1, y1, x2, y2 = ends["x"]
    assert x2 > x1 + 30 and abs(y2 - y1) < 1e-6  # body +x points East


def test_alpha_tilt_lowers_the_x_end_as_the_instruction_says() -> None:
    ends = _arrow_ends(pose_svg(Pose(float(np.deg2rad(10.0)), 0.0)))
    x1, y1, x2, y2 = ends["x"]
    slope = np.rad2deg(np.arctan2(y2 - y1, x2 - x1))  # screen y grows downward
    assert slope == np.clip(slope, 9.0, 11.0)  # "tilt 10° about z (lower the +x end)"
    axes = body_axes_in_level(Pose(0.3, -0.2, 1.0))
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(to_screen(np.zeros(3)), [150.0, 130.0])


def test_device_free_text_is_escaped() -> None:
    ET.fromstring(pose_svg(Pose(0.0, 0.0), "a <b> & c"))  # well-formed XML


def test_committed_field_guide_is_current() -> None:
    """docs/field-guide.md and its pictures are what scripts/make_field_guide.py writes."""
    markdown, pictures = field_guide_pages()
    assert (DOCS / "field-guide.md").read_text(encoding="utf-8") == markdown
    for name, svg in pictures.items():
        assert (DOCS / "field-guide" / name).read_text(encoding="utf-8") == svg, name
    linked = set(re.findall(r"\(field-guide/([^)]+\.svg)\)", markdown))
    assert linked == set(pictures)
    assert len(pictures) == sum(len(builtin_plan(n).positions) for n in builtin_names())
    assert "held at the factory K" in markdown  # the vehicle plan states its prior
