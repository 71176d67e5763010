"""Commissioning check after a store: restart the node and read back what it kept (§9).

``write-params --verify-after-restart``: after the store answered, NMT reset node (to the
target node only), wait for its boot-up, then read the calibration block: valid and the CRC
must be what was written, and the CRC must match the values. Only this shows that flash, not
RAM, holds the set: a node may answer a 'save' on a sub-index that stores something else
(issue 24, case 1). The node is left in the NMT state it was found in.

The risk is the restart itself: the node stops sending for its boot time, loses every value
it did not store, and its bus partners see it reboot (heartbeat consumers, a vehicle's
master). Use it on a bench or at commissioning, not on a vehicle in service.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from canimucal.device.client import CalibrationReadout, ImuClient
from canimucal.errors import DeviceError

logger = logging.getLogger(__name__)

RESTART_TIMEOUT_S = 20.0
"""How long the node may take to send its boot-up after the reset."""
POLL_S = 0.05


class RestartVerificationError(DeviceError):
    """After the restart the node does not hold what was written (exit 3)."""

    title = "Not kept across a restart"


@dataclass(frozen=True)
class RestartCheck:
    """What the node held after the restart, and how long it took to come back."""

    readout: CalibrationReadout
    boot_s: float


def verify_after_restart(
    client: ImuClient, crc: int, valid: int, timeout_s: float = RESTART_TIMEOUT_S
) -> RestartCheck:
    """Reset the node, wait for its boot-up, check valid and CRC (module docstring).

    Raises :class:`RestartVerificationError` when the node comes back holding something
    else, :class:`DeviceError` when it does not come back within ``timeout_s``.
    """
    boots = client.boots
    started = time.monotonic()
    client.reset_node()
    while client.boots == boots:
        if time.monotonic() - started > timeout_s:
            raise DeviceError(
                f"node {client.node_id} sent no boot-up within {timeout_s:g} s of NMT reset "
                "node; what it keeps is unknown"
            )
        time.sleep(POLL_S)
    boot_s = time.monotonic() - started
    logger.info("node %d booted %.2f s after the reset", client.node_id, boot_s)
    readout = client.read_calibration_block()
    if readout.valid != valid or readout.crc_stored != crc or not readout.crc_ok:
        state = "CRC ok" if readout.crc_ok else "CRC mismatch"
        raise RestartVerificationError(
            f"after a restart node {client.node_id} holds valid = {readout.valid}, CRC "
            f"0x{readout.crc_stored:08X} ({state}), not the set written (valid = {valid}, CRC "
            f"0x{crc:08X}): the store did not keep it; the node's documented store sub-index "
            "(0x2011) or its storage is wrong"
        )
    return RestartCheck(readout, boot_s)
