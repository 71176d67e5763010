"""TPDO frames while a slow store blocks the simulated node (truth ``store_pdo_mode``)."""

from __future__ import annotations

import pytest

from canimucal.simnode.tpdo_gate import TpdoGate


def _run(mode: str) -> tuple[TpdoGate, list[tuple[int, bytes]], list[tuple[int, bytes]]]:
    sent: list[tuple[int, bytes]] = []
    gate = TpdoGate(mode, lambda cob_id, data: sent.append((cob_id, data)))
    gate.send(0x190, b"\x00")
    with gate.blocking():
        for k in range(1, 4):
            gate.send(0x190, bytes([k]))
        during = list(sent)
    gate.send(0x190, b"\x04")
    return gate, during, sent


@pytest.mark.parametrize(
    ("mode", "during", "after", "dropped"),
    [
        ("drop", [0], [0, 4], 3),
        ("queue", [0], [0, 1, 2, 3, 4], 0),  # late, in order, before anything newer
        ("continue", [0, 1, 2, 3], [0, 1, 2, 3, 4], 0),
    ],
)
def test_frames_during_a_store_are_dropped_queued_or_sent(
    mode: str, during: list[int], after: list[int], dropped: int
) -> None:
    gate, seen_during, sent = _run(mode)
    assert [d[0] for _, d in seen_during] == during
    assert [d[0] for _, d in sent] == after
    assert gate.dropped == dropped
    assert gate.queued == (3 if mode == "queue" else 0)


def test_unknown_mode_is_refused() -> None:
    with pytest.raises(ValueError, match="drop, queue or continue"):
        TpdoGate("hold", lambda *_: None)
