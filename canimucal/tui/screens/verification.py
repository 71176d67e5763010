"""The verification screen: the verdict, the poses re-read after the write, and the files.

Each node's verdict is the certificate's line (never "PASSED" beside a failed acceptance);
each verification pose its |f| − g and tilt error, nominal and calibrated; then the level
check of the session's data and the files written.
"""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import Screen
from textual.widgets import Footer, Static

from canimucal.procedure import events as ev
from canimucal.runtime.certificate import verified_line
from canimucal.tui.text import level_line
from canimucal.tui.widgets import PlainStatic


def verification_text(
    checks: list[ev.LevelChecked],
    saved: list[ev.RecordSaved],
    writes: list[ev.WriteFinished],
    finished: ev.ProcedureFinished,
    verified: list[ev.PoseVerified] | None = None,
    verdicts: dict[int, str] | None = None,
) -> str:
    """Everything the screen says, as text."""
    lines = ["cancelled: what was recorded is kept" if finished.cancelled else "finished"]
    lines += list(finished.notes)
    lines += [f"node {n} verification: {text}" for n, text in (verdicts or {}).items()]
    lines.append("")
    if verified:
        lines.append("verification poses re-read after the write:")
        for v in verified:
            lines.append(verified_line(v))
            lines.append(f"    pose: {' '.join(v.words.split())}")
        lines.append("")
    lines.append("level check of the session's data (|f| − g and tilt at the level pose):")
    lines += [level_line(c) for c in checks] or ["  none (no level position solved)"]
    lines.append("")
    for w in writes:
        backup = f"; backup {w.backup_path}" if w.backup_path else ""
        lines.append(f"write node {w.node_id}: {w.message}{backup}")
    for s in saved:
        lines.append(f"node {s.node_id}: {s.record_path}")
        lines.append(f"  certificate {s.certificate_path}")
        lines.append(f"  recording {s.recording_path}")
    return "\n".join(lines)


class VerificationScreen(Screen[None]):
    """Shown when the procedure ends; q quits."""

    BINDINGS = [Binding("q", "app.quit", "Quit")]

    def __init__(
        self,
        checks: list[ev.LevelChecked],
        saved: list[ev.RecordSaved],
        writes: list[ev.WriteFinished],
        finished: ev.ProcedureFinished,
        *,
        verified: list[ev.PoseVerified] | None = None,
        verdicts: dict[int, str] | None = None,
    ) -> None:
        super().__init__()
        self.text = verification_text(checks, saved, writes, finished, verified, verdicts)

    def compose(self) -> ComposeResult:
        """Title and the text."""
        yield Static("canimucal · verification", classes="screen-title")
        with VerticalScroll():
            yield PlainStatic(self.text, id="verification-text")  # paths, device words
        yield Footer()
