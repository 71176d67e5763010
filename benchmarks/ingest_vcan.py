"""Loss over SocketCAN vcan with the default socket receive buffer (issue 3, item 7).

The virtual bus of ``benchmarks/ingest.py`` never drops a frame; a kernel socket does when
its receive buffer overflows. Here a producer **process** sends paired TPDO1/TPDO2 frames
(8 bytes each, sample counter in both, paced in 1 ms batches) on ``vcan0`` at 200, 1000 and
~3500 samples/s (3500: the ceiling of classical CAN at 1 Mbit/s); the client (``ImuClient``
streaming with a known layout: notifier thread -> raw queue -> consumer thread) counts lost
samples and halves by counter. The socket buffer is python-can's default (``SO_RCVBUF`` not
set: ``/proc/sys/net/core/rmem_default``).

Run (needs vcan0; this machine has none, so inside the VM):
    ../shared/tools/canvm/run_in_vm.sh . 'PYTHONPATH=. python benchmarks/ingest_vcan.py'
or natively: ``.venv/bin/python benchmarks/ingest_vcan.py [--seconds 10] [--rates 200,1000,3500]``.
"""

from __future__ import annotations

import argparse
import os
import struct
import subprocess
import sys
import time
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canimucal.device.client import ImuClient  # noqa: E402
from canimucal.model.samples import concat_blocks  # noqa: E402
from tests.support.pdo import design_layout  # noqa: E402

NODE = 0x10
T1, T2 = 0x180 + NODE, 0x280 + NODE


LAYOUT = design_layout(NODE)


def produce(channel: str, rate_hz: float, seconds: float) -> None:
    """Send ``rate_hz`` paired samples per second for ``seconds`` (1 ms batches)."""
    bus = can.Bus(interface="socketcan", channel=channel)
    n_total = int(rate_hz * seconds)
    t0 = time.perf_counter()
    counter = 0
    while counter < n_total:
        due = min(int((time.perf_counter() - t0) * rate_hz) + 1, n_total)
        while counter < due:
            c = counter % 65536
            for cob, values in ((T1, (1, -2048, 3)), (T2, (-1, 2, 5))):
                msg = can.Message(
                    arbitration_id=cob, data=struct.pack("<hhhH", *values, c), is_extended_id=False
                )
                while True:
                    try:
                        bus.send(msg, timeout=0.1)
                        break
                    except can.CanOperationError:  # transmit queue full: retry
                        time.sleep(0.0002)
            counter += 1
        time.sleep(0.001)
    elapsed = time.perf_counter() - t0
    print(f"{n_total} {elapsed:.3f}", flush=True)
    bus.shutdown()


def measure(channel: str, rate_hz: float, seconds: float) -> dict[str, float]:
    """Run a producer process against a streaming client; return the counts."""
    bus = can.Bus(interface="socketcan", channel=channel)
    client = ImuClient(bus, NODE)
    client.start_streaming(layout=LAYOUT, rate_hz=min(rate_hz, 1000.0), nmt_start=False)
    cmd = [sys.executable, __file__, "--produce", str(rate_hz), "--seconds", str(seconds)]
    cmd += ["--channel", channel]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.split()
    sent, produce_s = int(out[0]), float(out[1])
    time.sleep(0.5)
    client.stop_streaming(keep_operational=True)
    blocks = []
    while (b := client.get_block(0.0)) is not None:
        blocks.append(b)
    block = concat_blocks(blocks)
    client.close()
    bus.shutdown()
    lost = block.lost_samples + block.lost_accel + block.lost_gyro
    return {
        "rate": rate_hz,
        "sent": sent,
        "achieved": sent / produce_s,
        "received": block.n,
        "lost_samples": block.lost_samples,
        "lost_halves": block.lost_accel + block.lost_gyro,
        "loss_pct": 100.0 * lost / max(sent, 1),
        "missing_tail": sent - block.n - block.lost_samples,
    }


def main() -> None:
    """Parse flags; produce (child) or measure every rate (parent)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--channel", default=os.environ.get("CANIMUCAL_VCAN", "vcan0"))
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--rates", default="200,1000,3500")
    p.add_argument("--produce", type=float, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.produce is not None:
        produce(args.channel, args.produce, args.seconds)
        return
    rmem = Path("/proc/sys/net/core/rmem_default").read_text().strip()
    print(
        f"vcan loss, default socket receive buffer (rmem_default {rmem} bytes), {args.seconds:g} s"
    )
    print(
        f"{'rate/s':>8}{'achieved':>10}{'sent':>8}{'received':>10}{'lost smp':>10}"
        f"{'lost half':>10}{'loss %':>8}"
    )
    for rate in (float(r) for r in args.rates.split(",")):
        r = measure(args.channel, rate, args.seconds)
        print(
            f"{r['rate']:>8.0f}{r['achieved']:>10.0f}{r['sent']:>8.0f}{r['received']:>10.0f}"
            f"{r['lost_samples']:>10.0f}{r['lost_halves']:>10.0f}{r['loss_pct']:>8.3f}"
        )


if __name__ == "__main__":
    main()
