"""Every input the tool reads, through one dispatcher (docs/design.md §5): ``read_recording``.

The formats: the canimucal recording CSV, an imu_tk pair, an imucal CSV with its sections
(:mod:`canimucal.io`), and a CAN bus log in any format python-can reads, decoded into one
node's recording (:mod:`canimucal.runtime.log_import`). The dispatcher sits here, above
both ``io`` and ``device``, so ``solve``, ``analyze``, ``allan``, ``plan --noise`` and
``cm.read_recording`` take every one of them alike.

:func:`detect_format` tells them apart by content, never by name alone: a bus log by its
signature (BLF and SQLite magic, the ASC and TRC headers, a candump line, python-can's CSV
header; a gzip file by its ``.asc.gz``-style name), then the text formats of
:func:`canimucal.io.importers.detect_format`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, cast

from canimucal.device.log_formats import log_format
from canimucal.errors import InputError
from canimucal.io import importers
from canimucal.io.calibration import RecordingRef, sha256_of
from canimucal.io.recording import HeaderValue, Recording, read_recording_csv
from canimucal.model.positions import Plan

if TYPE_CHECKING:  # python-can loads only when a bus log is read
    from collections.abc import Mapping

    from canimucal.io.calibration import Calibration
    from canimucal.runtime.log_import import LogImport

Format = Literal["recording", "imutk", "imucal", "buslog"]
FORMATS: tuple[Format, ...] = (*importers.FORMATS, "buslog")
"""Every input format, as ``--format`` names it."""

_PathLike = str | os.PathLike[str]


def detect_format(path: _PathLike) -> Format:
    """Tell the format of ``path`` from its content (module doc); InputError when none fits."""
    if log_format(path) is not None:
        return "buslog"
    return importers.detect_format(path)


def read_recording(
    path: _PathLike,
    format: Format | None = None,  # noqa: A002 (the public API's name, as in `--format`)
    *,
    second: _PathLike | None = None,
    sample_rate_hz: float | None = None,
    node_id: int | None = None,
    pdo_map: _PathLike | None = None,
    plan: Plan | str | None = None,
    channel: str | None = None,
) -> Recording:
    """Read a recording in any input format (``format`` None: from its content).

    ``second`` is the imu_tk gyro file or the imucal section JSON; ``sample_rate_hz`` the
    rate of an input that has none. A bus log takes ``node_id`` (default: the one IMU in the
    log), ``pdo_map`` (a ``read-params --json`` document), ``plan`` (a plan or its name or
    file, to name the still stretches after its positions) and ``channel`` (for a log of
    several buses); :func:`import_log` also says what the import found.
    """
    kind = format or (detect_format(path) if Path(path).is_file() else "recording")
    if kind == "buslog":
        if second is not None:
            raise InputError("a bus log takes no second input")
        return import_log(
            path,
            node_id=node_id,
            pdo_map=pdo_map,
            plan=plan,
            sample_rate_hz=sample_rate_hz,
            channel=channel,
        ).recording
    log_options = {"node_id": node_id, "pdo_map": pdo_map, "plan": plan, "channel": channel}
    given = [name for name, value in log_options.items() if value is not None]
    if given:
        raise InputError(f"{', '.join(given)}: for bus logs only; {path} is a {kind} file")
    if kind == "recording":
        if second is not None:
            raise InputError("a canimucal recording takes no second input")
        return read_recording_csv(path)
    if kind == "imutk":
        return importers.read_imutk(path, second)
    return importers.read_imucal(path, second, sample_rate_hz)


def import_log(
    path: _PathLike,
    *,
    node_id: int | None = None,
    pdo_map: _PathLike | None = None,
    plan: Plan | str | None = None,
    sample_rate_hz: float | None = None,
    header: Mapping[str, HeaderValue] | None = None,
    channel: str | None = None,
    pose_check: bool = True,
    follow_schedule: bool = False,
    transient_s: float = 1.0,
) -> LogImport:
    """Read one node's recording out of a bus log, with what the import found (``import-log``).

    ``header`` adds keys to the recording's header (the site); ``pose_check`` False takes
    the still stretches as the plan's positions in order without checking each;
    ``follow_schedule`` labels a unit that followed the plan by itself, with ``transient_s``
    moves (:mod:`canimucal.runtime.log_import`).
    """
    from canimucal.io.plans import resolve_plan
    from canimucal.runtime.log_import import import_bus_log

    resolved = resolve_plan(plan) if isinstance(plan, str) else plan
    return import_bus_log(
        path,
        node_id=node_id,
        pdo_map=pdo_map,
        plan=resolved,
        sample_rate_hz=sample_rate_hz,
        header=header,
        channel=channel,
        pose_check=pose_check,
        follow_schedule=follow_schedule,
        transient_s=transient_s,
    )


def calibrate(source: Any, /, **options: Any) -> Calibration:
    """Calibrate from a recording, its path (any input format) or position averages.

    ``cm.calibrate``: a path is read with :func:`read_recording` and named in the result
    (file name and SHA-256); everything else, and every option, goes to
    :func:`canimucal.analysis.solve.calibrate`, whose defaults are ``canimucal solve``'s.
    """
    from canimucal.analysis.solve import calibrate as solve_calibrate

    if isinstance(source, str | os.PathLike):
        path = Path(source)
        ref = RecordingRef(file=path.name, sha256=sha256_of(path))
        return cast("Calibration", solve_calibrate(read_recording(path), ref=ref, **options))
    return cast("Calibration", solve_calibrate(source, **options))
