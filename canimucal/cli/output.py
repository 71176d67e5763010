"""Shared CLI output helpers: `--json PATH` (with `-` for stdout) and report printing."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.io.atomic import refuse_existing, write_text_atomic


def add_json_option(parser: argparse.ArgumentParser) -> None:
    """``--json PATH`` (``-`` = stdout, replacing the text report) and ``--overwrite``."""
    parser.add_argument(
        "--json",
        metavar="PATH",
        help="write the result as JSON to PATH ('-' for stdout, replacing the text report)",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="allow replacing an output file that exists"
    )


def check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, to replace a ``--json`` file without ``--overwrite``."""
    target = getattr(args, "json", None)
    if target and target != "-":
        refuse_existing(Path(target), overwrite=bool(getattr(args, "overwrite", False)))


def to_jsonable(value: Any) -> Any:
    """Convert numpy values and non-finite floats (→ null) into plain JSON values."""
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps(document: Any) -> str:
    """JSON text, indented, strict (no NaN literals)."""
    return json.dumps(to_jsonable(document), indent=2, allow_nan=False) + "\n"


def emit(args: argparse.Namespace, document: Any, report: str) -> None:
    """Print ``report`` unless ``--json -``; write ``document`` where ``--json`` says."""
    target = getattr(args, "json", None)
    if target == "-":
        print(dumps(document), end="")
        return
    print(report, end="" if report.endswith("\n") else "\n")
    if target:
        write_text_atomic(Path(target), dumps(document), overwrite=args.overwrite)
        print(f"wrote {target}")
