"""The procedure machine's work over its nodes: pose checks, averages, learning, solving.

Kept apart from :mod:`canimucal.procedure.machine`, which decides *when* (phases and
events): these functions compute *what*, over every node's track and accepted averages.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import replace

import numpy as np

from canimucal.analysis.acceptance import AcceptanceReport, check_acceptance
from canimucal.analysis.calibrate import Solution, solve_positions
from canimucal.io.calibration import Device
from canimucal.model.positions import Pose, PositionAverage, average_position
from canimucal.procedure.config import ProcedureConfig
from canimucal.procedure.posecheck import PoseCheck, check_pose, measured_force, predicted_force
from canimucal.procedure.tracks import NodeTrack


def check_poses(
    tracks: Iterable[NodeTrack], target: Pose, g: float, tolerance_deg: float, settle_s: float
) -> tuple[tuple[int, PoseCheck] | None, PoseCheck | None]:
    """Check each node's pose over its last ``settle_s``, stopping at the first refused one.

    Each node that passes gets its averaging reference set. Returns the refused node's id and
    check (or None) and the worst check that passed (largest error; None before any).
    """
    worst = None
    for track in tracks:
        accel, _ = track.recent_rows(settle_s)
        f = measured_force(np.nanmean(accel, axis=0), track.accel_lsb, track.offset_ms2)
        result = check_pose(target, f, g, tolerance_deg)
        if not result.passed:
            return (track.node_id, result), worst
        worst = result if worst is None or result.error_deg > worst.error_deg else worst
        track.set_reference(settle_s)
    return None, worst


def average_attempts(
    tracks: Iterable[NodeTrack], pose: Pose, sample_rate_hz: float
) -> dict[int, PositionAverage]:
    """Finish every node's attempt and average it at ``pose`` (by node id)."""
    averages = {}
    for track in tracks:
        attempt = track.attempt
        assert attempt is not None
        accel, gyro = track.finish_attempt()
        temps = [t for t in attempt.temps if np.isfinite(t)]
        averages[track.node_id] = average_position(
            pose,
            accel,
            gyro,
            sample_rate_hz,
            float(np.mean(temps)) if temps else None,
            attempt.lost,
        )
    return averages


def learn_from_average(track: NodeTrack, average: PositionAverage, pose: Pose, g: float) -> None:
    """Learn a node's noise from an accepted average; the first one also gives its offset."""
    track.stillness.learn_noise(average.std_accel)
    if track.offset_ms2 is None:
        f_pred = predicted_force(pose, g)
        track.offset_ms2 = track.accel_lsb * average.mean_accel - f_pred


def solve_nodes(
    cfg: ProcedureConfig, averages_of: Callable[[int], list[PositionAverage]]
) -> tuple[dict[int, Solution], dict[int, AcceptanceReport]]:
    """Solve every node at its mean temperature and check the acceptance limits."""
    solutions, acceptance = {}, {}
    for node_id in cfg.node_ids:
        device = cfg.devices.get(node_id, Device(node_id=node_id, serial=0))
        averages = averages_of(node_id)
        temps = [a.temp_c for a in averages if a.temp_c is not None]
        site = replace(cfg.site, temp_c=float(np.mean(temps)) if temps else cfg.site.temp_c)
        solution = solve_positions(averages, cfg.spec, site, device, plan_name=cfg.plan_name)
        solutions[node_id] = solution
        acceptance[node_id] = check_acceptance(solution, cfg.limits, cfg.site.accel_lsb, cfg.site.g)
    return solutions, acceptance
