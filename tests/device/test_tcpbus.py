"""The cross-process test bus (``tests/support/tcpbus.py``): relays, order, no loss, shutdown."""

from __future__ import annotations

import os
import time

import can

from tests.support import tcpbus


def _drain(bus: can.BusABC, n: int, timeout_s: float = 10.0) -> list[can.Message]:
    got: list[can.Message] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        msg = bus.recv(0.2)
        if msg is not None:
            got.append(msg)
    return got


def test_frames_go_both_ways_to_every_other_client_in_order() -> None:
    with tcpbus.TcpHub() as hub:
        a, b, c = (tcpbus.TcpBus(hub.channel) for _ in range(3))
        try:
            a.send(
                can.Message(
                    arbitration_id=0x610, data=b"\x40\x18\x10\x01\0\0\0\0", is_extended_id=False
                )
            )
            b.send(can.Message(arbitration_id=0x1ABCDE, data=b"\x01\x02", is_extended_id=True))
            got_b, got_c = _drain(b, 1), _drain(c, 2)
            got_a = _drain(a, 1)
            assert [m.arbitration_id for m in got_b] == [0x610]
            assert (
                bytes(got_b[0].data) == b"\x40\x18\x10\x01\0\0\0\0" and not got_b[0].is_extended_id
            )
            assert sorted(m.arbitration_id for m in got_c) == [0x610, 0x1ABCDE]
            assert got_a[0].is_extended_id and bytes(got_a[0].data) == b"\x01\x02"
            assert a.recv(0.05) is None  # never its own frame back
        finally:
            for bus in (a, b, c):
                bus.shutdown()


def test_no_loss_at_a_modest_rate_across_a_process() -> None:
    n = 2000
    with tcpbus.TcpHub() as hub:
        rx = tcpbus.TcpBus(hub.channel)
        try:
            pid = os.fork()
            if pid == 0:  # the child sends n numbered frames at ~4 kHz, then exits
                code = 0
                try:
                    tx = tcpbus.TcpBus(hub.channel)
                    for i in range(n):
                        tx.send(
                            can.Message(
                                arbitration_id=0x181,
                                data=i.to_bytes(2, "little"),
                                is_extended_id=False,
                            )
                        )
                        if i % 40 == 39:
                            time.sleep(0.01)
                    tx.shutdown()
                except BaseException:
                    code = 1
                os._exit(code)
            got = _drain(rx, n, timeout_s=30.0)
            _, status = os.waitpid(pid, 0)
            assert os.waitstatus_to_exitcode(status) == 0
            assert [int.from_bytes(m.data, "little") for m in got] == list(range(n))
        finally:
            rx.shutdown()
        deadline = time.monotonic() + 2.0
        while hub.clients and time.monotonic() < deadline:
            time.sleep(0.01)
        assert hub.clients == 0  # the sender's and receiver's connections closed cleanly


def test_registered_interface_opens_through_python_can() -> None:
    tcpbus.register()
    with tcpbus.TcpHub() as hub:
        with (
            can.Bus(interface=tcpbus.INTERFACE, channel=hub.channel) as a,
            can.Bus(interface=tcpbus.INTERFACE, channel=hub.channel) as b,
        ):
            assert isinstance(a, tcpbus.TcpBus)
            a.send(can.Message(arbitration_id=0x710, data=b"\x05", is_extended_id=False))
            got = _drain(b, 1)
            assert got and got[0].arbitration_id == 0x710
    closed_hub = tcpbus.TcpHub()
    closed_hub.close()
    try:
        can.Bus(interface=tcpbus.INTERFACE, channel=closed_hub.channel)
    except can.CanInitializationError as exc:
        assert "no CAN hub" in str(exc)
    else:
        raise AssertionError("connected to a closed hub")
