"""The docs/design.md §4 PDO mapping, for tests and benchmarks that code frames without a node."""

from __future__ import annotations

from canimucal.device.pdo_layout import (
    ACCEL_RAW,
    GYRO_RAW,
    SAMPLE_INFO,
    SampleLayout,
    layout_from_mapping,
    mapping_entry,
)


def design_layout(node_id: int) -> SampleLayout:
    """Return the docs/design.md §4 mapping (EDS defaults) at the default COB-IDs of ``node_id``.

    TPDO1 accel x/y/z + counter, TPDO2 gyro x/y/z + counter (INT16, U16), TPDO3 temperature
    + counter + status. The client reads the real mapping from the node; this is for tools
    that produce or decode frames without one (benchmarks, tests).
    """
    xyz_counter = {
        n: [mapping_entry(index, s, 16) for s in (1, 2, 3)] + [mapping_entry(SAMPLE_INFO, 2, 16)]
        for n, index in ((1, ACCEL_RAW), (2, GYRO_RAW))
    }
    info = [mapping_entry(SAMPLE_INFO, 1, 16), mapping_entry(SAMPLE_INFO, 2, 16)]
    entries = {**xyz_counter, 3: [*info, mapping_entry(SAMPLE_INFO, 3, 8)]}
    cob_ids = {n: base + node_id for n, base in ((1, 0x180), (2, 0x280), (3, 0x380))}
    return layout_from_mapping(cob_ids, entries)
