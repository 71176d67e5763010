"""Store benchmark against an IMU node: slow stores and timer skew.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/store.py [--delays 0,0.5,1,2.5,5]
[--skews -10000,-5000,-1000,0,1000,5000,10000] [--seconds 5] [--node simulated]``.
``--node`` picks the independent (durand) node, the default, or the simulated one; both take
the same behaviours (truth JSON keys, docs/design.md §5). "dropped" counts what each drops during a
store: samples and TPDO events (independent), TPDO frames (simulated).

1. Write + store time against the store's duration. The node blocks the SDO answer of
   0x1010 for the delay (CANopenNode erases flash inside the SDO handler) and drops its
   TPDOs meanwhile. Per delay: the whole ``write_calibration_transaction`` wall time, the
   number of stores the node made (must be 1: never retried), frames the node dropped, and
   the outcome; a last row runs a store longer than ``--store-timeout-s`` to time the
   "store not confirmed" path (no rollback).
2. Loss against event-timer skew. The node's TPDO event timer runs ``skew`` ppm slow (+)
   or fast (-) against its sensor clock. Per skew: samples paired in ``--seconds``, lost
   samples (counter skipped by the device), duplicates (counter re-sent: not a loss) and
   the client's skew estimate in ppm.

Python-can's virtual bus, in-process; figures are for this host (times include its load).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import uuid
from pathlib import Path

import can
import numpy as np

from canimucal.device.client import ImuClient
from canimucal.device.transaction import StoreNotConfirmedError, write_calibration_transaction
from canimucal.errors import DeviceError
from canimucal.io.calibration import Calibration
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode
from tests.support.independent_node import Behaviour, IndependentImuNode

NODE = 0x10
Node = IndependentImuNode | SimulatedImuNode


def _calibration(scale: float) -> Calibration:
    lsb = float(np.float32(9.80665 / 2048.0))
    return Calibration.from_dict(
        {
            "schema": "canimucal.calibration/1",
            "plan": "five",
            "device": {"serial": 0},
            "accel": {"bias": [1.0, -2.0, scale], "K": (np.eye(3) * 1.01 / lsb).tolist()},
            "gyro": {"bias": [0.5, 0.0, -0.5]},
        }
    )


def _pair(kind: str, **behaviour: object) -> tuple[Node, ImuClient, list[can.BusABC]]:
    channel = f"bench-store-{uuid.uuid4().hex[:8]}"
    buses = [can.Bus(interface="virtual", channel=channel) for _ in range(2)]
    node: Node
    if kind == "simulated":
        node = SimulatedImuNode(buses[0], NODE, Truth.from_dict(behaviour), seed=1).start()
    else:
        node = IndependentImuNode(buses[0], NODE, Behaviour(**behaviour)).start()  # type: ignore[arg-type]
    return node, ImuClient(buses[1], NODE, sdo_timeout_s=1.0), buses


def _dropped(node: Node) -> int:
    if isinstance(node, SimulatedImuNode):
        return node.frames_dropped_in_store
    return int(node.stats["dropped"])


def _close(node: Node, client: ImuClient, buses: list[can.BusABC]) -> None:
    client.close()
    node.stop()
    for bus in buses:
        bus.shutdown()


def store_rows(
    delays: list[float], timeout_s: float, kind: str = "independent"
) -> list[dict[str, object]]:
    rows = []
    cases = [(d, timeout_s) for d in delays] + [(timeout_s + 1.0, timeout_s)]
    for k, (delay, timeout) in enumerate(cases):
        node, client, buses = _pair(kind, store_delay_s=delay, nmt_start="operational")
        with tempfile.TemporaryDirectory() as backups:
            t0 = time.monotonic()
            try:
                write_calibration_transaction(
                    client, _calibration(k + 1.0), backup_dir=backups, store_timeout_s=timeout
                )
                outcome = "stored"
            except StoreNotConfirmedError:
                outcome = "not confirmed (exit 3)"
            except DeviceError as exc:
                outcome = f"error: {exc}"
            elapsed = time.monotonic() - t0
        time.sleep(max(0.0, delay - elapsed) + 0.2)  # let a late store finish
        rows.append(
            {
                "store_s": delay,
                "timeout_s": timeout,
                "write_store_s": round(elapsed, 3),
                "stores": len(node.store_log),
                "dropped": _dropped(node),
                "outcome": outcome,
            }
        )
        _close(node, client, buses)
    return rows


def skew_rows(
    skews: list[float], seconds: float, kind: str = "independent"
) -> list[dict[str, object]]:
    rows = []
    for skew in skews:
        node, client, buses = _pair(kind, timer_skew_ppm=skew, nmt_start="operational")
        client.start_streaming()
        block = client.read_samples(10**9, timeout_s=seconds)
        estimate = client.skew_ppm
        _close(node, client, buses)
        rows.append(
            {
                "skew_ppm": skew,
                "samples": block.n,
                "lost": block.lost_samples + block.lost_accel + block.lost_gyro,
                "duplicates": block.duplicates,
                "estimated_ppm": None if estimate is None else round(estimate),
            }
        )
    return rows


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--delays", default="0,0.5,1,2.5,5")
    parser.add_argument("--store-timeout-s", type=float, default=10.0)
    parser.add_argument("--skews", default="-10000,-5000,-1000,0,1000,5000,10000")
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    parser.add_argument("--node", choices=("independent", "simulated"), default="independent")
    args = parser.parse_args()
    print(f"node: {args.node}")
    stores = store_rows(_floats(args.delays), args.store_timeout_s, args.node)
    print("store delay  timeout  write+store  stores  dropped  outcome")
    for r in stores:
        print(
            f"{r['store_s']:>9.1f} s {r['timeout_s']:>6.1f} s {r['write_store_s']:>10.2f} s "
            f"{r['stores']:>7} {r['dropped']:>8}  {r['outcome']}"
        )
    skews = skew_rows(_floats(args.skews), args.seconds, args.node)
    print(f"\ntimer skew (ppm)  samples  lost  duplicates  estimated (ppm) in {args.seconds:g} s")
    for r in skews:
        print(
            f"{r['skew_ppm']:>16.0f} {r['samples']:>8} {r['lost']:>5} {r['duplicates']:>11} "
            f"{r['estimated_ppm']!s:>16}"
        )
    if args.json is not None:
        args.json.write_text(json.dumps({"store": stores, "skew": skews}, indent=1) + "\n")


if __name__ == "__main__":
    main()
