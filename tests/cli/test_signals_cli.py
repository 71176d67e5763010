"""Interrupts at any moment of a command: one line, exit 130 (Ctrl-C) or 143 (SIGTERM)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

import pytest

from canimucal.cli import main as cli_main
from canimucal.io.recording import read_recording
from canimucal.signals import Terminated


def _raising(exc: BaseException) -> Any:
    def build_parser(verb: str | None = None) -> NoReturn:
        raise exc

    return build_parser


@pytest.mark.parametrize(
    ("exc", "code", "line"),
    [(KeyboardInterrupt(), 130, "interrupted"), (Terminated(), 143, "terminated")],
)
def test_interrupt_while_importing_the_command_is_one_line(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    exc: BaseException,
    code: int,
    line: str,
) -> None:
    # the first ~1 s of a command is spent importing numpy/scipy/canopen in build_parser
    monkeypatch.setattr(cli_main, "build_parser", _raising(exc))
    assert cli_main.main(["solve", "x.csv"]) == code
    assert capsys.readouterr().err == f"{line}\n"
    assert signal.getsignal(signal.SIGINT) is not signal.SIG_IGN  # handlers put back


def test_sigterm_during_a_command_exits_143_with_the_notes(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def build_parser(verb: str | None = None) -> NoReturn:
        try:
            os.kill(os.getpid(), signal.SIGTERM)  # the handler main installed raises here
        except Terminated as term:
            term.add_note("previous calibration restored from /b/1.json")
            raise
        raise AssertionError("SIGTERM was not turned into Terminated")

    previous = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(cli_main, "build_parser", build_parser)
    assert cli_main.main(["write-params", "c.json"]) == 143
    assert capsys.readouterr().err == ("terminated; previous calibration restored from /b/1.json\n")
    assert signal.getsignal(signal.SIGTERM) is previous


def test_sim_stops_with_0_on_either_signal(monkeypatch: pytest.MonkeyPatch) -> None:
    for exc in (KeyboardInterrupt(), Terminated()):
        monkeypatch.setattr(cli_main, "build_parser", _raising(exc))
        assert cli_main.main(["sim"]) == 0


def test_record_sigterm_stops_like_ctrl_c(tmp_path: Path) -> None:
    out = tmp_path / "cut.csv"
    cmd = [sys.executable, "-m", "canimucal", "record", str(out), "--sim", "--plan", "five"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    partial = tmp_path / "cut.csv.partial"
    try:
        for _ in range(300):  # until rows are being written (≤ 30 s)
            if partial.exists() and partial.stat().st_size > 5_000:
                break
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "terminated" and "Traceback" not in err
    assert out.exists() and not partial.exists()  # the stream stopped, the file closed
    assert read_recording(out).n_rows > 100
