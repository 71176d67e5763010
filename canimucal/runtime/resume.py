"""Resuming an interrupted session from the recording(s) it left in its output directory.

A session writes every sample to ``recording.csv`` (``recording.node<ID>.csv`` with several
nodes) with each accepted position's label and angles. :func:`load_resume_state` reads them
back — a leftover ``.partial`` (the process died before closing it) is the newer copy and is
read instead —, checks the plan's poses against the recorded angles and that each node is
still the unit the recording came from (its serial), and returns the accepted averages per
node and the next position to measure. The procedure then starts there (warm-up
still applies after a power cycle) and the session appends to the same recording(s).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.analysis.session_model import header_prior
from canimucal.errors import DeviceError, InputError
from canimucal.io.atomic import read_bytes_nofollow
from canimucal.io.grouping import position_averages
from canimucal.io.recording import Recording, parse_recording
from canimucal.model.plan import KPrior
from canimucal.model.positions import Plan, PositionAverage
from canimucal.model.vocabulary.plans import builtin_names, builtin_plan
from canimucal.procedure.config import ResumeState

ANGLE_MATCH_DEG = 1e-3
"""Recorded angles (written in degrees) must equal the plan's to this many degrees."""


def recording_path(out_dir: Path, node_id: int, several: bool) -> Path:
    """``recording.csv``, or ``recording.node<ID>.csv`` when several nodes (docs/design.md §7)."""
    return out_dir / (f"recording.node{node_id}.csv" if several else "recording.csv")


def partial_path(path: Path) -> Path:
    """Return the ``.partial`` file a recording is written to until it is closed."""
    return path.with_name(path.name + ".partial")


def load_resume_state(
    out_dir: str | Path,
    plan: Plan,
    node_ids: Sequence[int] | None = None,
    serials: Mapping[int, int] | None = None,
) -> ResumeState:
    """Read the recording(s) in ``out_dir`` and say where the procedure goes on.

    ``node_ids`` defaults to every ``recording*.csv`` found (one file: a single node, id 0
    unless given). Raises :class:`InputError` when a recording is missing or unreadable, when
    a recorded position is not in the plan or its angles differ from the plan's pose, or when
    the nodes disagree about which positions were accepted; :class:`DeviceError` when
    ``serials`` (node id → the serial the node answers with now) names another unit than the
    recording's ``device_serial``: averages of two units must never make one calibration.
    The first node's recorded first position goes along (``first_accel``, ``first_gyro``), so
    the resumed procedure averages the later positions as long as the interrupted one did.
    """
    out = Path(out_dir)
    if not out.is_dir():
        raise InputError(f"cannot resume: {out} is not a directory")
    ids = list(node_ids) if node_ids is not None else _found_nodes(out)
    several = len(ids) > 1
    averages: dict[int, dict[int, PositionAverage]] = {}
    files: dict[int, Path] = {}
    priors: dict[int, KPrior] = {}
    first_accel: np.ndarray | None = None
    first_gyro: np.ndarray | None = None
    for node_id in ids:
        path = recording_path(out, node_id, several)
        source = partial_path(path) if os.path.lexists(partial_path(path)) else path
        if not os.path.lexists(source):
            raise InputError(f"cannot resume: no {path.name} in {out}")
        recording = parse_recording(read_bytes_nofollow(source), str(source))
        if serials is not None and node_id in serials:
            _check_unit(recording, source, node_id, serials[node_id])
        averages[node_id] = _accepted(recording, source, plan)
        files[node_id] = source
        held = header_prior(recording.header)
        if held is not None:
            priors[node_id] = held
        if first_accel is None and np.any(recording.position == 0):
            first_accel = np.asarray(recording.accel[recording.position == 0], dtype=np.float64)
            first_gyro = np.asarray(recording.gyro[recording.position == 0], dtype=np.float64)
    done = {frozenset(a) for a in averages.values()}
    if len(done) > 1:
        raise InputError(f"cannot resume: the recordings in {out} hold different positions")
    indices = sorted(next(iter(done))) if done else []
    if indices != list(range(len(indices))):
        raise InputError(f"cannot resume: positions {indices} are not the plan's first ones")
    if len(indices) >= len(plan.positions):
        raise InputError(f"cannot resume: every position of the plan is already in {out}")
    return ResumeState(averages, len(indices), files, priors, first_accel, first_gyro)


def recorded_plan(out_dir: str | Path) -> Plan:
    """Return the built-in plan the interrupted session's recording names in its header.

    ``--resume`` without ``--plan``: the header's ``plan`` (docs/design.md §5). A custom plan
    cannot be rebuilt from its recorded positions (the later ones are not there):
    :class:`InputError` asks for the plan file.
    """
    header, source = _recorded_header(out_dir)
    name = header.get("plan")
    if not isinstance(name, str) or name not in builtin_names():
        raise InputError(
            f"cannot resume: {source} names no built-in plan ({name or 'none'}): give plan "
            "(the plan file of the interrupted session)",
            options=("give plan",),
        )
    return builtin_plan(name)


def _recorded_header(out_dir: str | Path) -> tuple[dict[str, Any], Path]:
    """Return the header of the interrupted session's (first node's) recording and its path."""
    out = Path(out_dir)
    if not out.is_dir():
        raise InputError(f"cannot resume: {out} is not a directory")
    ids = _found_nodes(out)
    path = recording_path(out, ids[0], len(ids) > 1)
    source = partial_path(path) if os.path.lexists(partial_path(path)) else path
    return dict(parse_recording(read_bytes_nofollow(source), str(source)).header), source


def recorded_site(out_dir: str | Path) -> dict[str, float]:
    """Return the site the interrupted session recorded: ``g``, ``latitude_deg``, ``height_m``.

    What its header holds of them (a resumed session goes on at the site it started at).
    """
    header, _ = _recorded_header(out_dir)
    keys = ("g", "latitude_deg", "height_m")
    return {k: float(v) for k in keys if isinstance(v := header.get(k), int | float)}


def resumed_message(state: ResumeState) -> str:
    """``resumed: positions 1–4 kept from FILE`` (one line; positions counted from 1)."""
    files = ", ".join(str(p) for p in state.recordings.values()) or "the recording"
    n = state.next_index
    if n == 0:
        return f"resumed: no position kept from {files} (starting at position 1)"
    kept = "position 1" if n == 1 else f"positions 1–{n}"
    return f"resumed: {kept} kept from {files}"


def _found_nodes(out: Path) -> list[int]:
    ids: set[int] = set()
    for p in out.glob("recording.node*.csv*"):
        digits = p.name.removeprefix("recording.node").split(".")[0]
        if digits.isdigit() and p.name.endswith((".csv", ".csv.partial")):
            ids.add(int(digits))
    if ids:
        return sorted(ids)
    if (out / "recording.csv").exists() or (out / "recording.csv.partial").exists():
        return [0]
    raise InputError(f"cannot resume: no recording in {out}")


def _check_unit(recording: Recording, source: Path, node_id: int, serial: int) -> None:
    recorded = recording.header.get("device_serial")
    if recorded is not None and int(recorded) != int(serial):
        raise DeviceError(
            f"cannot resume: {source.name} was recorded from serial {int(recorded)}, node "
            f"{node_id} is serial {int(serial)} now: another unit (start a new session in "
            "another directory)"
        )


def _accepted(recording: Recording, source: Path, plan: Plan) -> dict[int, PositionAverage]:
    labelled = recording.position[recording.position >= 0]
    if labelled.size == 0:
        return {}
    out: dict[int, PositionAverage] = {}
    for index, average in zip(
        sorted({int(x) for x in labelled}), position_averages(recording), strict=True
    ):
        if index >= len(plan.positions):
            raise InputError(
                f"{source}: position {index + 1} recorded, the plan has "
                f"{len(plan.positions)}: a different plan?"
            )
        pose = plan.positions[index]
        recorded = np.rad2deg([average.pose.alpha, average.pose.beta, average.pose.psi])
        planned = np.rad2deg([pose.alpha, pose.beta, pose.psi])
        if not np.allclose(recorded, planned, rtol=0.0, atol=ANGLE_MATCH_DEG):
            raise InputError(
                f"{source}: position {index + 1} was recorded at angles "
                f"{_deg(recorded)} but the plan's pose is {_deg(planned)}: a different plan?"
            )
        out[index] = replace(average, pose=pose)
    return out


def _deg(angles: np.ndarray) -> str:
    return "(" + ", ".join(f"{a:g}°" for a in angles) + ")"
