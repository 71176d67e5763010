"""Device tests against two IMU nodes: the simulated one and an independent stack's.

``device_kind`` is parametrized over :data:`NODE_KINDS`; ``make_device(**behaviour)`` builds
a started node of that kind on its own bus of ``bus_channel`` and wraps it in a
:class:`DeviceUnderTest`, so one test body runs against python-canopen's responder
(:class:`~canimucal.simnode.node.SimulatedImuNode`) and durand's
(:class:`~tests.support.independent_node.IndependentImuNode`). Behaviour keys are those of
the truth JSON (docs/design.md §5, docs/hil.md: ``nmt_start``, ``heartbeat_ms``, ``store_delay_s``,
``store_pdo_mode``, ``storage_subs``, ``sync_pdos``, ``timer_skew_ppm``), which both nodes
take; a behaviour one node does not have (none today) skips the test for that node.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import can
import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from durand.services.sdo.server import SDODomainAbort

from canimucal.device import od
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode
from tests.support.canbus import NODE_ID
from tests.support.independent_node import Behaviour, IndependentImuNode

NODE_KINDS = ("simulated", "independent")
SIM_TRUTH_KEYS = (
    "nmt_start",
    "heartbeat_ms",
    "store_delay_s",
    "storage_subs",
    "store_pdo_mode",
    "sync_pdos",
    "timer_skew_ppm",
    "calibration_store_sub",
    "documented_store_sub",
    "second_send_ms",
    "refuses_start",
    "trim_object",
)
"""Behaviours the simulated node takes from its truth JSON."""


@dataclass
class DeviceUnderTest:
    """One started node of either kind, seen the same way by the tests."""

    kind: str
    node: SimulatedImuNode | IndependentImuNode

    @property
    def node_id(self) -> int:
        return self.node.node_id

    @property
    def nmt_state(self) -> str:
        return self.node.nmt_state

    def value(self, index: int, sub: int = 0) -> Any:
        return self.node.od_value(index, sub)

    @property
    def store_log(self) -> list[int]:
        """0x1010 sub-index of every completed store."""
        return list(self.node.store_log)

    @property
    def dropped_in_store(self) -> int:
        """What a slow store made the node lose: TPDO frames (simulated), or samples and
        TPDO events (independent)."""
        if isinstance(self.node, SimulatedImuNode):
            return self.node.frames_dropped_in_store
        return int(self.node.stats["dropped"])

    def calibration_valid(self) -> bool:
        return int(self.value(od.CAL_INFO, od.CAL_VALID_SUB)) == 1

    def power_cycle(self) -> None:
        if isinstance(self.node, SimulatedImuNode):
            self.node.reboot()
        else:
            self.node.power_cycle()

    def reboot_as(self, serial: int) -> None:
        """Power-cycle as another unit: 0x1018:04 reads ``serial`` from the boot-up on."""
        if isinstance(self.node, SimulatedImuNode):
            self.node.faults.set(serial_after_reboot=serial)
            self.node.reboot()
            return
        with self.node.lock:
            self.node.behaviour.serial = serial
            self.node.node.object_dictionary.write(0x1018, 4, serial)
            self.node.power_cycle()

    def emcy(self, code: int, register: int | None = None) -> None:
        """Send an EMCY (and set 0x1001); ``register`` defaults per node kind."""
        if isinstance(self.node, SimulatedImuNode):
            default = 0 if code == 0 else 0x11
            self.node.send_emergency(code, default if register is None else register)
        else:
            self.node.emcy(code, register)

    @property
    def trim(self) -> bool:
        """Whether the node has the mounting-trim object 0x2122 (the 42-object CRC layout).

        The independent node is a firmware before it: the 39-object layout.
        """
        return isinstance(self.node, SimulatedImuNode) and self.node.truth.trim_object

    def raw_objects(self) -> dict[tuple[int, int], bytes]:
        """The calibration objects (0x2100–0x2122) as their SDO bytes (docs/design.md §4 codes)."""
        objects = od.calibration_objects(self.trim)
        if isinstance(self.node, SimulatedImuNode):  # the bytes it holds, NaN payloads too
            get = self.node.local_node.get_data
            return {(i, s): bytes(get(i, s)) for i, s, _ in objects}
        return {(i, s): od.encode(code, self.value(i, s)) for i, s, code in objects}

    def calibration_active(self) -> bool:
        """The node's own verdict: valid = 1 and its stored CRC-32 matches (§4)."""
        return self.node.calibration_active()

    def intercept_write(
        self, key: tuple[int, int], hook: Callable[[], int | None]
    ) -> Callable[[], None]:
        """Call ``hook()`` before each write of ``key``; an abort code it returns refuses it.

        The write is refused with that SDO abort code before anything is stored (as a
        firmware's range check does). Returns the function that removes the hook.
        """
        if isinstance(self.node, SimulatedImuNode):
            local = self.node.local_node

            def on_write(index: int, subindex: int, **_: Any) -> None:
                if (index, subindex) == key and (code := hook()):
                    raise SdoAbortedError(code)

            local.add_write_callback(on_write)
            return lambda: local._write_callbacks.remove(on_write)
        handlers = self.node.node.object_dictionary.validate_callbacks[key]

        def validate(_value: Any) -> None:
            if code := hook():
                raise SDODomainAbort(code, key)

        handlers.add(validate)
        return lambda: handlers.remove(validate)

    def poke(self, index: int, sub: int, raw: bytes) -> None:
        """Put ``raw`` (SDO bytes) into a calibration object past the node's own checks."""
        if isinstance(self.node, SimulatedImuNode):
            self.node.local_node.data_store.setdefault(index, {})[sub] = raw
            return
        value = od.decode(od.OBJECT_CODES[(index, sub)], raw)
        with self.node.lock:
            self.node.node.object_dictionary._data[(index, sub)] = value

    def start(self) -> DeviceUnderTest:
        self.node.start()
        return self

    def stop(self) -> None:
        self.node.stop()


IDENTITY_KEYS = ("serial",)
"""Keys both nodes take besides their behaviours: the truth JSON's ``serial`` is the
independent node's too (``make_device(serial=...)``, ``node_on(..., serial=...)``)."""


def node_on(
    kind: str,
    bus: can.BusABC | canopen.Network,
    node_id: int = NODE_ID,
    *,
    start: bool = True,
    sim_options: dict[str, Any] | None = None,
    **behaviour: Any,
) -> DeviceUnderTest:
    """A node of ``kind`` on ``bus`` (the independent node needs a python-can bus).

    For tests that build their own buses or networks; ``make_device`` otherwise.

    ``behaviour`` takes :data:`IDENTITY_KEYS` and the behaviour keys (see the module
    docstring); ``sim_options`` are the simulated node's own constructor options
    (``state_file``, ``time_scale``, ``seed``), ignored by the independent node.
    """
    if kind == "independent":
        if not isinstance(bus, can.BusABC):
            raise TypeError("the independent node runs on a python-can bus")
        behaviour.setdefault("seed", 1)
        device = DeviceUnderTest(kind, IndependentImuNode(bus, node_id, Behaviour(**behaviour)))
    else:
        unknown = sorted(set(behaviour) - set(SIM_TRUTH_KEYS) - set(IDENTITY_KEYS))
        if unknown:
            pytest.skip(f"the simulated node has no {', '.join(unknown)}")
        truth = Truth.from_dict(
            {k: list(v) if isinstance(v, tuple) else v for k, v in behaviour.items()}
        )
        options = {"seed": 1, **(sim_options or {})}
        device = DeviceUnderTest(kind, SimulatedImuNode(bus, node_id, truth, **options))
    return device.start() if start else device


@pytest.fixture(params=NODE_KINDS)
def device_kind(request: pytest.FixtureRequest) -> str:
    """Which IMU node the test runs against."""
    return str(request.param)


@pytest.fixture
def make_independent_node(
    open_bus: Callable[[], can.BusABC],
) -> Iterator[Callable[..., IndependentImuNode]]:
    """Factory: ``make_independent_node(node_id=0x10, **behaviour)``, started; stopped after."""
    nodes: list[IndependentImuNode] = []

    def make(node_id: int = NODE_ID, **behaviour: Any) -> IndependentImuNode:
        behaviour.setdefault("seed", 1)
        node = IndependentImuNode(open_bus(), node_id, Behaviour(**behaviour))
        nodes.append(node)
        return node.start()

    yield make
    for node in nodes:
        node.stop()


@pytest.fixture
def make_device(
    device_kind: str,
    make_sim_node: Callable[..., SimulatedImuNode],
    make_independent_node: Callable[..., IndependentImuNode],
) -> Callable[..., DeviceUnderTest]:
    """Factory: ``make_device(**behaviour)`` of kind ``device_kind`` (node 0x10, started)."""

    def make(**behaviour: Any) -> DeviceUnderTest:
        if device_kind == "independent":
            return DeviceUnderTest(device_kind, make_independent_node(**behaviour))
        unknown = sorted(set(behaviour) - set(SIM_TRUTH_KEYS) - set(IDENTITY_KEYS))
        if unknown:
            pytest.skip(f"the simulated node has no {', '.join(unknown)}")
        truth = {k: list(v) if isinstance(v, tuple) else v for k, v in behaviour.items()}
        return DeviceUnderTest(device_kind, make_sim_node(truth=Truth.from_dict(truth)))

    return make
