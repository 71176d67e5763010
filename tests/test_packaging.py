"""Packaging: the licence, one version source, and dependency bounds that CI proves."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import canimucal

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def test_the_licence_is_spdx_mit_with_its_file() -> None:
    project = PYPROJECT["project"]
    assert project["license"] == "MIT" and project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("MIT License") and "the canimucal authors" in text
    assert "setuptools>=77" in PYPROJECT["build-system"]["requires"]  # SPDX licence support


def test_the_version_is_written_once() -> None:
    assert "version" not in PYPROJECT["project"] and "version" in PYPROJECT["project"]["dynamic"]
    attr = PYPROJECT["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "canimucal.version.__version__"
    assert canimucal.__version__ == canimucal.version.__version__


def test_ci_installs_each_lower_bound_pyproject_declares() -> None:
    """`.ci/run` tests with .ci/lowest-constraints.txt: one pin per dependency, at its bound."""
    bounds = {}
    for spec in PYPROJECT["project"]["dependencies"]:
        name, low = re.fullmatch(r"([A-Za-z0-9_.-]+)>=([0-9.]+)(,<[0-9.]+)?", spec).groups()[:2]
        bounds[name.lower()] = low
    pins = {}
    for line in (ROOT / ".ci" / "lowest-constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[name.strip().lower()] = version.strip()
    assert pins.keys() == bounds.keys()
    for name, low in bounds.items():
        padded = low + ".0" * (2 - low.count("."))
        assert pins[name] in (low, padded), name
    assert "make lowest" in (ROOT / ".ci" / "run").read_text()
    assert "-c .ci/lowest-constraints.txt" in (ROOT / "Makefile").read_text()
