"""canimucal: field calibration of a CANopen IMU from small rotations.

The public API (numpy in, results out)::

    import canimucal as cm
    cal = cm.calibrate(cm.read_recording("session.csv"), model="full", tilt=True)
    si = cal.accel.correct(counts)          # (n, 3) counts -> m/s²
    cal.to_json("calibration.json")

Names load on first use, so ``import canimucal`` (and ``canimucal --help``) stays light.
"""

from __future__ import annotations

import importlib as _importlib

from canimucal.version import __version__

TYPE_CHECKING = False
"""``typing.TYPE_CHECKING`` without importing typing: ~10 ms of every command's start-up,
during which a Ctrl-C could only print a traceback (the entry point holds signals after).
Not in ``__all__`` or ``dir()``."""

if TYPE_CHECKING:
    from typing import Any

    from canimucal.analysis.acceptance import AcceptanceConfig, AcceptanceLimits
    from canimucal.analysis.report import Analysis, analyze
    from canimucal.analysis.static_noise import StaticAnalysis, analyze_static
    from canimucal.errors import CanimucalError, DeviceError, InputError, ModelError
    from canimucal.io.calibration import Calibration
    from canimucal.io.recording import Recording
    from canimucal.model.plan import BoundTable, plan_bounds
    from canimucal.model.positions import Plan, Pose, PositionAverage, average_position
    from canimucal.runtime.inputs import calibrate, read_recording

_PUBLIC = {
    "read_recording": ("canimucal.runtime.inputs", "read_recording"),
    "Recording": ("canimucal.io.recording", "Recording"),
    "average_position": ("canimucal.model.positions", "average_position"),
    "Pose": ("canimucal.model.positions", "Pose"),
    "Plan": ("canimucal.model.positions", "Plan"),
    "PositionAverage": ("canimucal.model.positions", "PositionAverage"),
    "calibrate": ("canimucal.runtime.inputs", "calibrate"),
    "Calibration": ("canimucal.io.calibration", "Calibration"),
    "plan_bounds": ("canimucal.model.plan", "plan_bounds"),
    "BoundTable": ("canimucal.model.plan", "BoundTable"),
    "analyze": ("canimucal.analysis.report", "analyze"),
    "Analysis": ("canimucal.analysis.report", "Analysis"),
    "analyze_static": ("canimucal.analysis.static_noise", "analyze_static"),
    "StaticAnalysis": ("canimucal.analysis.static_noise", "StaticAnalysis"),
    "AcceptanceLimits": ("canimucal.analysis.acceptance", "AcceptanceLimits"),
    "AcceptanceConfig": ("canimucal.analysis.acceptance", "AcceptanceConfig"),
    "CanimucalError": ("canimucal.errors", "CanimucalError"),
    "InputError": ("canimucal.errors", "InputError"),
    "ModelError": ("canimucal.errors", "ModelError"),
    "DeviceError": ("canimucal.errors", "DeviceError"),
}

__all__ = [
    "AcceptanceConfig",
    "AcceptanceLimits",
    "Analysis",
    "BoundTable",
    "Calibration",
    "CanimucalError",
    "DeviceError",
    "InputError",
    "ModelError",
    "Plan",
    "Pose",
    "PositionAverage",
    "Recording",
    "StaticAnalysis",
    "__version__",
    "analyze",
    "analyze_static",
    "average_position",
    "calibrate",
    "plan_bounds",
    "read_recording",
]


def __getattr__(name: str) -> Any:
    """Load a public name on first use (PEP 562)."""
    try:
        module, attr = _PUBLIC[name]
    except KeyError:
        raise AttributeError(f"module 'canimucal' has no attribute {name!r}") from None
    value = getattr(_importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """List the public API (``__all__``): what ``dir(canimucal)`` and completion show."""
    return sorted(__all__)
