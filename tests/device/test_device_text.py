"""Untrusted device text (issue 13, failure 6): escaped everywhere, uploads bounded.

The simulated node presents any identity through the truth JSON (``device_name``,
``hardware_version``, ``software_version``); the tool must show none of it raw.
"""

from __future__ import annotations

import re

from canimucal.analysis.acceptance import AcceptanceLimits, AcceptanceReport, Check
from canimucal.device.client import Identity
from canimucal.io.calibration import Calibration
from canimucal.runtime.certificate import certificate_markdown
from canimucal.untrusted import markdown_text, markup_text, printable
from tests.device.test_write_faults import calibration

HOSTILE = "\x1b]0;pwned\x07\x1b[2J\x1b[H\r\nnode 16: FAKE, serial 1\x9b31m\u202e[/]"
MARKDOWN = "IMU\n\n## Acceptance limits: PASSED\n\n<script>alert(1)</script> [x](http://e)"
CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")


def test_printable_escapes_every_control_and_keeps_plain_text() -> None:
    assert printable("canimucal IMU v1.2 (ü)") == "canimucal IMU v1.2 (ü)"
    out = printable(HOSTILE)
    assert not CONTROL.search(out) and "\n" not in out
    assert out.startswith("\\x1b]0;pwned\\x07\\x1b[2J") and "\\u202e" in out
    assert printable(out) == out  # idempotent: escaping again for Markdown does not double


def test_markdown_and_markup_escaping() -> None:
    md = markdown_text(MARKDOWN)
    assert "\n" not in md and "<" not in md and ">" not in md
    assert "\\#\\# Acceptance limits" in md and "&lt;script&gt;" in md and "\\[x\\]" in md
    from textual.markup import to_content

    assert to_content(markup_text("a [/] [b]bold[/b] \x1b")).plain == "a [/] [b]bold[/b] \\x1b"


def test_certificate_cannot_be_forged_by_the_device_name() -> None:
    record = Calibration.from_dict(calibration(1.0, 0.0))
    identity = Identity(1, 2, 3, 4242, printable(MARKDOWN), "<b>hw</b>", "# sw")
    failed = AcceptanceReport((Check("worst bias σ", 9.0, 5.0, "mg", False, "max_bias_sigma_mg"),))
    text = certificate_markdown(record, identity, failed, AcceptanceLimits(), [])
    headings = [line for line in text.splitlines() if line.startswith("#")]
    assert headings[0].startswith("# Calibration certificate — IMU\\\\x0a\\\\x0a\\#\\#")
    verdicts = [h for h in headings if h.startswith("## Acceptance limits")]
    assert verdicts == ["## Acceptance limits: NOT PASSED"], headings
    assert "<b>" not in text and "<script>" not in text and "hardware &lt;b&gt;hw" in text
