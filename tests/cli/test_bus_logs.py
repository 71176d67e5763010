"""Bus logs in and out (issue 20 item 3): ``record --can-log``, ``import-log`` and logs as input.

One simulated session (two nodes on python-can's virtual bus following the recommended plan
by themselves, every frame written by python-can's own writers in each format it writes
without extra packages) is recorded once; every test reads its logs. The session's own
recordings are the reference: a log imported with the plan's schedule must give the same
samples, header and calibration (within σ/10, docs/design.md §5), and one imported by
stillness must label only samples the schedule holds still.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

import canimucal as cm
from canimucal.cli.main import main
from canimucal.io.plans import resolve_plan
from canimucal.io.recording import Recording
from canimucal.model.vocabulary.constants import COUNTER_MODULUS
from canimucal.runtime import inputs
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.recorder import ScheduleLabels
from tests.cli.conftest import make_truth
from tests.support.cli_run import CliRun

Cli = Callable[[Sequence[Any]], CliRun]

NODES = (16, 17)
PLAN = "recommended"
SECONDS = 6.0
TRANSIENT_S = 1.0  # record's default move time between scheduled poses
SEED = 5
FORMATS = (".log", ".asc", ".blf", ".trc", ".csv", ".db")
"""Every log format python-can 4.x writes and reads without extra packages."""
SITE_KEYS = ("g", "latitude_deg", "height_m", "heading_deg")


@dataclass(frozen=True)
class Session:
    """The recorded session: its recordings per node and its logs per suffix."""

    root: Path
    recordings: dict[int, Path]
    logs: dict[str, Path]
    solved: dict[Path, dict[str, Any]] = field(default_factory=dict)

    def recording(self, node: int) -> Recording:
        return read_recording(self.recordings[node])

    def site_flags(self, node: int) -> list[str]:
        header = self.recording(node).header
        flags = []
        for key in SITE_KEYS:
            if key in header:
                flags += [f"--{key.replace('_', '-')}", repr(header[key])]
        return flags


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Session:
    root = tmp_path_factory.mktemp("bus_logs")
    truth = root / "truth.json"
    truth.write_text(json.dumps(make_truth("full").to_dict()))
    logs = {suffix: root / f"session{suffix}" for suffix in FORMATS}
    argv = ["record", root / "rec.csv", "--sim", "--truth", truth, "--plan", PLAN,
            "--seconds", SECONDS, "--time-scale", 50, "--seed", SEED]  # fmt: skip
    for node in NODES:
        argv += ["--node-id", node]
    for path in logs.values():
        argv += ["--can-log", path]
    assert main([str(a) for a in argv]) == 0
    recordings = {node: root / f"rec.node{node}.csv" for node in NODES}
    assert all(path.is_file() for path in [*recordings.values(), *logs.values()])
    assert not list(root.glob("*.partial*"))
    return Session(root, recordings, logs)


def plan_for_session() -> Any:
    plan = resolve_plan(PLAN)
    return plan.with_total_seconds(SECONDS * len(plan.positions))


def import_args(session: Session, log: Path, out: Path, node: int, *extra: Any) -> list[Any]:
    return ["import-log", log, "--out", out, "--node-id", node, *session.site_flags(node), *extra]


def solve_json(cli: Cli, path: Path, cache: dict[Path, dict[str, Any]] | None = None) -> Any:
    if cache is not None and path in cache:
        return cache[path]
    run = cli(["solve", path, "--json", "-", "--no-check"])
    assert run.code == 0, run.err
    doc = json.loads(run.out)
    if cache is not None:
        cache[path] = doc
    return doc


def unwrapped(counter: np.ndarray) -> np.ndarray:
    """The 16-bit sample counter as a sequence that does not wrap."""
    steps = np.mod(np.diff(counter), COUNTER_MODULUS)
    return counter[0] + np.concatenate(([0], np.cumsum(steps)))


def estimates(doc: dict[str, Any]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, values and σ of every estimated parameter (the covariance's order)."""
    names = list(doc["covariance"]["order"])
    sigma = np.sqrt(np.diag(np.array(doc["covariance"]["matrix"], dtype=float)))
    values = np.array([_value(doc, name) for name in names], dtype=float)
    return names, values, sigma


def _value(doc: dict[str, Any], name: str) -> float:
    head, *indices = name.replace("]", "").split("[")
    node: Any = doc
    for part in head.split("."):
        node = node[part]
    for index in indices:
        node = node[int(index)]
    return float(node)


# ------------------------------------------------------------------------- the done-when


@pytest.mark.parametrize("suffix", FORMATS)
def test_a_scheduled_import_is_the_sessions_own_recording(
    session: Session, cli: Cli, tmp_path: Path, suffix: str
) -> None:
    """Same samples, same header, same calibration (within σ/10) as the session recorded."""
    node = NODES[0]
    out = tmp_path / "imported.csv"
    args = import_args(session, session.logs[suffix], out, node, "--plan", PLAN)
    run = cli([*args, "--seconds", SECONDS, "--follow-schedule"])
    assert run.code == 0, run.err
    assert "lost 0 samples, 0 accel and 0 gyro halves; 0 duplicate, 0 late" in run.out
    own, imported = session.recording(node), read_recording(out)
    # every sample the session wrote, decoded from the log with the same values
    seq = unwrapped(imported.counter)
    at = np.searchsorted(seq, unwrapped(own.counter))
    assert np.array_equal(imported.counter[at], own.counter)
    # a half that came after the client stopped listening is in the log, not the recording
    live = np.isfinite(own.accel[:, 0]) & np.isfinite(own.gyro[:, 0])
    assert np.count_nonzero(~live) <= 2 and live[:-2].all()
    assert np.array_equal(imported.accel[at][live], own.accel[live])
    assert np.array_equal(imported.gyro[at][live], own.gyro[live])
    assert np.array_equal(imported.position[at], own.position)
    t_own, t_log = own.t[live] - own.t[0], imported.t[at][live] - imported.t[at][0]
    assert np.allclose(t_log, t_own, atol=2e-6)  # the logs keep µs (the time of TPDO2)
    assert imported.header == own.header  # rate, node, serial, LSBs from the log; plan; site
    names, want, sigma = estimates(solve_json(cli, session.recordings[node], session.solved))
    names_got, got, _ = estimates(solve_json(cli, out))
    assert names_got == names
    worst = np.abs(got - want) / sigma
    assert worst.max() <= 0.1, f"{names[int(np.argmax(worst))]}: {worst.max():.3g}σ"


def test_stillness_labels_only_what_the_schedule_holds_still(
    session: Session, cli: Cli, tmp_path: Path
) -> None:
    """Without the schedule: every labelled sample is steady at its position, most are found."""
    node = NODES[0]
    out = tmp_path / "still.csv"
    run = cli([*import_args(session, session.logs[".blf"], out, node, "--plan", PLAN)])
    assert run.code == 0, run.err
    rec = read_recording(out)
    plan = plan_for_session()
    steady = ScheduleLabels(plan, transient_s=TRANSIENT_S, guard_s=0.0)
    seq = np.concatenate(([0], np.cumsum(np.mod(np.diff(rec.counter), COUNTER_MODULUS))))
    truth = steady.labels(seq / rec.sample_rate_hz)
    truth[seq / rec.sample_rate_hz >= steady.end_s] = len(plan.positions) - 1  # holds the last
    labelled = rec.position >= 0
    assert np.array_equal(rec.position[labelled], truth[labelled])  # never a moving sample
    for k in range(len(plan.positions)):
        found = np.count_nonzero(rec.position == k)
        held = np.count_nonzero(truth == k)
        assert found >= 0.8 * held, (k, found, held)
    # the angles are the plan's; solve takes the session's model from the header
    names, want, sigma = estimates(solve_json(cli, session.recordings[node], session.solved))
    _, got, _ = estimates(solve_json(cli, out))
    assert np.all(np.abs(got - want) <= 2.0 * sigma), names


def test_the_second_node_of_the_log_is_its_own(session: Session, cli: Cli, tmp_path: Path) -> None:
    node = NODES[1]
    out = tmp_path / "second.csv"
    args = import_args(session, session.logs[".trc"], out, node, "--plan", PLAN)
    run = cli([*args, "--seconds", SECONDS, "--follow-schedule"])
    assert run.code == 0, run.err
    own, imported = session.recording(node), read_recording(out)
    at = np.searchsorted(unwrapped(imported.counter), unwrapped(own.counter))
    live = np.isfinite(own.accel[:, 0])
    assert np.array_equal(imported.accel[at][live], own.accel[live])
    assert imported.header["node_id"] == node


def test_a_node_the_log_does_not_hold_is_refused(
    session: Session, cli: Cli, tmp_path: Path
) -> None:
    out = tmp_path / "none.csv"
    run = cli(["import-log", session.logs[".log"], "--out", out, "--node-id", 5])
    assert run.code == 2
    assert "node 5 (0x05) is not in this log (no TPDO at 0x185/0x285, no heartbeat); " in run.err
    assert "nodes seen: 16 (0x10" in run.err
    assert "17 (0x11" in run.err and len(run.err.strip().splitlines()) == 1
    run = cli(["import-log", session.logs[".log"], "--out", out])  # two IMUs: which one?
    assert run.code == 2 and "which node?" in run.err
    assert not out.exists()


def test_the_log_holds_what_the_tool_sent_as_transmitted(session: Session) -> None:
    """NMT start and SDO requests are in the log (python-can's Tx), as candump would show."""
    node = NODES[0]
    messages = _messages(session.logs[".asc"])
    sent = {m.arbitration_id for m in messages if not m.is_rx}
    assert {0x000, 0x600 + node} <= sent
    assert any(m.arbitration_id == 0 and bytes(m.data) == bytes([1, node]) for m in messages)
    assert all(m.is_rx for m in messages if m.arbitration_id in (0x180 + node, 0x580 + node))


def test_without_sdo_answers_the_rate_comes_from_the_log_times(cli: Cli, tmp_path: Path) -> None:
    """A real-time log stripped of SDO traffic: rate from the counters over log time, and no
    serial or LSBs invented."""
    log, rec = tmp_path / "live.log", tmp_path / "live.csv"
    run = cli(["record", rec, "--sim", "--position", 0, "--alpha-deg", 0, "--beta-deg", 0,
               "--seconds", 3, "--seed", SEED, "--can-log", log])  # fmt: skip
    assert run.code == 0, run.err
    quiet = tmp_path / "no_sdo.log"
    _write(quiet, [m for m in _messages(log) if not 0x580 < m.arbitration_id < 0x680])
    out = tmp_path / "imported.csv"
    run = cli(["import-log", quiet, "--out", out])
    assert run.code == 0, run.err
    assert "sample_rate_hz 200 (the log's times)" in run.out
    assert "device_serial not in the log" in run.out and "PDO mapping: EDS defaults" in run.out
    header = read_recording(out).header
    assert header["sample_rate_hz"] == read_recording(rec).header["sample_rate_hz"] == 200.0
    assert not {"device_serial", "accel_lsb", "gyro_lsb"} & set(header)


# ------------------------------------------------------------------ logs as direct input


def test_solve_analyze_and_allan_take_a_log(session: Session, cli: Cli, tmp_path: Path) -> None:
    """solve LOG is solve of what import-log writes; analyze and allan read a log too."""
    node = NODES[0]
    log = session.logs[".asc"]
    out = tmp_path / "imported.csv"
    assert cli(["import-log", log, "--out", out, "--node-id", node, "--plan", PLAN]).code == 0
    direct = cli(["solve", log, "--node-id", node, "--plan", PLAN, "--json", "-", "--no-check"])
    assert direct.code == 0, direct.err
    via_file = solve_json(cli, out)
    assert estimates(json.loads(direct.out))[1].tolist() == estimates(via_file)[1].tolist()
    assert json.loads(direct.out)["recording"]["file"] == log.name
    allan = cli(["allan", session.logs[".blf"], "--node-id", node, "--json", "-"])
    assert allan.code == 0, allan.err
    assert json.loads(allan.out)["stretch"]
    analyze = cli(["analyze", log, "--node-id", node, "--plan", PLAN, "--json", "-"])
    assert analyze.code == 0, analyze.err
    assert json.loads(analyze.out)["schema"] == "canimucal.analysis/1"
    wrong = cli(["solve", session.recordings[node], "--node-id", node])
    assert wrong.code == 2 and "for bus logs only" in wrong.err


def test_the_python_api_reads_a_log(session: Session) -> None:
    assert cm.read_recording is inputs.read_recording
    node = NODES[0]
    rec = cm.read_recording(session.logs[".log"], node_id=node, plan=PLAN)
    assert rec.header["node_id"] == node and rec.header["plan"] == PLAN
    assert int((rec.position >= 0).sum()) > 0
    cal = cm.calibrate(session.recordings[node])
    assert cal.recording is not None and cal.recording.file == session.recordings[node].name


def test_logs_are_told_by_content_not_name(session: Session, tmp_path: Path) -> None:
    for suffix, log in session.logs.items():
        renamed = tmp_path / f"capture{suffix}.dat"
        shutil.copyfile(log, renamed)
        assert inputs.detect_format(renamed) == "buslog", suffix
        rec = read_recording(renamed, node_id=NODES[0])
        assert rec.n_rows > 1000
    assert inputs.detect_format(session.recordings[NODES[0]]) == "recording"


def test_mf4_needs_asammdf(session: Session, cli: Cli, tmp_path: Path) -> None:
    pytest.importorskip("asammdf", reason="python-can writes .mf4 through asammdf")
    run = cli(["record", tmp_path / "r.csv", "--sim", "--position", 0, "--alpha-deg", 0,
               "--beta-deg", 0, "--seconds", 2, "--can-log", tmp_path / "r.mf4"])  # fmt: skip
    assert run.code == 0, run.err
    run = cli(["import-log", tmp_path / "r.mf4", "--out", tmp_path / "i.csv"])
    assert run.code == 0, run.err


# ----------------------------------------------------------- losses, duplicates, mapping


def _messages(path: Path) -> list[can.Message]:
    with can.LogReader(path) as reader:
        return list(reader)


def _write(path: Path, messages: Sequence[can.Message]) -> None:
    with can.Logger(path) as writer:
        for msg in messages:
            writer.on_message_received(msg)


def test_lost_and_duplicate_frames_are_counted_as_the_client_counts_them(
    session: Session, cli: Cli, tmp_path: Path
) -> None:
    """A candump log edited by python-can: dropped and repeated frames, no plan, no labels."""
    node = NODES[0]
    tpdo1, tpdo2 = 0x180 + node, 0x280 + node
    kept: list[can.Message] = []
    lost_accel: set[int] = set()
    lost_gyro: set[int] = set()
    lost_both: set[int] = set()
    duplicates = 0
    first: int | None = None  # the counter of the first TPDO1: pairing starts there
    for msg in _messages(session.logs[".log"]):
        cob = msg.arbitration_id
        if cob not in (tpdo1, tpdo2):
            kept.append(msg)
            continue
        counter = int.from_bytes(msg.data[6:8], "little")  # EDS mapping: x, y, z, counter
        first = counter if first is None and cob == tpdo1 else first
        d = (counter - (first if first is not None else counter)) % COUNTER_MODULUS
        if 3000 <= d < 3010:  # ten whole samples gone in a row
            if cob == tpdo1:
                lost_both.add(counter)
            continue
        if d % 97 == 50 and cob == tpdo1:
            lost_accel.add(counter)
            continue
        if d % 89 == 40 and cob == tpdo2 and d % 97 != 50:
            lost_gyro.add(counter)
            continue
        kept.append(msg)
        if d % 53 == 7:
            kept.append(msg)  # the same frame twice
            duplicates += 1
    edited = tmp_path / "edited.log"
    _write(edited, kept)
    out = tmp_path / "edited.csv"
    run = cli(["import-log", edited, "--out", out, "--node-id", node])
    assert run.code == 0, run.err
    summary = (
        f"lost {len(lost_both)} samples, {len(lost_accel)} accel and {len(lost_gyro)} gyro "
        f"halves; {duplicates} duplicate, 0 late"
    )
    assert summary in run.out
    rec = read_recording(out)
    for counter in lost_accel:
        row = np.flatnonzero(rec.counter == counter)
        assert row.size == 1 and np.isnan(rec.accel[row[0]]).all()
    assert not np.isin(rec.counter, list(lost_both)).any()
    labels = sorted(set(rec.position[rec.position >= 0].tolist()))
    assert labels == list(range(len(resolve_plan(PLAN).positions)))
    assert np.isnan(rec.alpha_deg[rec.position >= 0]).all()  # no plan: no angles


def test_the_mapping_comes_from_the_log_or_a_read_params_document(
    session: Session, cli: Cli, tmp_path: Path
) -> None:
    """TPDO1 moved to another COB-ID: the EDS default finds no samples, the log's upload or
    read-params' pdo block does."""
    node = NODES[0]
    moved = 0x1A0 + node
    messages = []
    for msg in _messages(session.logs[".blf"]):
        if msg.arbitration_id == 0x180 + node:
            msg.arbitration_id = moved
        messages.append(msg)
    moved_log = tmp_path / "moved.blf"
    _write(moved_log, messages)
    # the log's own upload of 0x1800:01 still says 0x190: not decodable
    run = cli(["import-log", moved_log, "--out", tmp_path / "a.csv", "--node-id", node])
    assert run.code == 2 and "sent 0 samples" in run.err
    # read-params of a node mapped so: its pdo block decodes the log
    params = tmp_path / "params.json"
    assert cli(["read-params", "--sim", "--node-id", node, "--json", params]).code == 0
    doc = json.loads(params.read_text())
    assert doc["pdo"]["0x1800:01"] == 0x180 + node
    doc["pdo"]["0x1800:01"] = moved
    params.write_text(json.dumps(doc))
    out = tmp_path / "b.csv"
    run = cli(["import-log", moved_log, "--out", out, "--node-id", node, "--pdo-map", params])
    assert run.code == 0, run.err
    assert f"PDO mapping: {params.name}" in run.out
    # the same log whose SDO answer says where TPDO1 went: no document needed
    answered = []
    for msg in messages:
        data = bytes(msg.data)
        if msg.arbitration_id == 0x580 + node and data[:4] == bytes([0x43, 0x00, 0x18, 0x01]):
            msg.data = bytearray(data[:4] + moved.to_bytes(4, "little"))
        answered.append(msg)
    answered_log = tmp_path / "answered.blf"
    _write(answered_log, answered)
    out2 = tmp_path / "c.csv"
    run = cli(["import-log", answered_log, "--out", out2, "--node-id", node])
    assert run.code == 0, run.err
    assert "PDO mapping: the log's SDO uploads" in run.out
    assert np.array_equal(read_recording(out).accel, read_recording(out2).accel, equal_nan=True)


# ------------------------------------------------------------------------ bad input


def test_corrupt_logs_are_one_line_exit_2(session: Session, cli: Cli, tmp_path: Path) -> None:
    blf = bytearray(session.logs[".blf"].read_bytes())
    blf[len(blf) // 2 : len(blf) // 2 + 64] = b"\xff" * 64  # inside a compressed container
    garbled = tmp_path / "garbled.blf"
    garbled.write_bytes(bytes(blf))
    lines = session.logs[".log"].read_text().splitlines()
    lines.insert(100, "this is no candump line")
    broken = tmp_path / "broken.log"
    broken.write_text("\n".join(lines) + "\n")
    empty = tmp_path / "empty.blf"
    empty.write_bytes(b"")
    for path, words in (
        (garbled, "garbled.blf: not a readable Vector BLF log"),
        (broken, "broken.log: not a readable candump log after frame 100"),
        (empty, "empty.blf: not a CAN bus log"),
    ):
        out = tmp_path / "out.csv"
        run = cli(["import-log", path, "--out", out, "--node-id", NODES[0]])
        assert run.code == 2, (path, run.err)
        assert words in run.err and len(run.err.strip().splitlines()) == 1, run.err
        assert not out.exists()
        assert cli(["solve", path, "--node-id", NODES[0]]).code == 2


def test_record_refuses_a_log_it_cannot_write_before_connecting(cli: Cli, tmp_path: Path) -> None:
    rec = tmp_path / "r.csv"
    base = ["record", rec, "--position", 0, "--alpha-deg", 0, "--beta-deg", 0, "--seconds", 1,
            "--channel", "no-such-can-channel"]  # fmt: skip  # no bus is opened: exit 2 first
    existing = tmp_path / "old.asc"
    existing.write_text("keep me")
    for log, words in (
        (tmp_path / "x.txt", "a bus log is named by its format"),
        (tmp_path / "x.blf.gz", "no compressed Vector BLF"),
        (existing, "exists; use --overwrite"),
    ):
        run = cli([*base, "--can-log", log])
        assert run.code == 2 and words in run.err, run.err
    assert existing.read_text() == "keep me" and not rec.exists()
