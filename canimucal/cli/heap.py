"""The C heap for the commands that sweep a recording's arrays (solve, allan, analyze).

glibc gives every allocation above its mmap threshold (128 KiB at start, raised as such
blocks are freed) fresh pages from the kernel, and hands freed heap memory back above its
trim threshold; each fresh page then costs a page fault on first touch. A recording's block
temporaries are megabytes each, made and dropped some hundred times a file: at 10⁷ rows
`solve` spent 3.2-3.7 s of system time in those faults, 1.6-1.9 s with the two thresholds
set as here (docs/performance.md). The memory stays the process's until it exits; the peak
grows by about the largest block temporaries (817 → 866 MiB at 10⁷ rows). A C library
other than glibc is left alone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

log = logging.getLogger(__name__)

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 * 2**20
"""Blocks up to this size come from the heap (glibc's largest allowed value on 64 bits)."""
TRIM_THRESHOLD_BYTES = 2**30
"""Free heap memory up to this much is kept for the next block instead of given back."""


def keep_heap_for_arrays() -> bool:
    """Set glibc's mmap and trim thresholds (module doc); say whether both were set."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):  # no C library by that name, or no mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    done = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
    done = mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1 and done
    log.debug("heap thresholds for bulk arrays: %s", "set" if done else "not set")
    return done
