"""PNG plots for `canimucal analyze --plots DIR` (matplotlib: the optional ``plots`` extra).

Two files, both checked before any work and written atomically (never replacing a file
without ``--overwrite``):

- ``residuals.png``: the base model's residual per position and axis (counts; the scalar
  fit's ``|f| − g`` in m/s²), the picture of what the base model gets wrong;
- ``allan.png``: the overlapping Allan deviation of the longest static window per sensor and
  axis against the white noise the simulator's base model predicts from its short-τ level
  (a measured curve above the dashed line at long τ is drift the base model does not have).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from canimucal.analysis.report import Analysis
from canimucal.errors import InputError
from canimucal.io.atomic import refuse_existing, write_bytes_atomic

PLOT_FILES = ("residuals.png", "allan.png")
AXES = ("x", "y", "z")


def pyplot() -> Any:
    """Matplotlib's pyplot on the file-only Agg backend; a one-line error when absent."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise InputError("--plots needs matplotlib: pip install 'canimucal[plots]'") from None
    return plt


def check_plot_targets(directory: Path, *, overwrite: bool) -> None:
    """Refuse before any work: no matplotlib, a directory that is a file, or existing plots."""
    pyplot()
    if directory.exists() and not directory.is_dir():
        raise InputError(f"--plots {directory}: exists and is not a directory")
    for name in PLOT_FILES:
        refuse_existing(directory / name, overwrite=overwrite)


def write_plots(a: Analysis, directory: Path, *, overwrite: bool) -> list[Path]:
    """Write the plots of the module doc to ``directory``; return their paths."""
    plt = pyplot()
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    fig, ax = plt.subplots(figsize=(7, 4))
    residuals = a.result.residuals
    for column, label in enumerate(a.result.residual_labels):
        ax.plot(range(1, len(residuals) + 1), residuals[:, column], marker="o", label=label)
    ax.axhline(0.0, color="grey", linewidth=0.8)
    ax.set_xlabel("position")
    unit = "counts; |f| − g in m/s²" if a.result.method == "scalar" else "counts"
    ax.set_ylabel(f"base-model residual ({unit})")
    ax.set_title(f"What the base model leaves ({a.result.method})")
    ax.legend(fontsize="small", ncol=2)
    written.append(_save(plt, fig, directory / PLOT_FILES[0], overwrite=overwrite))
    fig, axes = plt.subplots(1, len(a.allan), figsize=(6 * len(a.allan), 4), squeeze=False)
    for ax, (sensor, check) in zip(axes[0], a.allan.items(), strict=True):
        for axis in range(3):
            (line,) = ax.loglog(check.taus_s, check.adev[:, axis], label=f"{AXES[axis]} measured")
            ax.loglog(check.taus_s, check.white[:, axis], "--", color=line.get_color())
        ax.set_xlabel("τ (s)")
        ax.set_ylabel("Allan deviation (counts)")
        ax.set_title(f"{sensor}: measured, and white noise only (dashed)")
        ax.legend(fontsize="small")
    written.append(_save(plt, fig, directory / PLOT_FILES[1], overwrite=overwrite))
    return written


def _save(plt: Any, fig: Any, target: Path, *, overwrite: bool) -> Path:
    buffer = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    return write_bytes_atomic(target, buffer.getvalue(), overwrite=overwrite)
