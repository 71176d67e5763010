"""Soak benchmark (issue 6, item 4): an hour of simulated time at 1 kHz with 1 % frame loss.

Run: ``.venv/bin/python benchmarks/soak.py [--sim-seconds 3600] [--time-scale 8]
[--loss 0.01] [--bus virtual|loopback] [--keep-csv DIR]``.

The simulated node follows a pose schedule (six positions, ``sim_seconds / 6`` each, 1 s
moves) at 1000 Hz and drops each TPDO frame with probability ``loss`` (fault injection,
fixed seed). The tool's side is the real chain: :class:`ImuClient` (pairing, loss counts)
→ the procedure's :class:`~canimucal.runtime.recorder.Recorder` (schedule labelling) →
:class:`~canimucal.io.recording_writer.RecordingWriter` (CSV on disk). Checks, printed at the end:

1. resident memory (``VmRSS`` of ``/proc/self/status``) grows < 5 % between simulated
   minutes 10 and 60 (scaled to ``sim_seconds``: 1/6 and the end);
2. every lost sample is counted: the client's ``lost_accel + lost_gyro + 2·lost_samples``
   equals the TPDO1/TPDO2 frames the node dropped (faults are on only while streaming, and
   cleared, then the node stopped, before the client stops, so no frame is in flight);
3. no sample is attributed to the wrong position: each written row's label is compared with
   the simulator's own position index for that sample (recorded as it is produced).

Exit status 0 when all three hold. ``--bus loopback`` delivers frames synchronously in the
producer's thread (no virtual-bus queue): use it when the machine cannot keep up.

``--signals N`` and ``--writers N`` run the write-transaction storms of
:mod:`benchmarks.soak_writes` instead (SIGTERM/SIGINT/double interrupts at random write
steps; two overlapping writers), print their counts and exit 0 when every run held.
``--processes N`` runs N interrupted ``write-params`` processes against ``canimucal sim`` in
another process on a cross-process bus (``tests/support/tcpbus.py``): SIGINT, SIGTERM,
SIGHUP and pairs, 40 % of them in the store window, tallying what RAM and flash (the node's
state file) hold against what each process said; 0 silent runs and 0 unreported RAM/flash
disagreements, or exit 1.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.support

from canimucal.device.client import ImuClient
from canimucal.io.recording_writer import RecordingWriter
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.runtime.recorder import Recorder
from canimucal.sim.truth import Truth
from canimucal.simnode.node import POSE_TRANSIENT_S, SimulatedImuNode
from tests.support.buses import LoopbackBus, loopback_pair

NODE = 0x10
T1, T2 = 0x180 + NODE, 0x280 + NODE
RATE_HZ = 1000
TRANSIENT_S = POSE_TRANSIENT_S
"""The node moves between poses in this time; the recorder must assume the same."""
POSES_DEG = [(0, 0, 0), (22.5, 0, 0), (22.5, 2.5, 0), (45, 2.5, 90), (45, 5, 180), (0, 5, 270)]
SEED = 20260606


def rss_kib() -> int:
    """Resident set size of this process, KiB (``VmRSS``)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


@dataclass
class TruthTap:
    """The simulator's position index of every produced sample (sample k → ``index[k-1]``)."""

    index: NDArray[np.int8]
    produced: int = 0

    def wrap(self, node: SimulatedImuNode) -> None:
        """Record each block's ``position_index`` as the producer draws it."""
        sim = node.simulator
        draw: Callable[[int], Any] = sim.next_block

        def next_block(n: int) -> Any:
            block = draw(n)
            k = self.produced
            if k + n <= self.index.shape[0]:
                self.index[k : k + n] = block.position_index
            self.produced = k + n
            return block

        setattr(sim, "next_block", next_block)  # noqa: B010 (instance override)


@dataclass
class CheckingWriter:
    """A :class:`RecordingWriter` proxy that compares each row's label with the truth."""

    inner: RecordingWriter
    truth: TruthTap
    seq_last: int | None = None
    labelled: int = 0
    wrong: int = 0
    examples: list[str] = field(default_factory=list)

    def write_rows(self, **cols: Any) -> None:
        """Check the labels, then write."""
        counter = np.asarray(cols["counter"], dtype=np.int64)
        labels = np.asarray(cols["position"], dtype=np.int64)
        seq = np.empty_like(counter)
        last = self.seq_last
        for i, c in enumerate(counter.tolist()):
            last = c if last is None else last + (c - last) % 65536
            seq[i] = last
        if seq.size:
            self.seq_last = int(seq[-1])
        labelled = labels >= 0
        truth = self.truth.index[np.clip(seq - 1, 0, self.truth.index.shape[0] - 1)]
        wrong = labelled & (truth != labels)
        self.labelled += int(np.count_nonzero(labelled))
        self.wrong += int(np.count_nonzero(wrong))
        for i in np.flatnonzero(wrong)[: max(0, 5 - len(self.examples))]:
            self.examples.append(f"sample {seq[i]}: label {labels[i]}, truth {truth[i]}")
        self.inner.write_rows(**cols)

    def close(self) -> Any:
        """Close the real writer."""
        return self.inner.close()


def plan_for(sim_seconds: float) -> Plan:
    """Six positions sharing ``sim_seconds`` (moves included)."""
    each = sim_seconds / len(POSES_DEG) - TRANSIENT_S
    rad = np.deg2rad
    positions = tuple(
        PlannedPosition(float(rad(a)), float(rad(b)), float(rad(p)), float(rad(0.1)), each)
        for a, b, p in POSES_DEG
    )
    return Plan("custom", positions)


def _networks(kind: str) -> tuple[canopen.Network, canopen.Network, list[can.BusABC]]:
    """Node and client networks, on the virtual bus or a synchronous loopback link."""
    if kind == "virtual":
        channel = f"canimucal-soak-{time.monotonic_ns()}"
        buses: list[can.BusABC] = [can.Bus(interface="virtual", channel=channel) for _ in "ab"]
    else:
        buses = list(loopback_pair())
    nets = [canopen.Network(bus) for bus in buses]
    for net, bus in zip(nets, buses, strict=True):
        net.NOTIFIER_CYCLE = 0.1
        net.connect()
        if isinstance(bus, LoopbackBus) and net.notifier is not None:
            bus.receivers = net.notifier.listeners
    return nets[0], nets[1], buses


def _monitor(
    recorder: Recorder, stop: threading.Event, marks_s: tuple[float, float], tap: TruthTap
) -> dict[str, int]:
    """RSS at the two simulated-time marks (sampled as the rows pass them).

    Also prints the backlog: samples produced by the node but not yet written. A backlog
    that grows means the host cannot keep up at this time scale (memory then grows with
    the queues, which is not a leak): lower ``--time-scale`` or use ``--bus loopback``.
    """
    seen: dict[str, int] = {}
    names = ("start", "end")
    while not stop.wait(0.5):
        sim_s = recorder.tallies[0].rows / RATE_HZ
        for name, mark in zip(names, marks_s, strict=True):
            if name not in seen and sim_s >= mark:
                seen[name] = rss_kib()
                backlog = tap.produced - recorder.tallies[0].rows
                print(
                    f"  simulated {sim_s:7.0f} s: RSS {seen[name] / 1024:.1f} MiB, "
                    f"backlog {backlog} samples",
                    flush=True,
                )
    return seen


@dataclass
class Rig:
    """Everything one soak run holds."""

    node: SimulatedImuNode
    client: ImuClient
    networks: tuple[canopen.Network, canopen.Network]
    buses: list[can.BusABC]
    plan: Plan
    recorder: Recorder
    checking: CheckingWriter
    out_dir: Path
    tap: TruthTap


def _build(args: argparse.Namespace) -> Rig:
    node_net, client_net, buses = _networks(args.bus)
    truth = Truth.from_dict({"sample_rate_hz": RATE_HZ, "serial": 60})
    node = SimulatedImuNode(node_net, NODE, truth, time_scale=args.time_scale, seed=SEED)
    n_total = int(args.sim_seconds * RATE_HZ * 1.2) + 10 * RATE_HZ
    tap = TruthTap(np.full(n_total, -2, dtype=np.int8))  # allocated before minute 10
    tap.wrap(node)
    plan = plan_for(args.sim_seconds)
    node.set_schedule(plan)
    node.start()
    client = ImuClient(client_net, NODE)
    out_dir = Path(args.keep_csv or tempfile.mkdtemp(prefix="canimucal-soak-"))
    writer = RecordingWriter.open(
        out_dir / "soak.csv", {"schema": "canimucal.recording/1", "sample_rate_hz": RATE_HZ}
    )
    checking = CheckingWriter(writer, tap)
    recorder = Recorder([(client, checking, float(RATE_HZ))])  # type: ignore[list-item]
    return Rig(node, client, (node_net, client_net), buses, plan, recorder, checking, out_dir, tap)


def _soak(args: argparse.Namespace, rig: Rig) -> tuple[dict[str, int], float, float]:
    """Stream the whole schedule with frame loss on; return RSS marks, wall and CPU s."""
    marks = (args.sim_seconds / 6.0, args.sim_seconds - 30.0)
    stop = threading.Event()
    rss: dict[str, int] = {}
    watcher = threading.Thread(
        target=lambda: rss.update(_monitor(rig.recorder, stop, marks, rig.tap))
    )
    started, cpu0 = time.monotonic(), time.process_time()
    rig.recorder.start()
    watcher.start()
    while rig.client.get_block(0.0) is None and time.monotonic() - started < 5:
        time.sleep(0.01)
    rig.node.faults.set(tpdo_drop_fraction=args.loss, seed=SEED)
    try:
        rig.recorder.record_scheduled(rig.plan, transient_s=TRANSIENT_S)
    finally:
        rig.node.faults.clear()
        time.sleep(0.2)
        rig.client.node.nmt.send_command(0x80)  # the node stops sending before the client
        time.sleep(0.5)
        rig.recorder.stop()
        stop.set()
        watcher.join()
    return rss, time.monotonic() - started, time.process_time() - cpu0


def _close(rig: Rig) -> None:
    rig.checking.close()
    rig.client.close()
    rig.node.stop()
    for net in rig.networks:
        if net.notifier is not None:
            net.notifier.stop()
    for bus in rig.buses:
        bus.shutdown()


def run(args: argparse.Namespace) -> int:
    """Run the soak and print the figures; 0 when every check holds."""
    rig = _build(args)
    rss, wall_s, cpu_s = _soak(args, rig)
    _close(rig)
    return _report(args, rig, rss, wall_s, cpu_s)


def _report(
    args: argparse.Namespace, rig: Rig, rss: dict[str, int], wall_s: float, cpu_s: float
) -> int:
    checking, out_dir = rig.checking, rig.out_dir
    tally = rig.recorder.tallies[0]
    counted = tally.lost_accel + tally.lost_gyro + 2 * tally.lost_samples
    dropped = rig.node.faults.stats.count("dropped", T1, T2)
    growth = (rss["end"] - rss["start"]) / rss["start"] if len(rss) == 2 else float("nan")
    print(f"bus {args.bus}, time scale {args.time_scale:g}, loss {args.loss:g}")
    print(f"wall {wall_s:.0f} s for {tally.rows / RATE_HZ:.0f} simulated s; CPU {cpu_s:.0f} s")
    print(f"rows written {tally.rows}, labelled {checking.labelled}")
    print(
        f"frames dropped by the node (TPDO1+2): {dropped}; counted by the client: {counted} "
        f"(lost accel {tally.lost_accel}, gyro {tally.lost_gyro}, samples {tally.lost_samples}, "
        f"late {tally.late}, duplicates {tally.duplicates})"
    )
    print(f"misattributed samples: {checking.wrong} {checking.examples}")
    start_mib, end_mib = rss.get("start", 0) / 1024, rss.get("end", 0) / 1024
    print(f"RSS {start_mib:.1f} MiB → {end_mib:.1f} MiB: growth {100 * growth:.2f} %")
    print(f"CSV: {out_dir / 'soak.csv'}")
    ok = growth < 0.05 and counted == dropped and checking.wrong == 0 and dropped > 0
    print("PASS" if ok else "FAIL")
    if not args.keep_csv:
        for path in out_dir.iterdir():
            path.unlink()
        out_dir.rmdir()
    return 0 if ok else 1


def main() -> int:
    """Parse the options and run."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim-seconds", type=float, default=3600.0)
    parser.add_argument("--time-scale", type=float, default=8.0)
    parser.add_argument("--loss", type=float, default=0.01)
    parser.add_argument("--bus", choices=("virtual", "loopback"), default="virtual")
    parser.add_argument("--keep-csv", metavar="DIR", help="keep the recording in DIR")
    parser.add_argument("--signals", type=int, metavar="N", help="N interrupted writes instead")
    parser.add_argument("--writers", type=int, metavar="N", help="N two-writer rounds instead")
    parser.add_argument(
        "--processes", type=int, metavar="N", help="N interrupted write-params processes instead"
    )
    parser.add_argument("--seed", type=int, default=SEED)
    args = parser.parse_args()
    if args.signals or args.writers or args.processes:
        from benchmarks.soak_writes import process_storm, signal_storm, two_writers

        with tempfile.TemporaryDirectory() as backups:
            ok = True
            if args.signals:
                ok &= signal_storm(args.signals, args.seed, Path(backups))
            if args.writers:
                ok &= two_writers(args.writers, Path(backups))
            if args.processes:
                ok &= process_storm(args.processes, args.seed, Path(backups))
        print("PASS" if ok else "FAIL")
        return 0 if ok else 1
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
