"""Fixtures for device tests: a simulated IMU node and a client on python-can's virtual bus.

Each test gets its own virtual channel (``bus_channel``), so nodes of different tests never
meet. The usual stack, in creation order:

- ``client_network``: a ``canopen.Network`` (the client side) on its own virtual bus,
  with ``bus_frames`` recording every frame it receives (attached before any node starts,
  so the boot-up frame is seen);
- ``sim_node``: a started :class:`SimulatedImuNode` (node 0x10, nominal truth, seed 1,
  ``time_scale`` 1) on a second bus of the same channel; stopped at teardown;
- ``remote_node``: the client's ``RemoteNode`` for 0x10, built from the same EDS.

``make_sim_node(**kwargs)`` builds more nodes (other ids, truth, ``state_file``,
``time_scale``); every node and bus is closed at teardown.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import can
import canopen
import pytest

from canimucal.device.od import eds_path
from canimucal.simnode.node import SimulatedImuNode

NODE_ID = 0x10
_channel_numbers = itertools.count()


@dataclass(frozen=True)
class Frame:
    """One received CAN frame."""

    cob_id: int
    data: bytes
    timestamp: float


class FrameRecorder(can.Listener):
    """Records every frame a bus receives; thread-safe; ``wait_for`` polls with a timeout."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._frames: list[Frame] = []

    def stop(self) -> None:
        pass  # python-can 4.4 declares it abstract

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self._frames.append(Frame(msg.arbitration_id, bytes(msg.data), msg.timestamp))

    def frames(self, cob_id: int | None = None) -> list[Frame]:
        """Frames received so far (of one COB-ID if given)."""
        with self._lock:
            return [f for f in self._frames if cob_id is None or f.cob_id == cob_id]

    def clear(self) -> None:
        """Forget every frame received so far."""
        with self._lock:
            self._frames.clear()

    def wait_for(
        self, predicate: Callable[[list[Frame]], bool], timeout: float = 3.0
    ) -> list[Frame]:
        """Poll until ``predicate(frames)`` holds; return the frames (fail on timeout)."""
        deadline = time.monotonic() + timeout
        while True:
            frames = self.frames()
            if predicate(frames):
                return frames
            if time.monotonic() > deadline:
                raise AssertionError(f"condition not met within {timeout} s")
            time.sleep(0.01)

    def wait_count(self, cob_id: int, count: int, timeout: float = 3.0) -> list[Frame]:
        """Wait until ``count`` frames of ``cob_id`` arrived; return those frames."""
        self.wait_for(lambda fs: sum(f.cob_id == cob_id for f in fs) >= count, timeout)
        return self.frames(cob_id)


@pytest.fixture
def bus_channel() -> str:
    """A virtual-bus channel name no other test uses."""
    return f"canimucal-test-{os.getpid()}-{next(_channel_numbers)}"


@pytest.fixture
def open_bus(bus_channel: str) -> Iterator[Callable[[], can.BusABC]]:
    """Factory of python-can virtual buses on ``bus_channel``; all shut down at teardown."""
    buses: list[can.BusABC] = []

    def make() -> can.BusABC:
        bus = can.Bus(interface="virtual", channel=bus_channel)
        buses.append(bus)
        return bus

    yield make
    for bus in buses:
        bus.shutdown()


@pytest.fixture
def bus_frames() -> FrameRecorder:
    """Every frame the client side receives (see ``client_network``)."""
    return FrameRecorder()


@pytest.fixture
def client_network(
    open_bus: Callable[[], can.BusABC], bus_frames: FrameRecorder
) -> Iterator[canopen.Network]:
    """The client side: a connected ``canopen.Network`` on its own bus of ``bus_channel``."""
    network = canopen.Network(open_bus())
    network.NOTIFIER_CYCLE = 0.1  # quick teardown: the notifier polls the bus every 0.1 s
    network.listeners.append(bus_frames)
    network.connect()
    yield network
    if network.notifier is not None:
        network.notifier.stop(network.NOTIFIER_SHUTDOWN_TIMEOUT)


@pytest.fixture
def make_sim_node(
    open_bus: Callable[[], can.BusABC],
) -> Iterator[Callable[..., SimulatedImuNode]]:
    """Factory: ``make_sim_node(node_id=0x10, truth=None, state_file=None, time_scale=1.0,
    seed=1, start=True)`` builds a node on its own bus of ``bus_channel``."""
    nodes: list[SimulatedImuNode] = []

    def make(node_id: int = NODE_ID, *, start: bool = True, **kwargs: Any) -> SimulatedImuNode:
        kwargs.setdefault("seed", 1)
        node = SimulatedImuNode(open_bus(), node_id, **kwargs)
        nodes.append(node)
        if start:
            node.start()
        return node

    yield make
    for node in nodes:
        node.stop()


@pytest.fixture
def sim_node(
    client_network: canopen.Network, make_sim_node: Callable[..., SimulatedImuNode]
) -> SimulatedImuNode:
    """A started simulated node 0x10 (PRE-OPERATIONAL), nominal truth, seed 1, real time."""
    return make_sim_node()


@pytest.fixture
def remote_node(client_network: canopen.Network, sim_node: SimulatedImuNode) -> canopen.RemoteNode:
    """The client's view of ``sim_node``: a ``RemoteNode`` from the same EDS (SDO 1 s)."""
    node = client_network.add_node(NODE_ID, canopen.import_od(str(eds_path()), NODE_ID))
    node.sdo.RESPONSE_TIMEOUT = 1.0
    return node
