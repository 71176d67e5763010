"""Bus settings (docs/design.md §7) and the SDO transport policy (timeouts, retries, aborts).

The flags win over the environment, which wins over the config file (python-can's
``can.util.load_config`` order). ``interface`` defaults to ``socketcan`` when a channel is
known and no source names an interface. Opening failures become :class:`NoDeviceError`
(exit 4) with one line naming the interface and channel.

SDO transfers time out after 0.5 s (2 s in the CAN VM); timeouts are retried with
exponential backoff, aborts never (the node said no: retrying cannot change that).
"""

from __future__ import annotations

import errno
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from canimucal.device import od
from canimucal.errors import (
    DeviceSilentError,
    InputError,
    NodeRebootedError,
    NoDeviceError,
    SdoAbort,
    StoreTimeoutError,
)

logger = logging.getLogger(__name__)

DEFAULT_SDO_TIMEOUT_S = 0.5
"""SDO response timeout on a real or virtual bus."""

VM_SDO_TIMEOUT_S = 2.0
"""SDO response timeout inside the CAN VM (``IN_CAN_VM=1``, docs/design.md §8)."""

DEFAULT_INTERFACE_WITH_CHANNEL = "socketcan"

BACKOFF_START_S = 0.1
"""First retry delay after an SDO timeout; doubles on each further retry (0.1, 0.2, 0.4 s)."""


def default_sdo_timeout_s(environ: Mapping[str, str] | None = None) -> float:
    """SDO timeout: 0.5 s, or 2 s when ``IN_CAN_VM=1`` (slow emulated CAN)."""
    env = os.environ if environ is None else environ
    if env.get("IN_CAN_VM", "").strip() == "1":
        return VM_SDO_TIMEOUT_S
    return DEFAULT_SDO_TIMEOUT_S


@dataclass(frozen=True)
class BusSettings:
    """What the user gave on the command line; the rest comes from python-can's config.

    ``config_path`` is a python-can config file (default: ``~/.canrc``, ``~/.can``,
    ``/etc/can.conf``); ``context`` a section other than ``default`` of it; ``extra`` any
    other keyword python-can's backend accepts (e.g. ``receive_own_messages``).
    """

    interface: str | None = None
    channel: str | int | None = None
    bitrate: int | None = None
    config_path: str | None = None
    context: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def flags(self) -> dict[str, Any]:
        """Return the values given explicitly (``None`` left out), as python-can keys."""
        given: dict[str, Any] = dict(self.extra)
        for key in ("interface", "channel", "bitrate"):
            value = getattr(self, key)
            if value is not None:
                given[key] = value
        return given

    def resolve(self) -> dict[str, Any]:
        """Merge the bus configuration: flags, ``can.rc``, ``CAN_*`` environment, config file.

        Raises :class:`InputError` for an interface name python-can does not know and
        :class:`NoDeviceError` when no source names a channel or an interface.
        """
        given = self.flags()
        if "interface" not in given and not self._interface_named_elsewhere():
            channel = given.get("channel") or self._channel_named_elsewhere()
            if channel is None:
                raise NoDeviceError(
                    "no CAN bus configured: give channel (and interface), "
                    "CAN_INTERFACE/CAN_CHANNEL or a python-can config file",
                    options=("give channel (and interface)",),
                )
            given["interface"] = DEFAULT_INTERFACE_WITH_CHANNEL
        try:
            config = can.util.load_config(path=self.config_path, config=given, context=self.context)
        except can.CanInterfaceNotImplementedError as exc:
            raise InputError(f"unknown CAN interface: {exc}") from exc
        except ValueError as exc:
            raise InputError(f"bad CAN bus configuration: {exc}") from exc
        return dict(config)

    def _file_and_env(self) -> list[Mapping[str, Any]]:
        """Return the sources below the flags, in python-can's order (highest first)."""
        return [
            can.rc,
            can.util.load_environment_config(self.context),
            can.util.load_environment_config(),
            can.util.load_file_config(self.config_path, self.context or "default"),
            can.util.load_file_config(self.config_path),
        ]

    def _interface_named_elsewhere(self) -> bool:
        return any(src.get("interface") or src.get("bustype") for src in self._file_and_env())

    def _channel_named_elsewhere(self) -> Any:
        for src in self._file_and_env():
            if src.get("channel") not in (None, ""):
                return src["channel"]
        return None


def describe(config: Mapping[str, Any]) -> str:
    """``interface/channel`` of a resolved configuration, for messages."""
    return f"{config.get('interface')}/{config.get('channel')}"


def open_bus(settings: BusSettings) -> can.BusABC:
    """Open the configured bus; :class:`NoDeviceError` (exit 4, one line, a hint) otherwise.

    Any exception from the interface's driver counts: a vendor back end whose library is
    missing fails with whatever its wrapper raises (python-can's kvaser: ``NameError``).
    """
    config = settings.resolve()
    where = describe(config)
    try:
        bus = can.Bus(**config)
    except Exception as exc:  # the driver's own failure, whatever its type
        text = bus_error_text(exc, config)
        options = ("use another interface",) if "use another interface" in text else ()
        raise NoDeviceError(f"cannot open CAN bus {where}: {text}", options=options) from exc
    logger.info("opened CAN bus %s", where)
    return bus


REQUEST_UPLOAD = 0x40
"""SDO command specifier of an upload (read) request (CiA 301)."""
ABORT_OUT_OF_MEMORY = 0x05040005
"""CiA 301 SDO abort code the client sends to stop an over-long upload."""
_ERRNO_HINTS = {
    errno.ENODEV: "no such CAN interface: check the name with 'ip link', or create it "
    "('ip link add dev {channel} type vcan' for a virtual one)",
    errno.ENETDOWN: "the interface is down: 'ip link set {channel} up type can bitrate "
    "500000' (vcan: 'ip link set {channel} up')",
    errno.EAFNOSUPPORT: "this kernel has no SocketCAN: load it ('modprobe can_raw'), or "
    "use another interface",
    errno.EPERM: "not permitted: run as a user allowed to use the CAN interface",
    errno.EACCES: "not permitted: run as a user allowed to use the CAN interface",
}


def bus_error_text(exc: BaseException, config: Mapping[str, Any]) -> str:
    """One line: what failed opening the bus, and what to do about it."""
    channel = str(config.get("channel") or "can0")
    reason = " ".join(str(exc).split()) or type(exc).__name__
    number = getattr(exc, "errno", None)
    if number is None and isinstance(exc.__cause__, OSError):
        number = exc.__cause__.errno
    if number in _ERRNO_HINTS:
        hint = _ERRNO_HINTS[number].format(channel=channel)
        return f"[Errno {number}] {os.strerror(number)}; {hint}"
    if isinstance(exc, NameError | ImportError | can.CanInterfaceNotImplementedError):
        interface = config.get("interface")
        return (
            f"the driver of interface {interface!r} is not installed or not loadable "
            f"({reason}); install the vendor's driver and its Python package"
        )
    return reason


def abort_text(code: int) -> str:
    """Return ``"0x06090030 value range of parameter exceeded"``, in canopen's words.

    The text is canopen's own table of CiA 301 abort codes (``SdoAbortedError.CODES``),
    first letter lowered to fit the sentence it ends; a code it lacks is "unknown abort code".
    """
    text = SdoAbortedError.CODES.get(code, "unknown abort code")
    return f"0x{code:08X} {text[:1].lower()}{text[1:]}"


class SdoChannel:
    """Raw SDO upload/download with the retry policy and error mapping.

    Timeouts and bus errors are retried ``retries`` times after ``backoff_s``, doubling;
    aborts never. ``boots()`` (the client's count of boot-up frames) stops a retry when the
    node rebooted meanwhile: a write must not land on a freshly booted node unnoticed.
    """

    def __init__(
        self,
        node: canopen.RemoteNode,
        timeout_s: float,
        retries: int,
        *,
        backoff_s: float = BACKOFF_START_S,
        boots: Callable[[], int] | None = None,
    ) -> None:
        node.sdo.RESPONSE_TIMEOUT = timeout_s
        node.sdo.MAX_RETRIES = 1  # our own retry loop, with backoff
        self.timeout_s = timeout_s
        """The response timeout of each transfer (a store has its own)."""
        self._sdo = node.sdo
        self._retries = retries
        self._backoff_s = backoff_s
        self._boots = boots
        self._lock = threading.Lock()

    def upload(self, index: int, sub: int) -> bytes:
        """Read ``index:sub`` as bytes."""
        return bytes(self._call("read", index, sub, lambda: self._sdo.upload(index, sub)))

    def upload_bounded(self, index: int, sub: int, limit: int) -> tuple[bytes, bool]:
        """Read at most ``limit`` bytes of ``index:sub``; return them and whether cut short.

        A longer (segmented) value is aborted after the first segment past ``limit`` (SDO
        abort 0x05040005, out of memory), so a device name of megabytes costs a few dozen
        frames rather than the whole transfer.
        """
        return self._call("read", index, sub, lambda: self._read_bounded(index, sub, limit))

    def _read_bounded(self, index: int, sub: int, limit: int) -> tuple[bytes, bool]:
        stream = self._sdo.open(index, sub, "rb", buffering=0)
        data = bytearray()
        try:
            while len(data) <= limit:
                piece = stream.read(7)
                if not piece:
                    return bytes(data), False
                data += piece
            request = bytearray([0x80, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])
            request[4:8] = ABORT_OUT_OF_MEMORY.to_bytes(4, "little")
            self._sdo.send_request(request)
            logger.warning(
                "%s is longer than %d bytes: upload aborted", od.format_key(index, sub), limit
            )
            return bytes(data[:limit]), True
        finally:
            stream.close()

    def download(self, index: int, sub: int, data: bytes) -> None:
        """Write ``data`` to ``index:sub`` (expedited when ≤ 4 bytes)."""
        self._call("write", index, sub, lambda: self._sdo.download(index, sub, data))

    def download_once(self, index: int, sub: int, data: bytes, timeout_s: float) -> None:
        """Write once with its own response timeout and no retry (a 0x1010 store).

        A device may erase flash inside the SDO handler for seconds before it answers
        (CANopenNode does); a retry would store twice. Timeout: :class:`StoreTimeoutError`.
        """
        name = od.format_key(index, sub)
        with self._lock:
            saved = self._sdo.RESPONSE_TIMEOUT
            self._sdo.RESPONSE_TIMEOUT = timeout_s
            try:
                self._sdo.download(index, sub, data)
            except SdoAbortedError as exc:
                text = abort_text(int(exc.code))
                raise SdoAbort(f"device refused write of {name}: {text}", int(exc.code)) from exc
            except SdoCommunicationError as exc:
                raise StoreTimeoutError(
                    f"no SDO answer to write of {name} within {timeout_s:g} s: {exc}"
                ) from exc
            except can.CanError as exc:  # the request did not leave: nothing was stored
                raise DeviceSilentError(f"cannot send the write of {name}: {exc}") from exc
            finally:
                self._sdo.RESPONSE_TIMEOUT = saved

    def answers(self, index: int, sub: int, window_floor_s: float) -> list[bytes]:
        """Send one expedited upload request of ``index:sub`` and collect every answer.

        One node answers once; a second device with the same node-id answers too
        (docs/design.md §9). After the first answer this waits three times its latency
        more, at least ``window_floor_s``, for others. ``[]`` when nothing answers within
        the SDO timeout or the request could not be sent (the next transfer, retried as
        usual, reports it). Not retried.
        """
        request = bytes([REQUEST_UPLOAD, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])
        with self._lock:
            responses: queue.Queue[bytes] = queue.Queue()
            self._sdo.responses = responses  # canopen's own queue, fresh as before any request
            started = time.monotonic()
            try:
                self._sdo.send_request(request)
            except can.CanError as exc:  # nothing left: the next transfer retries and reports
                logger.warning("cannot send a read of %s: %s", od.format_key(index, sub), exc)
                return []
            try:
                got = [responses.get(timeout=self._sdo.RESPONSE_TIMEOUT)]
            except queue.Empty:
                return []
            deadline = time.monotonic() + max(window_floor_s, 3.0 * (time.monotonic() - started))
            while (left := deadline - time.monotonic()) > 0:
                try:
                    got.append(responses.get(timeout=left))
                except queue.Empty:
                    break
            return got

    def _call(self, what: str, index: int, sub: int, op: Any) -> Any:
        name = od.format_key(index, sub)
        delay = self._backoff_s
        boots = self._boots() if self._boots is not None else 0
        for attempt in range(self._retries + 1):
            try:
                with self._lock:
                    return op()
            except SdoAbortedError as exc:
                text = abort_text(int(exc.code))
                raise SdoAbort(f"device refused {what} of {name}: {text}", int(exc.code)) from exc
            except (SdoCommunicationError, can.CanError) as exc:
                if self._boots is not None and self._boots() != boots:
                    raise NodeRebootedError(
                        f"node rebooted during {what} of {name}; not retried: {exc}"
                    ) from exc
                if attempt == self._retries:
                    raise DeviceSilentError(
                        f"no SDO answer to {what} of {name} after {attempt + 1} tries: {exc}"
                    ) from exc
                logger.warning("SDO %s of %s: %s; retry in %.1f s", what, name, exc, delay)
                time.sleep(delay)
                delay *= 2
        raise AssertionError("unreachable")
