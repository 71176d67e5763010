"""The heap thresholds the array-sweeping commands set (canimucal/cli/heap.py)."""

from __future__ import annotations

import ctypes.util
import platform
import subprocess
import sys

import pytest

GLIBC = platform.libc_ver()[0] == "glibc" and ctypes.util.find_library("c") is not None


@pytest.mark.skipif(not GLIBC, reason="the thresholds are glibc's")
def test_glibc_takes_both_thresholds() -> None:
    # in a child: the thresholds are the process's for good
    code = (
        "from canimucal.cli.heap import keep_heap_for_arrays as k; "
        "raise SystemExit(k() is not True)"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0
