"""Every mounting map the tool accepts: the 24 rotations among the 48 signed permutations."""

from __future__ import annotations

import itertools

from canimucal.errors import InputError
from canimucal.model.mounting import MountingMap

WORDS = ("forward", "back", "left", "right", "up", "down")


def all_proper_maps() -> list[MountingMap]:
    """Return each signed permutation of the vehicle directions that is a proper rotation."""
    maps = []
    for words in itertools.product(WORDS, repeat=3):
        try:
            maps.append(MountingMap(*words))
        except InputError:
            continue
    return maps
