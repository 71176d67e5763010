"""Which 0x1010 sub-index stores the calibration: the one the node names (docs/design.md §4, §9).

A node says it in 0x2011 (U8, read-only): the 0x1010/0x1011 sub-index whose 'save'/'load'
covers the calibration block 0x2100-0x2121, or 1 when only "all parameters" does. Reading
0x1010:N tells nothing: CANopenNode answers it from the object's default whether or not a
storage group is registered there, and CANopenLinux keeps its own node-id/bit-rate record on
sub 4, so a 'save' to a sub-index the node did not name may store something else and still
answer OK (issue 24, case 1).

The rule: store with the documented sub-index; a node that documents none is stored with
0x1010:01, which CiA 301 defines as every parameter; ``--store-sub`` may name another only
where the node documents none (or 1). Checked before anything is written.
"""

from __future__ import annotations

import logging

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.errors import DeviceError, InputError, SdoAbort

logger = logging.getLogger(__name__)

STORE_SUB_CHOICES = (od.STORE_ALL_SUB, od.STORE_APP_SUB, od.STORE_CALIBRATION_SUB)
"""What ``--store-sub`` may ask for."""


def documented_store_sub(client: ImuClient) -> int | None:
    """Read the node's 0x2011; None when it has no such object (it does not say)."""
    try:
        value = int(client.read_value(od.CALIBRATION_STORE_SUB, 0, "u8"))
    except SdoAbort as exc:
        if exc.code in (od.ABORT_NO_OBJECT, od.ABORT_NO_SUBINDEX):
            return None
        raise
    if not 1 <= value <= 127:
        raise DeviceError(
            f"node {client.node_id}: 0x2011 = {value} names no 0x1010 sub-index; nothing written"
        )
    return value


def choose_store_sub(client: ImuClient, requested: int | None) -> int:
    """Pick the 0x1010 sub-index to store the calibration with (module docstring).

    Raises :class:`InputError` (exit 2) for a ``requested`` sub-index the node contradicts
    and :class:`DeviceError` (exit 3) when the node offers no usable one; nothing is
    written either way.
    """
    documented = documented_store_sub(client)
    if requested is not None:
        return _requested(client, requested, documented)
    if documented is not None and documented != od.STORE_ALL_SUB:
        if client.store_supported(documented):
            return documented
        raise DeviceError(
            f"node {client.node_id} documents 0x1010:{documented:02X} for its calibration "
            "(0x2011) but does not offer it; nothing written"
        )
    if client.store_supported(od.STORE_ALL_SUB):
        if documented is None:
            logger.warning(
                "node %d does not say which 0x1010 sub-index stores its calibration (no "
                "0x2011): storing every parameter with 0x1010:01",
                client.node_id,
            )
        return od.STORE_ALL_SUB
    raise DeviceError(
        f"node {client.node_id} offers no 0x1010:01 and "
        + ("names none for its calibration (0x2011 = 1)" if documented else "has no 0x2011")
        + "; nothing written (store=False writes RAM only)",
        options=("store=False",),
    )


def _requested(client: ImuClient, requested: int, documented: int | None) -> int:
    if requested not in STORE_SUB_CHOICES:
        raise InputError(
            f"store_sub must be one of {STORE_SUB_CHOICES}, got {requested}",
            options=("store_sub",),
        )
    names_one = documented not in (None, od.STORE_ALL_SUB)
    if names_one and requested not in (documented, od.STORE_ALL_SUB):
        raise InputError(
            f"store_sub {requested}: node {client.node_id} stores its calibration with "
            f"0x1010:{documented:02X} (0x2011); nothing written",
            options=("store_sub",),
        )
    if requested == od.STORE_APP_SUB and documented != od.STORE_APP_SUB:
        logger.warning(
            "storing with 0x1010:03 as asked: CiA 301 defines it for 0x6000-0x9FFF, "
            "so this node must map the calibration there"
        )
    if not client.store_supported(requested):
        raise DeviceError(f"node {client.node_id} has no 0x1010:{requested:02X}; nothing written")
    return requested
