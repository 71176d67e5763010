"""Find the numbers of a text that carry no unit (issue 22 item 6: every number has a unit).

A number counts as carrying its unit when the text right after it names one (``12.3 mg``,
``0.5°``, ``4.2 counts/√Hz``), or when it is a count or a ratio by its own wording: after
``×``, ``p = ``, ``χ² = ``, ``χ²/dof = ``, ``position``/``pos``/``node``/``verification``,
or before ``dof``, ``segments``, ``%`` or ``σ``. The first number of a range (``15–120 s``)
takes the unit of the second, a value the unit of its σ (``12.3 ± 0.1 counts``).
"""

from __future__ import annotations

import re
from collections.abc import Iterable

NUMBER = re.compile(r"(?<![\w.\[])[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
UNITS = (
    "counts",
    "cnt",
    "mg",
    "ppm",
    "°/s",
    "°",
    "deg",
    "m/s²",
    "rad/s",
    "rad",
    "s",
    "Hz",
    "m",
    "(°/s)/g",
)
COUNTS_OF_THINGS = ("dof", "segments", "%", "σ", "values", "positions", "poses")
RATIO_WORDS = ("×", "p = ", "χ² = ", "χ²/dof = ", "p-value ", "ratio ")
INDEX_WORDS = ("position ", "positions ", "pos ", "node ", "verification ", "/")


def bare_numbers(text: str, labels: Iterable[str] = ()) -> list[str]:
    """Return each number of ``text`` without a unit, with what follows it (module doc).

    ``labels``: leading words of a line that are names, not values (``accel.K[0][0]``,
    a table's position column), skipped with the rest of their token.
    """
    out = []
    for line in text.splitlines():
        stripped = line.strip()
        for label in labels:
            if stripped.startswith(label):
                stripped = stripped[len(label) :]
        for m in NUMBER.finditer(stripped):
            before, after = stripped[: m.start()], stripped[m.end() :]
            if after.startswith(("–", "][", " ± ")):
                continue  # a range or a value ± σ (the unit follows), or an index
            if before.endswith(RATIO_WORDS) or before.endswith(INDEX_WORDS):
                continue
            rest = after.lstrip()
            if rest.startswith(UNITS) or rest.startswith(COUNTS_OF_THINGS):
                continue
            out.append(f"{m.group(0)!r} in {line.strip()!r}")
    return out
