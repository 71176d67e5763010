"""A CAN bus shared by separate processes: a TCP hub on 127.0.0.1 and a python-can bus for it.

:class:`TcpHub` listens on an ephemeral port of 127.0.0.1 and relays every frame a client
sends to every *other* connected client, in the order received (like a CAN bus without
``receive_own_messages``). Its ``taps`` see each frame with the sending connection's number
in the hub's thread, so a test can act (send a signal) when a process puts its k-th SDO
request on the bus. :class:`TcpBus` is the :class:`can.BusABC` of one client;
:func:`register` makes it python-can's interface ``canimucal-tcp``, so the CLI's own
``--interface canimucal-tcp --channel 127.0.0.1:PORT`` path opens it unchanged. Traffic never
leaves the machine.

Wire format: one 14-byte record per frame, ``!IBB8s`` = arbitration id, flags (bit 0
extended id, bit 1 remote, bit 2 error frame), data length, data (zero-padded). On joining, the
hub first sends one byte, ``JOINED``, once it relays to the new client; :class:`TcpBus` waits
for it, so a bus that exists has joined (without it a frame sent right after the connection
could be relayed before the hub accepted the new client, which then never saw it).
"""

from __future__ import annotations

import selectors
import socket
import struct
import threading
import time
from collections.abc import Callable

import can

INTERFACE = "canimucal-tcp"
_RECORD = struct.Struct("!IBB8s")
_EXTENDED, _REMOTE, _ERROR = 1, 2, 4
JOINED = b"\x06"

Tap = Callable[[int, can.Message], None]


def pack(msg: can.Message) -> bytes:
    """One wire record of ``msg``."""
    flags = (
        (_EXTENDED if msg.is_extended_id else 0)
        | (_REMOTE if msg.is_remote_frame else 0)
        | (_ERROR if msg.is_error_frame else 0)
    )
    return _RECORD.pack(msg.arbitration_id, flags, msg.dlc, bytes(msg.data).ljust(8, b"\0"))


def unpack(record: bytes, timestamp: float) -> can.Message:
    """The frame of one wire record, stamped ``timestamp``."""
    arb_id, flags, dlc, data = _RECORD.unpack(record)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=arb_id,
        is_extended_id=bool(flags & _EXTENDED),
        is_remote_frame=bool(flags & _REMOTE),
        is_error_frame=bool(flags & _ERROR),
        dlc=dlc,
        data=data[:dlc] if not flags & _REMOTE else None,
    )


class TcpHub:
    """The bus: a thread relaying each client's frames to all other clients.

    ``channel`` is ``"127.0.0.1:PORT"`` (what ``--channel`` takes); ``relayed`` counts frames
    delivered to at least one other client. Use as a context manager or call :meth:`close`.
    """

    def __init__(self) -> None:
        self._server = socket.create_server(("127.0.0.1", 0))
        self._server.setblocking(False)
        self.port = self._server.getsockname()[1]
        self.channel = f"127.0.0.1:{self.port}"
        self.taps: list[Tap] = []
        self.relayed = 0
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._server, selectors.EVENT_READ, None)
        self._clients: dict[socket.socket, tuple[int, bytearray]] = {}
        self._numbers = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tcp-can-hub", daemon=True)
        self._thread.start()

    @property
    def clients(self) -> int:
        """Clients connected now."""
        return len(self._clients)

    def _run(self) -> None:
        while not self._stop.is_set():
            for key, _ in self._selector.select(timeout=0.05):
                if key.fileobj is self._server:
                    self._accept()
                else:
                    self._read(key.fileobj)  # type: ignore[arg-type]
        for sock in list(self._clients):
            self._drop(sock)
        self._selector.close()
        self._server.close()

    def _accept(self) -> None:
        try:
            sock, _ = self._server.accept()
        except BlockingIOError:
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(True)
        self._numbers += 1
        self._clients[sock] = (self._numbers, bytearray())
        self._selector.register(sock, selectors.EVENT_READ, None)
        try:
            sock.sendall(JOINED)  # relayed to from now on
        except OSError:
            self._drop(sock)

    def _drop(self, sock: socket.socket) -> None:
        self._clients.pop(sock, None)
        try:
            self._selector.unregister(sock)
        except (KeyError, ValueError):
            pass
        sock.close()

    def _read(self, sock: socket.socket) -> None:
        try:
            chunk = sock.recv(65536)
        except OSError:
            chunk = b""
        if not chunk:
            self._drop(sock)
            return
        number, buffer = self._clients[sock]
        buffer += chunk
        whole = len(buffer) - len(buffer) % _RECORD.size
        if not whole:
            return
        records, buffer[:] = bytes(buffer[:whole]), buffer[whole:]
        now = time.time()
        for start in range(0, whole, _RECORD.size):
            msg = unpack(records[start : start + _RECORD.size], now)
            for tap in list(self.taps):
                tap(number, msg)
        for other in [s for s in self._clients if s is not sock]:
            try:
                other.sendall(records)
            except OSError:
                self._drop(other)
        if len(self._clients) > 1:
            self.relayed += whole // _RECORD.size

    def close(self) -> None:
        """Stop relaying and close every connection."""
        self._stop.set()
        self._thread.join(5.0)

    def __enter__(self) -> TcpHub:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TcpBus(can.BusABC):
    """A python-can bus on a :class:`TcpHub`; ``channel`` is ``"HOST:PORT"``."""

    def __init__(self, channel: str, **kwargs: object) -> None:
        host, _, port = str(channel).rpartition(":")
        try:
            self._sock = socket.create_connection((host or "127.0.0.1", int(port)), timeout=5.0)
        except (OSError, ValueError) as exc:
            raise can.CanInitializationError(f"no CAN hub at {channel}: {exc}") from exc
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            joined = self._sock.recv(1)  # within the connect timeout above
        except OSError as exc:
            self._sock.close()
            raise can.CanInitializationError(f"CAN hub at {channel} did not answer: {exc}") from exc
        if joined != JOINED:
            self._sock.close()
            raise can.CanInitializationError(f"no canimucal-tcp hub at {channel}")
        self._sock.settimeout(None)
        self._send_lock = threading.Lock()
        self._buffer = bytearray()
        self._closed = self._eof = False
        self.channel_info = f"canimucal-tcp {channel}"
        super().__init__(channel=channel, **kwargs)  # type: ignore[arg-type]

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Put ``msg`` on the hub."""
        try:
            with self._send_lock:
                self._sock.sendall(pack(msg))
        except OSError as exc:
            raise can.CanOperationError(f"CAN hub connection lost: {exc}") from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while len(self._buffer) < _RECORD.size:
            if self._closed or self._eof:
                time.sleep(0.05 if timeout is None else min(timeout, 0.05))
                return None, False
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            self._sock.settimeout(left if left is None else max(left, 1e-4))
            try:
                chunk = self._sock.recv(4096)
            except TimeoutError:
                return None, False
            except OSError as exc:
                if self._closed:
                    return None, False
                raise can.CanOperationError(f"CAN hub connection lost: {exc}") from exc
            if not chunk:
                self._eof = True  # the hub closed
                return None, False
            self._buffer += chunk
        record = bytes(self._buffer[: _RECORD.size])
        del self._buffer[: _RECORD.size]
        return unpack(record, time.time()), False

    def shutdown(self) -> None:
        """Close the connection."""
        if self._closed:
            return
        self._closed = True
        super().shutdown()
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()


def register() -> None:
    """Make :class:`TcpBus` python-can's interface ``canimucal-tcp`` in this process."""
    import can.interfaces
    import can.util

    can.interfaces.BACKENDS[INTERFACE] = (__name__, TcpBus.__name__)
    valid = frozenset(can.interfaces.BACKENDS)
    can.interfaces.VALID_INTERFACES = valid
    can.util.VALID_INTERFACES = valid  # load_config checks the name against this copy
