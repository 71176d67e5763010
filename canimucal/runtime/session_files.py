"""The files a session writes: their names, the calibration record's JSON, recording rows.

Kept apart from :mod:`canimucal.runtime.session` (which drives the clients and the
machine): how each output is named, rewritten and appended to.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.io.calibration import (
    CalibrationRecord,
    RecordingRef,
    calibration_to_dict,
    read_calibration,
)
from canimucal.io.recording_writer import RecordingWriter
from canimucal.procedure.tracks import LabelledRows
from canimucal.runtime.resume import partial_path


def output_name(out_dir: Path, stem: str, node_id: int, several: bool, suffix: str) -> Path:
    """``stem.suffix``, or ``stem.node<ID>.suffix`` when several nodes (DESIGN §7)."""
    return out_dir / (f"{stem}.node{node_id}{suffix}" if several else f"{stem}{suffix}")


def calibration_ref(ref: RecordingRef) -> dict[str, Any]:
    """Return the ``recording`` block as a dict."""
    return {"file": ref.file, "sha256": ref.sha256}


def record_with(record: CalibrationRecord, **blocks: Any) -> CalibrationRecord:
    """Return the record with top-level blocks replaced (through the strict reader)."""
    d = calibration_to_dict(record)
    d.update(blocks)
    return read_calibration(json.dumps(d, allow_nan=False))


def record_json(record: CalibrationRecord) -> str:
    """Return the record's JSON text (indent 2, final newline)."""
    return json.dumps(calibration_to_dict(record), indent=2, allow_nan=False) + "\n"


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, replacing what is there."""
    from canimucal.io.atomic import write_text_atomic

    write_text_atomic(path, text, overwrite=True)


def open_resumed(path: Path, header: Mapping[str, Any]) -> RecordingWriter:
    """Append to the recording of an interrupted session (its ``.partial`` is the newer copy)."""
    partial = partial_path(path)
    if partial.exists():
        os.replace(partial, path)
    return RecordingWriter.open(path, header, append=True)


def write_piece(writer: RecordingWriter, piece: LabelledRows) -> None:
    """Append one labelled piece of rows to the recording (no angles: NaN)."""
    block = piece.block
    n = block.n
    if n == 0:
        return
    angles = np.full((n, 3), np.nan)
    if piece.angles_deg is not None:
        angles[:] = piece.angles_deg
    writer.write_rows(
        t=block.t,
        accel=block.accel,
        gyro=block.gyro,
        counter=block.counter,
        position=np.full(n, piece.position),
        alpha_deg=angles[:, 0],
        beta_deg=angles[:, 1],
        psi_deg=angles[:, 2],
        temp_c=np.full(n, block.temp_c),
    )
