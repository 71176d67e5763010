"""Build helpers for the reference firmware's C sources (``firmware/``), host gcc.

``make test`` compiles the module's core with gcc and runs its C unit tests and the
differential tests against the Python side. Without gcc these tests skip with the reason
(``.ci/run`` installs gcc and libc6-dev, so CI never skips them). Sources of CANopenNode are
not in the repo: tests that need them use ``../shared/third_party`` by path (or
``$CANIMUCAL_SHARED_DIR/third_party``) and skip when it is absent (a clone without the shared
tree).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

PROJECT = Path(__file__).resolve().parents[2]
FIRMWARE = PROJECT / "firmware"
MODULE = FIRMWARE / "module"
SHARED = Path(os.environ.get("CANIMUCAL_SHARED_DIR") or PROJECT.parent / "shared")
THIRD_PARTY = SHARED / "third_party"
CANOPENNODE = THIRD_PARTY / "CANopenNode"
CANOPENLINUX = THIRD_PARTY / "CANopenLinux"
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]

Compile = Callable[..., Path]


def gcc_or_skip() -> str:
    """Path of gcc, or skip: the C tests need a host compiler (CI installs one)."""
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is not installed (apt-get install gcc libc6-dev)")
    return gcc


def third_party_or_skip() -> Path:
    """``../shared/third_party`` (CANopenNode, CANopenLinux), or skip when absent."""
    if not (CANOPENNODE / "301" / "CO_ODinterface.h").is_file():
        pytest.skip(f"CANopenNode sources not found at {CANOPENNODE}")
    return THIRD_PARTY


@pytest.fixture(scope="session")
def compile_c(tmp_path_factory: pytest.TempPathFactory) -> Compile:
    """``compile_c(sources, name, flags=(), shared=False, link=True, strict=True)``: gcc.

    Builds into a tmp dir; fails the test with gcc's output when it does not compile (with
    ``strict``, on any warning); returns the built file.
    """
    gcc = gcc_or_skip()
    out_dir = tmp_path_factory.mktemp("firmware-build")

    def build(
        sources: Sequence[Path],
        name: str,
        flags: Sequence[str] = (),
        *,
        shared: bool = False,
        link: bool = True,
        strict: bool = True,
    ) -> Path:
        out = out_dir / name
        warnings = STRICT if strict else ["-std=gnu11", "-w"]  # third-party code: errors only
        cmd = [gcc, *warnings, *flags, *map(str, sources), "-o", str(out)]
        if shared:
            cmd[1:1] = ["-shared", "-fPIC"]
        if not link:
            cmd.insert(1, "-c")
        elif not shared:
            cmd.append("-lm")
        run = subprocess.run(cmd, capture_output=True, text=True, check=False)
        assert run.returncode == 0 and not run.stderr, " ".join(cmd) + "\n" + run.stderr
        return out

    return build
