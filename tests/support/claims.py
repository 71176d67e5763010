"""What a write-params message claims the device holds, in RAM and in flash (docs/design.md §9).

The tool's messages name what RAM and flash hold after every ending that is not a plain
success; :func:`claimed` reads the claim back so a test can compare it with the device
(RAM read by SDO, flash from the simulated node's non-volatile memory).
``"old"``/``"new"``: that whole set; ``"invalid"``: valid = 0; ``"unknown"``: the message
says it cannot know (a silent node, a store that was not answered).
"""

from __future__ import annotations

import re

_SET = {
    "the new calibration": "new",
    "the previous calibration": "old",
    "valid = 0": "invalid",
}


def _which(text: str) -> str:
    for phrase, name in _SET.items():
        if text.startswith(phrase):
            return name
    return "unknown"


def claimed(message: str, *, stored: bool = True) -> tuple[str, str]:
    """``(ram, flash)`` as ``message`` states them (see the module doc).

    ``stored``: whether the write was asked to store (``--no-store``: flash never written).
    """
    untouched = "old"  # flash is only ever written by the store
    if "RAM and flash hold the new calibration" in message or (
        "the store had begun: it completed" in message
    ):
        return "new", "new"
    match = re.search(r"RAM and flash hold (.+?)(?: \(|;|$)", message)
    if match:
        which = _which(match.group(1))
        return which, which
    match = re.search(r"RAM holds (.+?)(?:;|$)", message)
    if match and "what flash holds is known only after a power cycle" in message:
        ram = _which(match.group(1))
        if match.group(1).startswith("the new set"):
            ram = "new"
        return ram, "unknown"
    if "store not confirmed" in message:
        return "unknown", "unknown"
    if "rollback incomplete; device invalidated" in message:
        return "invalid", untouched
    if "previous calibration restored from" in message or "nothing written" in message:
        return "old", untouched
    if "the calibration was written, stored and read back" in message:
        return "new", "new"
    if "written and verified (not stored" in message:
        return "new", untouched if stored else "old"
    return "unknown", "unknown"
