"""What a session writes about each node: the record's ``device`` block, the recording header."""

from __future__ import annotations

from typing import Any

import numpy as np

from canimucal.analysis.calibrate import SiteConditions
from canimucal.device.client import Identity
from canimucal.io.calibration import Device


def device_of(node_id: int, identity: Identity) -> Device:
    """Return the calibration record's ``device`` block of a node."""
    return Device(
        node_id=node_id,
        vendor_id=identity.vendor_id,
        product_code=identity.product_code,
        revision=identity.revision,
        serial=identity.serial,
    )


def recording_header(
    rate_hz: float, site: SiteConditions, identity: Identity, node_id: int
) -> dict[str, Any]:
    """Return the header of a node's recording CSV (DESIGN §5)."""
    header: dict[str, Any] = {
        "sample_rate_hz": rate_hz,
        "node_id": node_id,
        "device_serial": identity.serial,
        "g": site.g,
        "heading_deg": float(np.rad2deg(site.heading)),
        "accel_lsb": site.accel_lsb,
        "gyro_lsb": site.gyro_lsb,
    }
    if site.latitude is not None:
        header["latitude_deg"] = float(np.rad2deg(site.latitude))
    if site.height_m is not None:
        header["height_m"] = site.height_m
    return header
