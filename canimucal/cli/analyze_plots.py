"""PNG plots for `canimucal analyze --plots DIR` (matplotlib: the optional ``plots`` extra).

Three files, all checked before any work and written atomically (never replacing a file
without ``--overwrite``):

- ``residuals.png``: the base model's residual per position and axis (counts; the scalar
  fit's ``|f| − g`` in m/s²) with the ±1σ noise of each position's mean as error bars,
  accelerometer and gyro on their own axes (their scales differ by orders of magnitude),
  points only (positions are not a sequence in time); a file of several trials has each
  trial's positions between dotted lines, named ``trial k`` at the top;
- ``allan.png``: the overlapping Allan deviation of the longest static window per sensor and
  axis against the white noise the simulator's base model predicts from its short-τ level
  (a measured curve above the dashed line at long τ is drift the base model does not have),
  with the chosen averaging time marked;
- ``session.png``: the accelerometer (and gyro) counts over the session's time, each
  labelled position's span shaded and numbered.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.analysis.report import Analysis
from canimucal.errors import InputError
from canimucal.io.atomic import make_directory, refuse_existing, write_bytes_atomic

PLOT_FILES = ("residuals.png", "allan.png", "session.png")
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
    make_directory(directory)
    written = [_save(plt, residual_figure(plt, a), directory / PLOT_FILES[0], overwrite=overwrite)]
    fig, axes = plt.subplots(1, len(a.allan), figsize=(6 * len(a.allan), 4), squeeze=False)
    for ax, (sensor, check) in zip(axes[0], a.allan.items(), strict=True):
        for axis in range(3):
            (line,) = ax.loglog(check.taus_s, check.adev[:, axis], label=f"{AXES[axis]} measured")
            ax.loglog(check.taus_s, check.white[:, axis], "--", color=line.get_color())
        _mark_averaging_time(ax, check.best_averaging_s, float(np.max(check.taus_s)))
        ax.set_xlabel("τ (s)")
        ax.set_ylabel("Allan deviation (counts)")
        ax.set_title(f"{sensor}: measured, and white noise only (dashed)")
        ax.legend(fontsize="small")
    written.append(_save(plt, fig, directory / PLOT_FILES[1], overwrite=overwrite))
    written.append(
        _save(plt, _session_figure(plt, a), directory / PLOT_FILES[2], overwrite=overwrite)
    )
    return written


def _mark_averaging_time(ax: Any, tau_s: float, longest_s: float) -> None:
    """Mark the chosen averaging time; beyond the data's τ range, say so in words."""
    if not np.isfinite(tau_s):
        return
    if tau_s <= longest_s:
        ax.axvline(tau_s, color="black", linewidth=1.0, linestyle=":")
        ax.annotate(
            f"chosen τ = {tau_s:.3g} s",
            (tau_s, 0.95),
            xycoords=("data", "axes fraction"),
            ha="right",
            fontsize="small",
        )
        return
    ax.annotate(
        f"chosen τ = {tau_s:.3g} s, beyond this window's {longest_s:.3g} s",
        (0.98, 0.95),
        xycoords="axes fraction",
        ha="right",
        fontsize="small",
    )


def residual_figure(plt: Any, a: Analysis) -> Any:
    """Residuals per position with ±1σ error bars; accel and gyro on their own axes."""
    residuals = a.result.residuals
    labels = a.result.residual_labels
    groups = [range(0, min(3, residuals.shape[1]))]
    if residuals.shape[1] > 3:
        groups.append(range(3, residuals.shape[1]))
    fig, axes = plt.subplots(len(groups), 1, figsize=(7, 3 * len(groups)), squeeze=False)
    positions = np.arange(1, len(residuals) + 1)
    errors = _residual_errors(a, residuals.shape)
    spans = trial_spans(a.session.averages, len(residuals))
    for ax, group in zip(axes[:, 0], groups, strict=True):
        for k, column in enumerate(group):
            ax.errorbar(
                positions + 0.12 * (k - 1),
                residuals[:, column],
                yerr=None if errors is None else errors[:, column],
                fmt="o",
                capsize=3,
                label=labels[column],
            )
        ax.axhline(0.0, color="grey", linewidth=0.8)
        _mark_trials(ax, spans)
        ax.set_xticks(positions)
        sensor = "gyro" if group.start >= 3 else "accelerometer"
        unit = "|f| − g, m/s²" if a.result.method == "scalar" else "counts"
        ax.set_ylabel(f"{sensor} residual ({unit})")
        ax.legend(fontsize="small", ncol=3)
    axes[-1, 0].set_xlabel("position (error bars: ±1σ noise of the position's mean)")
    axes[0, 0].set_title(f"What the base model leaves ({a.result.method})", pad=16 if spans else 6)
    return fig


def trial_spans(averages: Any, rows: int) -> list[tuple[int, int, int]]:
    """``(trial, first, last)`` plotted positions (1-based) of each trial; [] for one trial.

    ``averages`` are the session's positions in the residuals' order; a count other than
    ``rows`` (the residual table's) marks nothing.
    """
    found: list[int | None] = [getattr(x, "trial", None) for x in averages]
    trials = [t for t in found if t is not None]
    if len(trials) != rows or len(set(trials)) < 2:
        return []
    spans: list[tuple[int, int, int]] = []
    for i, trial in enumerate(trials, start=1):
        if spans and spans[-1][0] == trial:
            spans[-1] = (trial, spans[-1][1], i)
        else:
            spans.append((trial, i, i))
    return spans


def _mark_trials(ax: Any, spans: list[tuple[int, int, int]]) -> None:
    """Dotted lines between trials and each trial's name above its positions."""
    for k, (trial, first, last) in enumerate(spans):
        if k:
            ax.axvline(first - 0.5, color="grey", linewidth=0.8, linestyle=":")
        ax.annotate(
            f"trial {trial}",
            ((first + last) / 2.0, 1.0),
            xycoords=("data", "axes fraction"),
            ha="center",
            va="bottom",
            fontsize="small",
        )


def _residual_errors(a: Analysis, shape: tuple[int, ...]) -> Any:
    """±1σ of each position's mean per channel (counts), or None for the scalar fit."""
    averages = a.session.averages
    if a.result.method == "scalar" or len(averages) != shape[0]:
        return None
    out = np.full(shape, np.nan)
    for i, average in enumerate(averages):
        out[i, :3] = np.sqrt(np.diag(average.cov_accel))
        if shape[1] > 3 and average.cov_gyro is not None:
            out[i, 3:] = np.sqrt(np.diag(average.cov_gyro))
    return out


def _session_figure(plt: Any, a: Analysis) -> Any:
    """Plot the counts over time, each labelled position shaded and numbered."""
    rec = a.recording
    t = np.asarray(rec.t, dtype=float) - float(rec.t[0])
    sensors = [("accelerometer", rec.accel)]
    if np.isfinite(rec.gyro).any():
        sensors.append(("gyro", rec.gyro))
    fig, axes = plt.subplots(len(sensors), 1, figsize=(9, 3 * len(sensors)), squeeze=False)
    labels = np.asarray(rec.position)
    for ax, (name, values) in zip(axes[:, 0], sensors, strict=True):
        for axis in range(3):
            ax.plot(t, values[:, axis], linewidth=0.6, label=AXES[axis])
        for label in sorted(set(labels.tolist()) - {-1}):
            span = t[labels == label]
            ax.axvspan(float(span[0]), float(span[-1]), color="tab:green", alpha=0.15)
            ax.annotate(
                str(label + 1),
                ((span[0] + span[-1]) / 2, 1.0),
                xycoords=("data", "axes fraction"),
                ha="center",
                va="bottom",
                fontsize="small",
            )
        ax.set_ylabel(f"{name} (counts)")
        ax.legend(fontsize="small", ncol=3, loc="lower right")
    axes[-1, 0].set_xlabel("time (s); shaded: the samples averaged for each numbered position")
    return fig


def _save(plt: Any, fig: Any, target: Path, *, overwrite: bool) -> Path:
    buffer = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    return write_bytes_atomic(target, buffer.getvalue(), overwrite=overwrite)
