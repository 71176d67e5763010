"""The CAN runner: ImuClients in, the procedure machine in the middle, files out.

:class:`Session` drives one or several :class:`~canimucal.device.client.ImuClient` (one per
node on the same rigid body), feeds their sample blocks to the
:class:`~canimucal.procedure.machine.Procedure`, writes **every** sample to one recording CSV
per node as it comes (``RecordingWriter``: a ``.partial`` file until closed, so an
interrupted session keeps what was measured), saves the calibration record and certificate
before any write, writes with the transactional write and re-reads the result. In demo mode
(``sims`` given) confirming a pose moves the simulated node(s) there first.

Each call returns the procedure's events; a TUI polls :meth:`Session.poll` from its I/O
worker and posts the events to its screen. What an operator asks of a running session is a
:class:`SessionCommand`, or a :class:`WriteOptions` for the write (the one command with options).
"""

from __future__ import annotations

import logging
import os
import queue
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from enum import Enum
from pathlib import Path
from typing import Any, assert_never

import numpy as np

from canimucal.analysis.acceptance import acceptance_block
from canimucal.analysis.calibrate import SiteConditions
from canimucal.device.calibration_map import readback_of
from canimucal.device.client import Identity, ImuClient
from canimucal.device.events import (
    BusErrorReceived,
    EmergencyReceived,
    HeartbeatLost,
    HeartbeatResumed,
    NodeRebooted,
    SerialChanged,
)
from canimucal.device.start_check import refused_start
from canimucal.device.transaction import write_calibration_transaction
from canimucal.errors import CanimucalError, DeviceError
from canimucal.io.atomic import make_directory
from canimucal.io.calibration import (
    Calibration,
    Device,
    RecordingRef,
    calibration_to_json,
    sha256_of,
)
from canimucal.io.recording import matrix_header
from canimucal.io.recording_writer import RecordingWriter
from canimucal.model.plan import KPrior
from canimucal.model.positions import Plan, Pose
from canimucal.model.vocabulary.units import Scales
from canimucal.procedure import events as ev
from canimucal.procedure.config import ProcedureConfig
from canimucal.procedure.machine import Phase, Procedure
from canimucal.procedure.tracks import LabelledRows
from canimucal.runtime.certificate import (
    SessionFacts,
    certificate_html,
    certificate_markdown,
    mounting_text,
    verification_of,
    verification_verdict,
)
from canimucal.runtime.plan_forecast import schedule, session_forecast
from canimucal.runtime.resume import partial_path
from canimucal.sim.schedule import operator_angles
from canimucal.simnode.node import SimulatedImuNode

logger = logging.getLogger(__name__)

SILENCE_TIMEOUT_S = 5.0
"""A streaming node silent this long (wall time) stops the session with a DeviceError."""
DEMO_MOVE_S = 3.0
"""Sample time a demo move takes before the pose is confirmed (transient 1 s + lag)."""


class SessionCommand(Enum):
    """An operator's command to a running session (see :meth:`Session.command`)."""

    CONFIRM_POSE = "confirm pose"
    ACCEPT = "accept"
    REDO = "redo"
    SKIP = "skip"
    SKIP_WARMUP = "skip warm-up"
    SOLVE = "solve"
    FINISH_WITHOUT_WRITING = "finish without writing"
    CANCEL = "cancel"


@dataclass(frozen=True)
class WriteOptions:
    """How :meth:`Session.write` writes.

    ``override`` writes a result that failed the acceptance limits (operator's choice);
    ``force`` only overrides the serial check (docs/design.md §7); ``store`` saves with 0x1010:04.
    """

    override: bool = False
    force: bool = False
    store: bool = True


@dataclass
class NodeLink:
    """One node of the session: its client, identity, recording and (demo) simulated node."""

    client: ImuClient
    identity: Identity
    writer: RecordingWriter
    sim: SimulatedImuNode | None = None
    header: dict[str, Any] | None = None
    record_path: Path | None = None
    certificate_path: Path | None = None
    record: Calibration | None = None
    trim_object: bool | None = None
    """Whether the node has the mounting-trim object 0x2122 (known once written)."""


class Session:
    """Runs a :class:`Procedure` against live clients; see the module doc."""

    def __init__(
        self,
        procedure: Procedure,
        clients: Mapping[int, ImuClient],
        identities: Mapping[int, Identity],
        out_dir: Path,
        *,
        sims: Mapping[int, SimulatedImuNode] | None = None,
        header: Mapping[int, dict[str, Any]] | None = None,
        backup_dir: Path | None = None,
        overwrite: bool = False,
        operator_rng: np.random.Generator | None = None,
        operator: str | None = None,
        site_name: str | None = None,
    ) -> None:
        self.procedure = procedure
        self.operator_rng = operator_rng
        self.operator = operator
        self.site_name = site_name
        self.out_dir = out_dir
        self.backup_dir = backup_dir
        make_directory(out_dir)
        several = len(clients) > 1
        self.links: dict[int, NodeLink] = {}
        for node_id, client in clients.items():
            path = output_name(out_dir, "recording", node_id, several, ".csv")
            head = {
                **(header or {}).get(node_id, {}),
                **model_header(procedure.config),
                **prior_header(procedure.config, node_id),
            }
            if procedure.config.resume_from is not None:
                writer = open_resumed(path, head)
            else:
                writer = RecordingWriter.open(path, head, overwrite=overwrite)
            sim = None if sims is None else sims.get(node_id)
            self.links[node_id] = NodeLink(client, identities[node_id], writer, sim, head)
        self.several = several
        self.overwrite = overwrite
        self.silence_timeout_s = SILENCE_TIMEOUT_S
        self._last_block_s: dict[int, float] = {}
        self.history: list[ev.Event] = []

    # -- samples -----------------------------------------------------------------------------

    def poll(self, timeout_s: float = 0.05) -> list[ev.Event]:
        """Feed every block waiting in the clients' queues (waiting up to ``timeout_s``)."""
        out: list[ev.Event] = []
        now = time.monotonic()
        for node_id, link in self.links.items():
            block = link.client.get_block(timeout_s)
            if block is not None:
                self._last_block_s[node_id] = now
            elif now - self._last_block_s.get(node_id, now) > self.silence_timeout_s:
                why = refused_start(link.client)
                raise DeviceError(
                    (why or f"node {node_id} sent no samples for {self.silence_timeout_s:g} s")
                    + "; what was recorded is kept"
                )
            while block is not None:
                out += self.procedure.feed(node_id, block)
                block = link.client.get_block(0.0)
            out += self._device_events(node_id, link)  # after the blocks sent before them
            self._write_rows(node_id)
        return self._keep(out)

    def _device_events(self, node_id: int, link: NodeLink) -> list[ev.Event]:
        """Turn what the node reported (``client.events``) into procedure events.

        A reboot or an EMCY rejects the attempt being averaged (never averaged across), but
        not an EMCY 0x0000 or 0x81xx/0x82xx (docs/design.md §9: shown only); after
        a reboot the identity is read again and streaming resumed, unless another unit came
        back (``SerialChanged``: the procedure stops with :class:`ProcedureFailed`).
        """
        out: list[ev.Event] = []
        while True:
            try:
                event = link.client.events.get_nowait()
            except queue.Empty:
                return out
            out += self._device_event(node_id, link, event)
            if self.procedure.phase is Phase.CANCELLED:
                return out

    def _device_event(self, node_id: int, link: NodeLink, event: object) -> list[ev.Event]:
        proc = self.procedure
        if isinstance(event, NodeRebooted):
            message = f"node {node_id} rebooted (boot-up seen); values it had not stored are gone"
            out: list[ev.Event] = [ev.DeviceEventReported(node_id, "reboot", message)]
            out += proc.device_interrupted(node_id, f"node {node_id} rebooted")
            serial = link.client.identity().serial  # a new serial queues SerialChanged
            if serial == link.identity.serial:
                link.client.resume_streaming()
                self._last_block_s[node_id] = time.monotonic()
            return out
        if isinstance(event, SerialChanged):
            message = (
                f"node {node_id} came back as serial {event.new_serial}, not "
                f"{event.old_serial}: a different unit is on the bus; the session stops "
                "(what was recorded is kept)"
            )
            stopped = [e for e in proc.cancel() if not isinstance(e, ev.ProcedureFinished)]
            return [  # stopped like on an error: the TUI shows the failure, not a summary
                ev.DeviceEventReported(node_id, "serial_changed", message),
                ev.ProcedureFailed(message, "Different unit"),
                *stopped,
            ]
        if isinstance(event, EmergencyReceived):
            message = f"node {node_id} sent an emergency: {event.text}"
            if not event.interrupts:  # error reset or communication: shown, pose goes on
                message += " (communication or error reset: the pose goes on)"
                return [ev.DeviceEventReported(node_id, "emergency", message)]
            out = [ev.DeviceEventReported(node_id, "emergency", message)]
            return out + proc.device_interrupted(node_id, message)
        if isinstance(event, HeartbeatLost):
            message = (
                f"node {node_id}: no heartbeat for {event.timeout_s:g} s "
                f"(the session stops after {self.silence_timeout_s:g} s without samples)"
            )
            return [ev.DeviceEventReported(node_id, "heartbeat_lost", message)]
        if isinstance(event, HeartbeatResumed):
            message = f"node {node_id}: heartbeat back"
            return [ev.DeviceEventReported(node_id, "heartbeat_resumed", message)]
        if isinstance(event, BusErrorReceived):
            message = f"CAN error frame on the bus (id 0x{event.can_id:X})"
            return [ev.DeviceEventReported(node_id, "bus_error", message)]
        return []

    def _write_rows(self, node_id: int) -> None:
        writer = self.links[node_id].writer
        for piece in self.procedure.take_rows(node_id):
            write_piece(writer, piece)

    def _keep(self, events: list[ev.Event]) -> list[ev.Event]:
        self.history += [e for e in events if not isinstance(e, ev.SamplesReceived)]
        return events

    # -- commands ------------------------------------------------------------------------------

    def start(self) -> list[ev.Event]:
        """Start streaming every node and the procedure."""
        for node_id, link in self.links.items():
            link.client.start_streaming()
            self._last_block_s[node_id] = time.monotonic()
            try:
                link.client.watch_heartbeat()  # HeartbeatLost after 3 periods (0x1017)
            except DeviceError:
                logger.info("node %d sends no heartbeat: its loss is not watched", node_id)
        return self._keep(self.procedure.start())

    def confirm_pose(self) -> list[ev.Event]:
        """Confirm the pose; in demo mode move the simulated node(s) there first.

        In demo mode the session then keeps feeding samples for ``DEMO_MOVE_S`` of sample
        time before confirming, so samples still queued from the old pose (at a fast time
        scale a 20 ms batch is most of a second) are not taken for the new one.
        """
        events: list[ev.Event] = []
        sims = [link.sim for link in self.links.values() if link.sim is not None]
        if sims:
            events += self._drain()
            alpha, beta, psi = self._placed(self.procedure.target)
            for sim in sims:  # one rigid body: every unit gets the same pose error
                sim.set_pose(alpha, beta, psi)
            events += self._feed_for(DEMO_MOVE_S)
        return events + self._keep(self.procedure.confirm_pose())

    def _placed(self, target: Pose) -> tuple[float, float, float]:
        """Return where the demo's operator really puts the unit.

        Each angle is off by a draw from the pose's 1σ ``tolerance`` (a step ladder is not a
        dividing head), unless no ``operator_rng`` was given.
        """
        angles = target.angles
        if self.operator_rng is not None:
            angles = operator_angles(target, self.operator_rng)
        return float(angles[0]), float(angles[1]), float(angles[2])

    def _drain(self) -> list[ev.Event]:
        """Feed every block already waiting, so the old pose's samples are behind us."""
        out: list[ev.Event] = []
        while any(not link.client.samples.empty() for link in self.links.values()):
            out += self.poll(0.0)
        return out

    def _feed_for(self, seconds: float, wall_timeout_s: float = 30.0) -> list[ev.Event]:
        """Poll until every node has fed ``seconds`` more sample time (or the wall timeout)."""
        tracks = self.procedure.tracks
        until = {n: tracks[n].time_s + seconds for n in self.links}
        deadline = time.monotonic() + wall_timeout_s
        out: list[ev.Event] = []
        while any(tracks[n].time_s < t for n, t in until.items()):
            if time.monotonic() > deadline:
                raise DeviceError(f"no samples for {wall_timeout_s:g} s while moving the unit")
            out += self.poll()
        return out

    def command(self, command: SessionCommand) -> list[ev.Event]:
        """Run one operator command; a command the phase does not take does nothing."""
        proc = self.procedure
        match command:
            case SessionCommand.CONFIRM_POSE:
                return self.confirm_pose()
            case SessionCommand.SOLVE:
                return self.solve()
            case SessionCommand.ACCEPT:
                events = proc.accept()
            case SessionCommand.REDO:
                events = proc.redo()
            case SessionCommand.SKIP:
                events = proc.skip()
            case SessionCommand.SKIP_WARMUP:
                events = proc.skip_warmup()
            case SessionCommand.FINISH_WITHOUT_WRITING:
                events = proc.finish_without_writing()
            case SessionCommand.CANCEL:
                events = proc.cancel()
            case _:
                assert_never(command)
        return self._keep(events)

    def solve(self) -> list[ev.Event]:
        """Solve; close the recordings and save records and certificates (before any write)."""
        events = self.procedure.solve()
        if self.procedure.phase is Phase.REVIEW:
            events += self.save()
        return self._keep(events)

    def save(self) -> list[ev.Event]:
        """Close each recording and save its calibration record and certificate beside it."""
        out: list[ev.Event] = []
        for node_id, link in self.links.items():
            self._write_rows(node_id)
            rec_path = link.writer.close()
            verify_path = self._name("verification", node_id, ".csv")
            link.writer = RecordingWriter.open(verify_path, link.header or {}, overwrite=True)
            solution = self.procedure.solutions[node_id]
            ref = RecordingRef(file=rec_path.name, sha256=sha256_of(rec_path))
            assert self.procedure.solved is not None
            verdict = acceptance_block(
                self.procedure.solved.acceptance[node_id], self.procedure.config.limits
            )
            link.record = replace(solution.record, recording=ref, acceptance=verdict)
            link.record_path = self._name("calibration", node_id, ".json")
            write_text(link.record_path, calibration_to_json(link.record))
            link.certificate_path = self._name("certificate", node_id, ".md")
            self._write_certificates(node_id)
            out.append(
                ev.RecordSaved(
                    node_id, str(link.record_path), str(link.certificate_path), str(rec_path)
                )
            )
        return out

    def certificate(self, node_id: int, *, html: bool = False) -> str:
        """Render the certificate of one node as it stands now (Markdown, or the HTML page)."""
        link = self.links[node_id]
        proc = self.procedure
        assert proc.solved is not None and link.record is not None
        render = certificate_html if html else certificate_markdown
        return render(
            link.record,
            link.identity,
            proc.solved.acceptance[node_id],
            proc.config.limits,
            [e for (n, _), e in proc.level_checks.items() if n == node_id],
            warnings=proc.solutions[node_id].warnings,
            facts=self.facts(node_id),
        )

    def facts(self, node_id: int) -> SessionFacts:
        """Operator, site, written or not, verification, warm-up and the mounting map."""
        proc = self.procedure
        site = proc.config.site
        result = proc.write_results.get(node_id)
        written = result is not None and result.ok
        verified = proc.verified.get(node_id, [])
        if proc.warmup_skipped:
            warmup = "skipped by the operator"
        elif proc.config.warmup:
            warmup = "waited until the temperature was stable"
        else:
            warmup = "not required (resumed or disabled)"
        return SessionFacts(
            operator=self.operator,
            site=self.site_name,
            written=written,
            verification=verification_of(verified, written, proc.config.limits, site.g),
            warmup=warmup,
            mounting=mounting_text(proc.config.mounting, proc.config.mounting_note),
            scales=Scales(site.accel_lsb, site.gyro_lsb, site.g),
            plan_times=schedule(proc.config.plan, proc.config.averaging).words(),
            forecast=tuple(session_forecast(proc.config, node_id)),
            verified=tuple(verified),
            trim_object=self.links[node_id].trim_object,
        )

    def verification_verdict(self, node_id: int) -> str:
        """Return the certificate's verification line for one node ("" before a solution)."""
        solved = self.procedure.solved
        if solved is None or node_id not in solved.acceptance:
            return ""
        return verification_verdict(
            self.facts(node_id).verification, solved.acceptance[node_id].passed
        )

    def _write_certificates(self, node_id: int) -> None:
        link = self.links[node_id]
        assert link.certificate_path is not None
        write_text(link.certificate_path, self.certificate(node_id))
        write_text(link.certificate_path.with_suffix(".html"), self.certificate(node_id, html=True))

    def write(self, options: WriteOptions | None = None) -> list[ev.Event]:
        """Write every node's calibration transactionally, read it back, verify at level."""
        options = options or WriteOptions()
        events = self.procedure.begin_write(override=options.override)
        if self.procedure.phase is not Phase.WRITING:
            return self._keep(events)
        for node_id, link in self.links.items():
            assert link.record is not None
            try:
                report = write_calibration_transaction(
                    link.client,
                    link.record,
                    force=options.force,
                    store=options.store,
                    backup_dir=self.backup_dir,
                )
            except CanimucalError as exc:
                events += self.procedure.write_finished(node_id, False, str(exc))
                continue
            link.trim_object = report.trim_object
            self._add_readback(node_id)
            backup = str(report.backup_path) if report.backup_path else None
            what = "written and verified"
            if not report.trim_object and link.record.mounting_trim_deg is not None:
                what += (
                    "; the mounting trim was NOT written: the node has no 0x2122 (a firmware "
                    "before it)"
                )
            events += self.procedure.write_finished(node_id, True, what, backup)
        return self._keep(events)

    def _add_readback(self, node_id: int) -> None:
        link = self.links[node_id]
        readout = link.client.read_calibration_block()
        assert link.record is not None and link.record_path is not None
        back = readback_of(readout.block, readout.valid, readout.crc_ok)
        link.record = replace(link.record, readback=back)
        write_text(link.record_path, calibration_to_json(link.record))

    def finish(self) -> None:
        """Rewrite the certificates with the verification, close what is open (idempotent).

        A node that was written but not verified at level (the session was interrupted or
        cancelled in between) has ``verification: {done: false, passed: false}`` recorded
        in its calibration JSON and certificate.
        """
        for node_id, link in self.links.items():
            self._write_rows(node_id)
            link.writer.close()
            if link.certificate_path is not None and self.procedure.solved is not None:
                if link.record is not None and link.record_path is not None:
                    verification = self.facts(node_id).verification
                    link.record = replace(link.record, verification=verification)
                    write_text(link.record_path, calibration_to_json(link.record))
                self._write_certificates(node_id)

    def _name(self, stem: str, node_id: int, suffix: str) -> Path:
        return output_name(self.out_dir, stem, node_id, self.several, suffix)


def output_name(out_dir: Path, stem: str, node_id: int, several: bool, suffix: str) -> Path:
    """``stem.suffix``, or ``stem.node<ID>.suffix`` when several nodes (docs/design.md §7)."""
    return out_dir / (f"{stem}.node{node_id}{suffix}" if several else f"{stem}{suffix}")


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, replacing what is there."""
    from canimucal.io.atomic import write_text_atomic

    write_text_atomic(path, text, overwrite=True)


def open_resumed(path: Path, header: Mapping[str, Any]) -> RecordingWriter:
    """Append to the recording of an interrupted session (its ``.partial`` is the newer copy)."""
    partial = partial_path(path)
    if os.path.lexists(partial):  # a symlink is moved as a link, then refused by the append
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


def device_of(node_id: int, identity: Identity) -> Device:
    """Return the calibration record's ``device`` block of a node."""
    return Device(
        node_id=node_id,
        vendor_id=identity.vendor_id,
        product_code=identity.product_code,
        revision=identity.revision,
        serial=identity.serial,
    )


def model_header(cfg: ProcedureConfig) -> dict[str, Any]:
    """Header keys naming the model the session solves (docs/design.md §5), for ``solve`` to reuse.

    ``tolerance_deg`` is the plan's largest tilt tolerance; ``solve`` takes each position's
    own from the built-in plan that ``plan`` names. ``gyro`` is ``moves`` when the session
    fits the MEMS gyro's S to its moves; ``gyro_g`` (only when true) that it estimates G.
    """
    spec = cfg.spec
    tolerance = max(p.tolerance for p in cfg.plan.positions)
    return {
        "plan": cfg.plan_name or cfg.plan.name,
        "model": spec.accel_k,
        "tilt": spec.tilt,
        "gyro": "moves" if spec.gyro == "mems" and cfg.gyro_moves else spec.gyro,
        "tolerance_deg": round(float(np.rad2deg(tolerance)), 10),
        **({"gyro_g": True} if spec.gyro_g else {}),
    }


def prior_header(cfg: ProcedureConfig, node_id: int) -> dict[str, Any]:
    """Header keys of the prior on K the session holds for one node, for ``solve`` to reuse."""
    return k_prior_header(cfg.k_priors.get(node_id, KPrior()), cfg.plan, cfg.site.accel_lsb)


def k_prior_header(held: KPrior, plan: Plan, accel_lsb: float) -> dict[str, Any]:
    """Header keys (``prior_k``, ``prior_k_sigma`` and their sources) of a prior on K.

    Empty when ``plan`` holds no prior; defaults (the nominal mean, the plan's σ) filled in.
    """
    if not held.needed(plan):
        return {}
    full = held.resolved(plan, accel_lsb)
    assert full.mean is not None and full.rel_sigma is not None
    return {
        "prior_k": matrix_header(full.mean),
        "prior_k_sigma": full.rel_sigma,
        "prior_k_source": full.mean_source,
        "prior_k_sigma_source": full.sigma_source,
    }


def recording_header(
    rate_hz: float, site: SiteConditions, identity: Identity, node_id: int
) -> dict[str, Any]:
    """Return the header of a node's recording CSV (docs/design.md §5)."""
    header: dict[str, Any] = {
        "sample_rate_hz": rate_hz,
        "node_id": node_id,
        "device_serial": identity.serial,
        "g": site.g,
        "heading_deg": float(np.rad2deg(site.heading)),
        "accel_lsb": site.accel_lsb,
        "gyro_lsb": site.gyro_lsb,
    }
    if site.latitude is not None:
        header["latitude_deg"] = float(np.rad2deg(site.latitude))
    if site.height_m is not None:
        header["height_m"] = site.height_m
    return header
