"""`canimucal read-params`: identity, nominal LSBs and the calibration block a node holds.

``--json PATH`` writes, per node, the identity, the nominal values, the docs/design.md §5
``readback`` block (the device's values as read, valid flag, CRC check) and the calibration
record of what the node holds, with the raw ``objects`` map (so the file restores it with
``write-params``), and the TPDO communication and mapping objects as ``pdo``
(``{"0x1800:01": 400, …}``: ``import-log --pdo-map`` decodes a log of the node with them).
Several ``--node-id``: one file per node, ``NAME.node<ID>.json``.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

import numpy as np

from canimucal.cli.bus_options import (
    add_bus_options,
    node_ids,
    open_from_args,
    require_single_stdout,
)
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.io.atomic import per_node_path

if TYPE_CHECKING:
    from canimucal.device.client import ImuClient

SCHEMA = "canimucal.read-params/1"


def add_subparser(subparsers: Any) -> None:
    """Register ``read-params``."""
    p = subparsers.add_parser(
        "read-params",
        help="read identity and calibration from the IMU node(s)",
        description="Read the node's identity, nominal LSBs and calibration block (read-only).",
    )
    add_bus_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Read every node and report."""
    check_outputs(args)
    require_single_stdout(args, len(node_ids(args)))
    with open_from_args(args) as session:
        session.refuse_second_answerers("their answers would mix; nothing read")
        several = len(session.clients) > 1
        for nid, client in session.clients.items():
            document = read_document(client)
            target = args.json
            if target and target != "-":
                target = str(per_node_path(target, nid, several))
            emit(
                argparse.Namespace(json=target, overwrite=args.overwrite),
                document,
                report(document),
            )
    return 0


def read_document(client: ImuClient) -> dict[str, Any]:
    """Everything ``read-params`` reports about one node, as a JSON-ready dict."""
    from canimucal.device.calibration_map import readback_of, record_from_block
    from canimucal.device.objects import format_key
    from canimucal.schema import to_plain

    identity = client.identity()
    accel_lsb, gyro_lsb = client.nominal_lsb()
    odr = client.output_data_rate()
    readout = client.read_calibration_block()
    calibration = record_from_block(
        readout.block, identity, node_id=client.node_id, objects=readout.objects, raw=readout.raw
    ).to_dict()
    return {
        "schema": SCHEMA,
        "device": {
            "node_id": client.node_id,
            "vendor_id": identity.vendor_id,
            "product_code": identity.product_code,
            "revision": identity.revision,
            "serial": identity.serial,
            "device_name": identity.device_name,
            "hardware_version": identity.hardware_version,
            "software_version": identity.software_version,
        },
        "nominal": {"accel_lsb": accel_lsb, "gyro_lsb": gyro_lsb, "output_data_rate_hz": odr},
        "readback": to_plain(readback_of(readout.block, readout.valid, readout.crc_ok)),
        "crc_stored": readout.crc_stored,
        "calibration": calibration,
        "pdo": {format_key(*key): value for key, value in client.pdo_objects().items()},
        "bus_load": client.bus_load(full_window=True).as_dict(),
    }


def report(document: dict[str, Any]) -> str:
    """Human-readable summary of one node."""
    d, n, r = document["device"], document["nominal"], document["readback"]
    state = (
        "valid, CRC ok"
        if r["valid"] == 1 and r["crc_ok"]
        else (
            f"valid = {r['valid']}, CRC {'ok' if r['crc_ok'] else 'MISMATCH'}: nominal values apply"
        )
    )
    lines = [
        f"node {d['node_id']}: {d['device_name'] or 'unnamed'}, serial {d['serial']}, "
        f"vendor 0x{d['vendor_id']:08X}, product 0x{d['product_code']:08X}, "
        f"revision 0x{d['revision']:08X}, hardware {d.get('hardware_version') or '—'}, "
        f"software {d.get('software_version') or '—'}",
        f"nominal: accel {n['accel_lsb']:.8g} m/s² per count, gyro {n['gyro_lsb']:.8g} rad/s "
        f"per count, {n['output_data_rate_hz']} Hz",
        f"calibration: {state}",
        "accel bias (counts): " + _row(r["accel_bias"]),
        "accel correction M (m/s² per count):",
        *("  " + _row(row) for row in r["accel_correction"]),
        "gyro bias (counts): " + _row(r["gyro_bias"]),
        "gyro correction N (rad/s per count):",
        *("  " + _row(row) for row in r["gyro_correction"]),
        "gyro G (counts per m/s²):",
        *("  " + _row(row) for row in r["gyro_g"]),
        "base tilt (deg): "
        + _row([None if v is None else float(np.rad2deg(v)) for v in r["base_tilt_rad"]]),
        _trim_line(r.get("mounting_trim_rad")),
    ]
    if "bus_load" in document:
        from canimucal.device.busload import BusLoad

        load = document["bus_load"]
        lines.append(BusLoad(**{key: load[key] for key in BusLoad._fields}).text())
    return "\n".join(lines) + "\n"


def _trim_line(trim: Any) -> str:
    """Word the alignment rotation the node applies, or that it has none (0x2122 absent)."""
    if trim is None:
        return (
            "mounting trim: no 0x2122 on this node (a firmware before it; 39-object CRC): "
            "no alignment applied"
        )
    degrees = [None if v is None else float(np.rad2deg(v)) for v in trim]
    return "mounting trim alpha, beta, psi (deg): " + _row(degrees)


def _row(values: Any) -> str:
    """Numbers as the device holds them; ``non-finite`` where it holds NaN or ±inf (JSON null)."""
    return ", ".join("non-finite" if v is None else f"{float(v):.8g}" for v in values)
