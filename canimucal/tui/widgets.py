"""Small widget helpers shared by the screens."""

from __future__ import annotations

from typing import Any

from textual.widgets import DataTable


def passive_table(**kwargs: Any) -> DataTable[str]:
    """Return a DataTable that never takes focus (the screen keeps its keys, enter too)."""
    table: DataTable[str] = DataTable(cursor_type="none", **kwargs)
    table.can_focus = False
    return table
