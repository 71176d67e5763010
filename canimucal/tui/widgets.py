"""Small widget helpers shared by the screens."""

from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.widgets import DataTable, Static


def passive_table(**kwargs: Any) -> DataTable[str]:
    """Return a DataTable that never takes focus (the screen keeps its keys, enter too)."""
    table: DataTable[str] = DataTable(cursor_type="none", **kwargs)
    table.can_focus = False
    return table


class PlainStatic(Static):
    """A Static whose text is shown as it is, never parsed as markup.

    For text the tool does not write itself: device names, bus channels, file names, error
    messages. ``markup=False`` alone is not enough on every Textual the package allows
    (1.x parses a string in ``update`` regardless: ``[/]`` raised MarkupError), so the text
    goes in as a Rich ``Text``, which no Textual version parses.
    """

    def __init__(self, text: str = "", **kwargs: Any) -> None:
        super().__init__(Text(text), markup=False, **kwargs)

    def update(self, content: Any = "", **kwargs: Any) -> None:
        """Show ``content``; a string is shown literally (``kwargs``: Static's own)."""
        super().update(Text(content) if isinstance(content, str) else content, **kwargs)
