"""One device per node-id (docs/design.md §9): a second answerer is refused, exit 4.

Two units set to one node-id both answer every SDO request and both take every write: the
tool would write one calibration into two units and read a mix of both. Before writing (and
in ``read-params``, ``record`` and a session) :func:`refuse_second_answerer` reads the
serial once and listens for more than one answer; during a transaction the running count of
surplus answers (:attr:`ImuClient.extra_sdo_answers`) catches one that appears later.
"""

from __future__ import annotations

from canimucal.device.client import ImuClient
from canimucal.errors import DuplicateNodeError

_COUNT_WORDS = {2: "two", 3: "three", 4: "four"}


def describe_answerers(node_id: int, serials: list[int | None]) -> str:
    """``two devices answer as node 16 (serials 4242 and 5555)``."""
    count = _COUNT_WORDS.get(len(serials), str(len(serials)))
    known = [s for s in serials if s is not None]
    distinct = sorted(set(known))
    if len(distinct) > 1:
        names = ", ".join(map(str, distinct[:-1])) + f" and {distinct[-1]}"
        which = f"serials {names}"
    elif distinct:
        which = (
            f"all serial {distinct[0]}: units with a copied serial, or one that sends "
            "every frame more than once"
        )
    else:
        which = "their serials unreadable"
    return f"{count} devices answer as node {node_id} ({which})"


def refuse_second_answerer(client: ImuClient, consequence: str) -> None:
    """Raise :class:`DuplicateNodeError` when more than one device answers as the node.

    ``consequence`` ends the message (``nothing written``). A node that does not answer at
    all is left to the next transfer, which reports the silence.
    """
    serials = client.answering_serials()
    if len(serials) > 1:
        raise DuplicateNodeError(f"{describe_answerers(client.node_id, serials)}: {consequence}")
