"""Simulated sessions without a recording: the fast path of the analysis tests."""

from __future__ import annotations

import numpy as np

from canimucal.analysis.data import SessionData, Window
from canimucal.model.positions import Plan, Pose, average_position
from canimucal.sim.imu import ImuSimulator
from canimucal.sim.truth import Truth


def simulate_session(
    truth: Truth, plan: Plan, *, seed: int, transient_s: float = 2.0, estimate_scatter: bool = False
) -> SessionData:
    """Simulate a plan position by position, grouped as :func:`session_from_recording` would.

    The fast path of the Monte Carlo tests: the unit is set to each pose plus an angle error
    drawn from the pose's tolerance (labelled with the nominal angles), time runs on for
    ``transient_s`` between positions (the warm-up goes on), and no recording is built.
    With ``estimate_scatter`` the poses carry no tolerance and the analysis estimates it.
    """
    sim = ImuSimulator(truth, seed=seed)
    rng = np.random.default_rng(seed)
    fs = sim.sample_rate_hz
    averages, windows = [], []
    for p in plan.positions:
        alpha, beta, psi = p.angles + rng.normal(0.0, p.tolerance, 3)
        sim.set_pose(alpha, beta, psi, transient_s=0.0)
        if transient_s > 0:
            sim.next_block(int(round(transient_s * fs)))
        block = sim.next_block(int(round(p.seconds * fs)))
        pose = Pose(p.alpha, p.beta, p.psi, 0.0 if estimate_scatter else p.tolerance)
        temp = float(np.mean(block.temp_c))
        averages.append(average_position(pose, block.accel, block.gyro, fs, temp))
        windows.append(Window(block.t_s, block.accel, block.gyro, block.temp_c))
    return SessionData(
        averages=tuple(averages),
        windows=tuple(windows),
        g=truth.g,
        latitude=truth.latitude,
        heading=truth.heading,
        accel_lsb=truth.accel.nominal_lsb,
        gyro_lsb=truth.gyro.nominal_lsb,
        known_positions=True,
        scatter_source="estimated" if estimate_scatter else "plan",
    )
