"""The guided procedure as a state machine fed with sample blocks (no Textual, no CAN, no I/O).

warm-up → for each position: instruct → (operator confirms) → wait for stillness → pose
check → average with progress → accept or redo → solve → review → write (by the runner) →
verification at two poses other than the fit's level one (:mod:`.verification`) → done.
Every method returns the events it caused (see
:mod:`canimucal.procedure.events`); a display shows them, an automatic operator reacts to them.

Time is sample time (:class:`~canimucal.procedure.tracks.NodeTrack`): a simulated node run
faster than real time finishes as fast. Several nodes on one rigid body share the poses:
stillness and progress wait for the slowest node; motion on any node restarts the position.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from canimucal.analysis.acceptance import AcceptanceReport, check_acceptance
from canimucal.analysis.calibrate import Solution, solve_positions
from canimucal.io.calibration import Device
from canimucal.model.plan import KPrior
from canimucal.model.positions import PlannedPosition, Pose, PositionAverage, average_position
from canimucal.model.samples import SampleBlock
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import averaged_sensors, choose_time, later_budget_s
from canimucal.procedure.config import LEVEL, ProcedureConfig, ResumeState
from canimucal.procedure.events import Phase
from canimucal.procedure.gyro_fit import ConfirmedMove, fit_confirmed_moves
from canimucal.procedure.level import level_check
from canimucal.procedure.movecheck import MoveTracker
from canimucal.procedure.posecheck import FloorFit, PoseCheck, describe_pose, measured_force
from canimucal.procedure.tracks import Attempt, LabelledRows, NodeTrack, live_readout
from canimucal.procedure.verification import pose_verified, verification_poses
from canimucal.procedure.warmup import WarmupTracker, progress_event

logger = logging.getLogger(__name__)

__all__ = ["LEVEL", "Phase", "Procedure", "ProcedureConfig"]


class Procedure:
    """The state machine; see the module doc. Commands raise nothing on a wrong phase."""

    def __init__(self, config: ProcedureConfig) -> None:
        self.config = config
        site = config.site
        self.tracks = {
            n: NodeTrack(n, config.sample_rate_hz, site.accel_lsb, site.gyro_lsb)
            for n in config.node_ids
        }
        self.move_trackers = {
            n: MoveTracker(config.sample_rate_hz, site.gyro_lsb) for n in config.node_ids
        }
        self.pending_moves: dict[int, ConfirmedMove] = {}
        """Per node, the move the last passed check saw (its end pose not yet accepted)."""
        self.confirmed_moves: dict[int, list[ConfirmedMove]] = {n: [] for n in config.node_ids}
        """Per node, the moves the gyro confirmed whose target position was accepted."""
        self.warmups = {
            n: WarmupTracker(
                window_s=config.warmup_window_s,
                threshold_c_per_min=config.warmup_threshold_c_per_min,
            )
            for n in config.node_ids
        }
        self.phase = Phase.WARMUP if config.warmup else Phase.INSTRUCT
        self.index = 0
        self.verifying = False
        self.verify_index = 0
        """The verification pose being measured (:func:`.verification_poses`)."""
        self.verified: dict[int, list[ev.PoseVerified]] = {n: [] for n in config.node_ids}
        """Per node, the verification poses re-read after the write, in order."""
        self.seconds_later: float | None = None
        self.resumed_time: ev.AveragingTimeChosen | None = None
        """On resume: the later positions' time, chosen from the recorded first position."""
        self.accepted: dict[int, dict[int, PositionAverage]] = {n: {} for n in config.node_ids}
        self.skipped: set[int] = set()
        self.pending_averages: dict[int, PositionAverage] = {}
        self.solutions: dict[int, Solution] = {}
        self.solved: ev.Solved | None = None
        self.write_results: dict[int, ev.WriteFinished] = {}
        self.warmup_skipped = False
        """The operator stopped waiting for warm-up (the certificate says so)."""
        self.level_checks: dict[tuple[int, str], ev.LevelChecked] = {}
        self._still = False
        self._last_progress_s = -np.inf
        self._last_warm_s = -np.inf
        if config.resume_from is not None:
            for node_id in config.node_ids:
                self.preload(node_id, config.resume_from.averages.get(node_id, {}))
            self.index = config.resume_from.next_index
            self.resumed_time = self._resumed_time(config.resume_from)

    # -- queries -----------------------------------------------------------------------------

    @property
    def target(self) -> PlannedPosition:
        """The pose the unit should be in now."""
        if self.verifying:
            return self.verify_poses[self.verify_index]
        return self.config.plan.positions[self.index]

    @property
    def verify_poses(self) -> tuple[PlannedPosition, ...]:
        """The poses re-read after the write (:func:`.verification_poses` of the plan)."""
        return verification_poses(self.config.plan)

    def seconds_for(self, index: int) -> float:
        """Averaging time of position ``index``."""
        if self.verifying:
            return self.config.verify_seconds
        planned = self.config.plan.positions[index].seconds
        return self.config.averaging.seconds_for(index, planned, self.seconds_later)

    def averages(self, node_id: int) -> list[PositionAverage]:
        """Return the accepted averages of one node, in plan order."""
        return [self.accepted[node_id][i] for i in sorted(self.accepted[node_id])]

    def take_rows(self, node_id: int) -> list[LabelledRows]:
        """Rows ready for the recording of ``node_id`` (see :mod:`.tracks`)."""
        return self.tracks[node_id].take_rows()

    def start(self) -> list[ev.Event]:
        """First events: warm-up, or the first instruction when warm-up is off."""
        if self.phase is Phase.WARMUP:
            return [ev.PhaseChanged(Phase.WARMUP, None)]
        return self._instruct()

    def preload(self, node_id: int, averages: Mapping[int, PositionAverage]) -> None:
        """Take positions an interrupted session accepted (by plan index) as accepted.

        Their averages teach the pose check the floor slope and bias, as on acceptance; the
        first-position long recording rule does not apply again (later positions use the
        averaging policy's later time).
        """
        track = self.tracks[node_id]
        for index, average in sorted(averages.items()):
            self.accepted[node_id][index] = average
            learn_from_average(track, average, average.pose, self.config.site.g)

    # -- samples -----------------------------------------------------------------------------

    def feed(self, node_id: int, block: SampleBlock) -> list[ev.Event]:
        """Process one block of one node; return the events it caused."""
        track = self.tracks[node_id]
        step = track.advance(block)
        averaging = self.phase is Phase.AVERAGING and track.attempt is not None
        track.record(block, undecided=averaging)
        self.move_trackers[node_id].add(block.gyro, block.counter, block.accel)
        out: list[ev.Event] = []
        out += self._live(track, block)
        if self.phase is Phase.WARMUP:
            out += self._warmup(track)
        elif self.phase in (Phase.INSTRUCT, Phase.REVIEW_POSITION, Phase.READY_TO_SOLVE):
            track.stillness.update(block.accel, step)
        elif self.phase is Phase.SETTLING:
            track.stillness.update(block.accel, step)
            out += self._settling()
        elif averaging:
            out += self._averaging(track, block, step)
        return out

    def _live(self, track: NodeTrack, block: SampleBlock) -> list[ev.Event]:
        cfg = self.config
        event = live_readout(track, block, self.target, cfg.site.g, cfg.live_period_s)
        return [] if event is None else [event]

    def _warmup(self, track: NodeTrack) -> list[ev.Event]:
        tracker = self.warmups[track.node_id]
        tracker.add(track.time_s, track.temp_c)
        if all(w.warm for w in self.warmups.values()):
            return [progress_event(tracker, skipped=False), *self._instruct()]
        if track.time_s - self._last_warm_s < 1.0:
            return []
        self._last_warm_s = track.time_s
        return [progress_event(tracker, skipped=False)]

    def _settling(self) -> list[ev.Event]:
        cfg = self.config
        still_for = min(t.stillness.still_for_s for t in self.tracks.values())
        now_still = all(t.stillness.still_for_s > 0 for t in self.tracks.values())
        out: list[ev.Event] = []
        if now_still != self._still:
            self._still = now_still
            out.append(ev.StillnessChanged(now_still, still_for, cfg.settle_s))
        if still_for < cfg.settle_s:
            return out
        return out + self._check_and_average()

    def _check_and_average(self) -> list[ev.Event]:
        cfg = self.config
        first = not any(self.accepted[n] for n in cfg.node_ids)
        tol = cfg.first_pose_tolerance_deg if first else cfg.pose_tolerance_deg
        tracks = self.tracks.values()
        refused, worst = check_poses(tracks, self.target, cfg.site.g, tol, cfg.settle_s)
        if refused is not None:
            node_id, result = refused
            back = self._set_phase(Phase.INSTRUCT)  # the screen offers confirm again
            return back + [
                ev.PoseRefused(
                    self.index,
                    node_id,
                    result.measured_deg,
                    result.target_deg,
                    result.error_deg,
                    tol,
                    result.message(),
                )
            ]
        assert worst is not None
        moved = self._check_moves(worst.target_deg)
        if moved is not None:
            return self._set_phase(Phase.INSTRUCT) + [moved]
        for track in self.tracks.values():
            track.attempt = Attempt()
        self._last_progress_s = -np.inf
        events: list[ev.Event] = self._set_phase(Phase.AVERAGING)
        seconds = self.seconds_for(self.index)
        return events + [ev.AveragingStarted(self.index, seconds, worst.tilt_error_deg)]

    def _check_moves(self, tilt_deg: tuple[float, float]) -> ev.MoveRefused | None:
        """Return the refusal of the first node whose gyro saw another move than the plan's."""
        tol = self.config.move_tolerance_deg
        self.pending_moves = {}
        if tol is None or self.verifying:
            return None
        for node_id, tracker in self.move_trackers.items():
            result = tracker.check(self.target, tol)
            if result is None or result.passed:
                continue
            logger.info("node %d: move refused: %s", node_id, result.message())
            return ev.MoveRefused(
                self.index,
                node_id,
                tilt_deg,
                tilt_deg,
                result.error_deg,
                tol,
                result.message(),
                result.measured_deg,
                result.target_deg,
            )
        self._keep_moves()
        return None

    def _keep_moves(self) -> None:
        """Keep each node's checked move, to be confirmed when its position is accepted."""
        for node_id, tracker in self.move_trackers.items():
            rows, start, bias = tracker.raw_rows(), tracker.start_pose, tracker.start_bias
            if rows is None or start is None or bias is None:
                continue
            label = f"position {self.index - 1} → {self.index}"
            gyro, accel, counter = rows
            self.pending_moves[node_id] = ConfirmedMove(
                start,
                self.target,
                bias,
                np.full(3, np.nan),
                gyro,
                counter,
                label,
                accel,
                start_key=tracker.start_key,
                end_key=None if tracker.start_key is None else self.index,
                start_cov=tracker.start_bias_cov,
            )

    def _averaging(self, track: NodeTrack, block: SampleBlock, step: int) -> list[ev.Event]:
        cfg = self.config
        chunk_n = max(10, round(cfg.chunk_s * cfg.sample_rate_hz))
        if not track.add_to_attempt(block, step, chunk_n, cfg.disturbance_k):
            return self._reject(f"motion or a disturbance on node {track.node_id}", track.node_id)
        total = self.seconds_for(self.index)
        elapsed = min(t.attempt_s for t in self.tracks.values())
        if elapsed >= total:
            return self._position_done(total)
        if track.time_s - self._last_progress_s < cfg.progress_period_s:
            return []
        self._last_progress_s = track.time_s
        return [ev.AveragingProgressed(self.index, elapsed, total, total - elapsed)]

    def _reject(self, reason: str, node_id: int | None) -> list[ev.Event]:
        """Discard the attempt on every node (rows kept unlabelled) and settle again."""
        for track in self.tracks.values():
            track.attempt = None
            track.decide(-1, None)
            track.stillness.reset()
        self._still = False
        events = self._set_phase(Phase.SETTLING)
        return [ev.PositionRejected(self.index, reason, node_id, restarting=True), *events]

    def _position_done(self, total: float) -> list[ev.Event]:
        pose = self.target
        averages = average_attempts(self.tracks.values(), pose, self.config.sample_rate_hz)
        self.pending_averages = averages
        if self.verifying:
            return self._verified(averages)
        events = self._set_phase(Phase.REVIEW_POSITION)
        return events + [ev.PositionAveraged(self.index, averages, total)]

    # -- operator commands ---------------------------------------------------------------------

    def skip_warmup(self) -> list[ev.Event]:
        """Stop waiting for warm-up (the demo, or an operator in a hurry)."""
        if self.phase is not Phase.WARMUP:
            return []
        tracker = next(iter(self.warmups.values()))
        self.warmup_skipped = True
        return [progress_event(tracker, skipped=True), *self._instruct()]

    def confirm_pose(self) -> list[ev.Event]:
        """Take the pose as set: wait for stillness, then check and average."""
        if self.phase is not Phase.INSTRUCT:
            return []
        for track in self.tracks.values():
            track.stillness.reset()
        self._still = False
        return self._set_phase(Phase.SETTLING)

    def accept(self) -> list[ev.Event]:
        """Accept the averaged position and move on."""
        if self.phase is not Phase.REVIEW_POSITION:
            return []
        index, pose = self.index, self.target
        angles = tuple(float(np.rad2deg(x)) for x in pose.angles)
        chosen = self._choose_time() if index == 0 else []
        for node_id, average in self.pending_averages.items():
            track = self.tracks[node_id]
            self.accepted[node_id][index] = average
            track.decide(index, (angles[0], angles[1], angles[2]))
            track.attempt = None
            learn_from_average(track, average, pose, self.config.site.g)
            moved = self.pending_moves.pop(node_id, None)
            if moved is not None and average.mean_gyro is not None:
                confirmed = replace(
                    moved,
                    end_gyro=np.asarray(average.mean_gyro, dtype=float),
                    end_cov=average.cov_gyro,
                )
                self.confirmed_moves[node_id].append(confirmed)
            self.move_trackers[node_id].start(
                pose, average.mean_gyro, key=index, mean_cov=average.cov_gyro
            )
        events: list[ev.Event] = [ev.PositionAccepted(index), *chosen]
        return events + self._next_position()

    def redo(self) -> list[ev.Event]:
        """Discard the current attempt (averaged or under way) and instruct the pose again."""
        if self.phase not in (Phase.REVIEW_POSITION, Phase.AVERAGING, Phase.SETTLING):
            return []
        for track in self.tracks.values():
            track.attempt = None
            track.decide(-1, None)
        self.pending_averages = {}
        rejected = ev.PositionRejected(self.index, "redo by the operator", None, restarting=True)
        return [rejected, *self._instruct()]

    def device_interrupted(self, node_id: int, reason: str) -> list[ev.Event]:
        """Take a node's reboot or emergency: never average across it.

        While averaging, the attempt is rejected (as a disturbance is) and the position is
        settled and averaged again; while settling, stillness starts over. Otherwise nothing.
        """
        if self.phase is Phase.AVERAGING:
            return self._reject(reason, node_id)
        if self.phase is Phase.SETTLING:
            for track in self.tracks.values():
                track.stillness.reset()
            self._still = False
        return []

    def skip(self) -> list[ev.Event]:
        """Leave the current position out (not allowed for the first, level one)."""
        if self.phase not in (Phase.INSTRUCT, Phase.SETTLING) or self.index == 0:
            return []
        if self.verifying:
            return []
        self.skipped.add(self.index)
        self.pending_moves = {}
        for tracker in self.move_trackers.values():
            tracker.clear()  # the unit is somewhere the plan does not say: next move unchecked
        return self._next_position()

    def cancel(self) -> list[ev.Event]:
        """Stop the procedure; what was recorded stays recorded."""
        for track in self.tracks.values():
            track.decide(-1, None)
        events = self._set_phase(Phase.CANCELLED)
        return events + [ev.ProcedureFinished(cancelled=True)]

    def solve(self) -> list[ev.Event]:
        """Solve every node and check the acceptance limits."""
        if self.phase is not Phase.READY_TO_SOLVE:
            return []
        solutions, acceptance = solve_nodes(self.config, self.averages, self.confirmed_moves)
        self.solutions = solutions
        self.solved = ev.Solved(solutions, acceptance)
        events = self._set_phase(Phase.REVIEW)
        events.append(self.solved)
        for node_id, solution in solutions.items():
            level = [a for a in self.averages(node_id) if not np.any(a.pose.angles)]
            if level:
                events.append(self._level_event(node_id, "before", level[0], solution))
        return events

    def begin_write(self, *, override: bool = False) -> list[ev.Event]:
        """Start the write the operator confirmed (the runner writes and reports back).

        Refused (no event) unless every node passed the acceptance limits or ``override``.
        """
        if self.phase is not Phase.REVIEW or self.solved is None:
            return []
        if not (self.solved.acceptable or override):
            return []
        return self._set_phase(Phase.WRITING)

    def write_finished(
        self, node_id: int, ok: bool, message: str, backup_path: str | None = None
    ) -> list[ev.Event]:
        """Take the runner's report of one node's write; after the last, verify (module doc)."""
        result = ev.WriteFinished(node_id, ok, message, backup_path)
        self.write_results[node_id] = result
        if len(self.write_results) < len(self.config.node_ids):
            return [result]
        if not any(r.ok for r in self.write_results.values()):
            return [result, *self._set_phase(Phase.DONE), ev.ProcedureFinished()]
        self.verifying = True
        return [result, *self._instruct()]

    def finish_without_writing(self) -> list[ev.Event]:
        """End after the review, leaving the devices as they are."""
        if self.phase is not Phase.REVIEW:
            return []
        return [*self._set_phase(Phase.DONE), ev.ProcedureFinished(notes=("nothing written",))]

    # -- helpers -------------------------------------------------------------------------------

    def _set_phase(self, phase: Phase) -> list[ev.Event]:
        previous, self.phase = self.phase, phase
        return [ev.PhaseChanged(phase, previous)] if previous != phase else []

    def _instruct(self) -> list[ev.Event]:
        events = self._set_phase(Phase.INSTRUCT)
        pose = self.target
        index, total = self.index, len(self.config.plan.positions)
        seconds = self.seconds_for(self.index)
        words = describe_pose(pose, self.config.mounting, self.config.vehicle_size)
        if self.verifying:
            index, total = self.verify_index, len(self.verify_poses)
            words = f"verification {index + 1}/{total}: {words}"
        return events + [ev.PoseInstructed(index, total, pose, words, seconds, self.verifying)]

    def _next_position(self) -> list[ev.Event]:
        self.pending_averages = {}
        self.index += 1
        while self.index in self.skipped:
            self.index += 1
        if self.index < len(self.config.plan.positions):
            return self._instruct()
        self.index = len(self.config.plan.positions) - 1
        return self._set_phase(Phase.READY_TO_SOLVE)

    def _resumed_time(self, state: ResumeState) -> ev.AveragingTimeChosen | None:
        """Choose the later time from the recorded first position, as :meth:`_choose_time`."""
        if state.next_index == 0 or state.first_accel is None:
            return None
        samples = {"accel": [state.first_accel]}
        if state.first_gyro is not None:
            samples["gyro"] = [state.first_gyro]
        event = choose_time(
            self.config.averaging,
            samples,
            self.config.sample_rate_hz,
            averaged_sensors(self.config.spec.gyro),
            later_budget_s(self.config.plan),
        )
        if event.source == "noise":
            self.seconds_later = event.seconds
        return event

    def _choose_time(self) -> list[ev.Event]:
        track = next(iter(self.tracks.values()))
        attempt = track.attempt
        samples = {"accel": attempt.accel, "gyro": attempt.gyro} if attempt is not None else {}
        event = choose_time(
            self.config.averaging,
            samples,
            self.config.sample_rate_hz,
            averaged_sensors(self.config.spec.gyro),
            later_budget_s(self.config.plan),
        )
        if event.source == "noise":
            self.seconds_later = event.seconds
        return [event]

    def _level_event(
        self, node_id: int, stage: str, average: PositionAverage, solution: Solution
    ) -> ev.LevelChecked:
        site = self.config.site
        event = level_check(node_id, stage, average, solution.record, site)
        self.level_checks[(node_id, stage)] = event
        return event

    def _verified(self, averages: dict[int, PositionAverage]) -> list[ev.Event]:
        """Judge one verification pose on every written node; then the next, or done."""
        events: list[ev.Event] = []
        pose, total = self.target, len(self.verify_poses)
        words = describe_pose(pose, self.config.mounting, self.config.vehicle_size)
        for node_id, average in averages.items():
            result = self.write_results.get(node_id)
            if node_id not in self.solutions or result is None or not result.ok:
                continue
            record = self.solutions[node_id].record
            event = pose_verified(
                node_id, self.verify_index, total, pose, words, average, record, self.config.site
            )
            self.verified[node_id].append(event)
            events.append(event)
        for track in self.tracks.values():
            track.attempt = None
            track.decide(-1, None)
        self.pending_averages = {}
        if self.verify_index + 1 < total:
            self.verify_index += 1
            return events + self._instruct()
        return events + self._set_phase(Phase.DONE) + [ev.ProcedureFinished()]


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
        f = measured_force(np.nanmean(accel, axis=0), track.accel_lsb)
        result = track.floor.check(target, f, tolerance_deg)
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
    """Learn a node's noise and its floor slope and bias from an accepted average.

    The pose check predicts the next positions with them
    (:class:`~canimucal.procedure.posecheck.FloorFit`).
    """
    track.stillness.learn_noise(average.std_accel)
    if track.floor.empty:
        track.floor = FloorFit(g)  # the site's g
    track.floor.add(pose, measured_force(average.mean_accel, track.accel_lsb))


def solve_nodes(
    cfg: ProcedureConfig,
    averages_of: Callable[[int], list[PositionAverage]],
    moves: Mapping[int, Sequence[ConfirmedMove]] | None = None,
) -> tuple[dict[int, Solution], dict[int, AcceptanceReport]]:
    """Solve every node at its mean temperature and check the acceptance limits.

    With ``cfg.gyro_moves`` and a ``mems`` gyro, each node's S comes from the ``moves`` its
    gyro confirmed (:mod:`.gyro_fit`), where they identify it.
    """
    solutions, acceptance = {}, {}
    for node_id in cfg.node_ids:
        device = cfg.devices.get(node_id, Device(node_id=node_id, serial=0))
        averages = averages_of(node_id)
        temps = [a.temp_c for a in averages if a.temp_c is not None]
        site = replace(cfg.site, temp_c=float(np.mean(temps)) if temps else cfg.site.temp_c)
        k_prior = cfg.k_priors.get(node_id, KPrior())
        solution = solve_positions(
            averages,
            cfg.spec,
            site,
            device,
            plan_name=cfg.plan_name,
            prior=k_prior.prior(cfg.plan, cfg.spec, site.accel_lsb),
            prior_source=k_prior.describe(cfg.plan),
        )
        if cfg.gyro_moves and cfg.spec.gyro == "mems" and moves:
            node_moves = moves.get(node_id, ())
            solution = fit_confirmed_moves(solution, node_moves, averages, site, cfg.sample_rate_hz)
        solutions[node_id] = solution
        acceptance[node_id] = check_acceptance(solution, cfg.limits, cfg.site.accel_lsb, cfg.site.g)
    return solutions, acceptance
