"""Facts of the IMU node that the numerics, the files and the client share (docs/design.md §4).

Each is written once, here; the device's object table (:mod:`canimucal.device.objects`)
names them in its EDS entries and range rules.
"""

from __future__ import annotations

COUNTER_BITS = 16
"""The sample counter 0x2002:02 is an UNSIGNED16."""

COUNTER_MODULUS = 1 << COUNTER_BITS
"""The sample counter wraps at 65536: gaps and pairing count modulo this."""

OUTPUT_DATA_RATES_HZ: tuple[int, ...] = (50, 100, 200, 250, 500, 1000)
"""Output data rates the node offers (0x2010:03); an inferred rate near one snaps to it."""

INT16_MIN = -(1 << 15)
INT16_MAX = (1 << 15) - 1
"""The raw outputs 0x2000/0x2001 are INTEGER16: they saturate at these counts."""

INT16_SPAN = 1 << 16
"""The INT16 span, 65536 counts: the largest bias a calibration may hold, the largest noise
a simulated sensor may ask for."""
