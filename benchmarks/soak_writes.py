"""Write-transaction storms of :mod:`benchmarks.soak` (issue 13): signals and two writers.

``--signals N``: N transactions, each interrupted at a random SDO request by SIGTERM, SIGINT
or SIGINT followed 1–5 requests later by SIGTERM (a second interrupt, usually inside the
rollback). The signal is sent to this process by a tap on the client's side of a
synchronous loopback link, so it lands wherever the transaction is. Checks per run (the
same as ``tests/device/test_signals_write.py``): never valid = 1 over a mixed set; an
interrupt after the backup always ends with the old set back and the backup named.

``--writers N``: N rounds of two clients (two ``canopen.Network``s on one python-can
virtual channel, one thread each) writing different sets to one node at once. Checks: at
most one reports success, the device holds exactly that set, or the old set (or valid = 0)
with both told; then one back-to-back pair, both of which must succeed.
"""

from __future__ import annotations

import signal
import threading
import time
import uuid
from collections import Counter
from pathlib import Path

import can
import canopen
import numpy as np

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.device.transaction import WriteReport, write_calibration_transaction
from canimucal.errors import DeviceError
from canimucal.io.calibration import Calibration
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode
from tests.device.test_signals_write import check_outcome, interrupted_write
from tests.device.test_write_faults import (
    NODE_ID,
    SERIAL,
    LoopRig,
    _connect,
    _old_and_new,
    calibration,
)
from tests.support.buses import FaultyBus, loopback_pair
from tests.support.nodes import DeviceUnderTest


def _loop_rig(backups: Path) -> tuple[LoopRig, list[canopen.Network], list[can.BusABC]]:
    client_end, node_end = loopback_pair()
    faulty = FaultyBus(client_end)
    client_net, node_net = _connect(faulty, client_end), _connect(node_end, node_end)
    node = SimulatedImuNode(node_net, NODE_ID, Truth.from_dict({"serial": SERIAL}), seed=3)
    client = ImuClient(client_net, NODE_ID, sdo_timeout_s=0.003, sdo_retries=1, sdo_backoff_s=0.001)
    node.start()
    rig = LoopRig(DeviceUnderTest("simulated", node), client, faulty, node_end, backups)
    return rig, [client_net, node_net], [faulty, node_end]


def signal_storm(runs: int, seed: int, backups: Path) -> bool:
    """Run ``runs`` interrupted transactions; print the outcomes; True when all checks held."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    rig, networks, buses = _loop_rig(backups)
    tally: Counter[str] = Counter()
    failures: list[str] = []
    started = time.monotonic()
    try:
        old, new, n_requests = _old_and_new(rig)
        rng = np.random.default_rng(seed)
        for _ in range(runs):
            rig.load(old)
            kind = str(rng.choice(["term", "int", "double"]))
            k = int(rng.integers(1, n_requests + 1))
            if kind == "double":
                plan = {k: signal.SIGINT, k + int(rng.integers(1, 6)): signal.SIGTERM}
            else:
                plan = {k: signal.SIGTERM if kind == "term" else signal.SIGINT}
            raised, _ = interrupted_write(rig, plan)
            try:
                tally[f"{kind}: {check_outcome(rig, old, new, plan, raised)}"] += 1
            except AssertionError as exc:
                failures.append(str(exc))
                tally[f"{kind}: FAILED"] += 1
    finally:
        rig.client.close()
        rig.node.stop()
        for net in networks:
            if net.notifier is not None:
                net.notifier.stop()
        for bus in buses:
            bus.shutdown()
    print(f"signal storm: {runs} runs in {time.monotonic() - started:.1f} s")
    for key, count in sorted(tally.items()):
        print(f"  {key}: {count}")
    for failure in failures[:5]:
        print(f"  failure: {failure}")
    return not failures


def _raw(node: SimulatedImuNode) -> dict[tuple[int, int], bytes]:
    get = node.local_node.get_data
    return {(i, s): bytes(get(i, s)) for i, s, _ in od.CALIBRATION_OBJECTS}


def _holds(node: SimulatedImuNode, report: WriteReport) -> bool:
    final = {(w.index, w.sub): w.data for w in report.writes if w.index != od.STORE}
    raw = _raw(node)
    return all(raw[key] == data for key, data in final.items())


def two_writers(rounds: int, backups: Path) -> bool:
    """Run ``rounds`` of overlapping writers and one back-to-back pair; True when all held."""
    channel = f"soak-writers-{uuid.uuid4().hex[:8]}"
    buses = [can.Bus(interface="virtual", channel=channel) for _ in range(3)]
    networks = [canopen.Network(bus) for bus in buses]
    for net in networks:
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
    node = SimulatedImuNode(networks[0], NODE_ID, Truth.from_dict({"serial": SERIAL}), seed=2)
    clients = [ImuClient(net, NODE_ID, sdo_timeout_s=0.2, sdo_retries=1) for net in networks[1:]]
    node.start()
    records = [Calibration.from_dict(calibration(s, b)) for s, b in ((1.03, 5.0), (0.98, -7.0))]
    tally: Counter[str] = Counter()
    failures: list[str] = []
    try:
        for client, record in zip(clients, records, strict=True):  # back to back
            report = write_calibration_transaction(client, record, backup_dir=backups, store=False)
            if not _holds(node, report):
                failures.append("back-to-back write reported ok, device holds another set")
        for _ in range(rounds):
            old = _raw(node)
            results: list[WriteReport | DeviceError | None] = [None, None]
            barrier = threading.Barrier(2)

            def write(
                i: int,
                results: list[WriteReport | DeviceError | None] = results,
                barrier: threading.Barrier = barrier,
            ) -> None:
                barrier.wait()
                try:
                    results[i] = write_calibration_transaction(
                        clients[i], records[i], backup_dir=backups, store=False
                    )
                except DeviceError as exc:
                    results[i] = exc

            threads = [threading.Thread(target=write, args=(i,)) for i in (0, 1)]
            for t in threads:
                t.start()
            for t in threads:
                t.join(60)
            done = [r for r in results if isinstance(r, WriteReport)]
            state = _raw(node)
            valid = state[(od.CAL_INFO, od.CAL_VALID_SUB)]
            if len(done) > 1:
                failures.append("both writers reported success")
            elif done and not _holds(node, done[0]):
                failures.append("success reported, device holds another set")
            elif not done and not (state == old or valid == b"\x00"):
                failures.append("both told, yet a mixed set is valid")
            told = sum(f"another SDO client is using node {NODE_ID}" in str(r) for r in results)
            tally[f"{len(done)} ok, {told} told of the other"] += 1
    finally:
        for client in clients:
            client.close()
        node.stop()
        for net in networks:
            if net.notifier is not None:
                net.notifier.stop()
        for bus in buses:
            bus.shutdown()
    print(f"two writers: {rounds} overlapping rounds (+1 back-to-back pair)")
    for key, count in sorted(tally.items()):
        print(f"  {key}: {count}")
    for failure in failures[:5]:
        print(f"  failure: {failure}")
    return not failures


def process_storm(runs: int, seed: int, workdir: Path) -> bool:
    """``runs`` interrupted ``write-params`` processes on a cross-process bus; print the tally.

    Each run forks ``canimucal write-params`` against ``canimucal sim`` in another process on
    a :class:`~tests.support.tcpbus.TcpHub` (its flash a state file, its store taking 0.2 s)
    and signals it per a seeded :func:`tests.support.storm.draw_plan`: SIGINT, SIGTERM,
    SIGHUP or a pair, at a random SDO request or (in 40 % of the runs) in the store window.
    RAM is read back by SDO from this process, flash from the node's state file; the
    message is held to what they hold (:func:`tests.support.storm.judge`). Prints the runs by
    window, signals and ending, what RAM and flash held, and the silent runs and unreported
    RAM/flash disagreements (both must be 0).
    """
    # the command's modules are imported once here, so each forked command starts at once
    import canimucal.cli.main  # noqa: F401
    import canimucal.cli.sim_cmd  # noqa: F401
    import canimucal.cli.write_params_cmd  # noqa: F401
    import canimucal.runtime.wiring  # noqa: F401
    import canimucal.simnode.node  # noqa: F401
    from tests.support.storm import ProcessRig, draw_plan, judge

    signal.signal(signal.SIGINT, signal.default_int_handler)
    rig = ProcessRig(workdir)
    tally: Counter[str] = Counter()
    held: Counter[str] = Counter()
    problems: Counter[str] = Counter()
    failures: list[str] = []
    started = time.monotonic()
    try:
        rng = np.random.default_rng(seed)
        for _ in range(runs):
            outcome = rig.interrupted_write(draw_plan(rng, rig.requests_per_write))
            said, found = judge(outcome, rig.backups)
            plan = outcome.plan
            tally[f"{plan.window:5s} {plan.kind:8s} exit {outcome.code}: {said}"] += 1
            held[f"RAM {outcome.ram}, flash {outcome.flash}"] += 1
            problems.update(found)
            if found:
                failures.append(f"{found}: {plan}, exit {outcome.code}: {outcome.stderr!r}")
    finally:
        rig.close()
    took = time.monotonic() - started
    windows = Counter(key.split()[0] for key in tally.elements())
    print(f"process storm: {runs} write-params processes in {took:.1f} s ({dict(windows)})")
    for key, count in sorted(tally.items()):
        print(f"  {key}: {count}")
    print("what the device held afterwards:")
    for key, count in sorted(held.items()):
        print(f"  {key}: {count}")
    silent = problems["silent"]
    unreported = problems["unreported disagreement"]
    print(f"silent: {silent}; RAM/flash disagreements not reported: {unreported}")
    other = {k: v for k, v in problems.items() if k not in ("silent", "unreported disagreement")}
    print(f"other contract breaks: {other or 0}")
    for failure in failures[:5]:
        print(f"  failure: {failure}")
    return not failures
