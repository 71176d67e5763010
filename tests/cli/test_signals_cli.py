"""Interrupts at any moment of a command: one line, exit 130 (Ctrl-C), 143 (SIGTERM), 129 (HUP)."""

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
from canimucal.runtime.inputs import read_recording
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


@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [(signal.SIGTERM, 143, "terminated"), (signal.SIGHUP, 129, "hung up")],
)
def test_a_signal_during_a_command_exits_with_its_status_and_the_notes(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    signum: int,
    code: int,
    word: str,
) -> None:
    from canimucal.cli import plan_cmd

    def run(args: Any) -> NoReturn:
        try:
            os.kill(os.getpid(), signum)  # the handler main installed raises here
        except Terminated as term:
            term.add_note("previous calibration restored from /b/1.json")
            raise
        raise AssertionError("the signal was not turned into an interrupt")

    previous = signal.getsignal(signum)
    monkeypatch.setattr(plan_cmd, "run", run)
    assert cli_main.main(["plan"]) == code
    assert capsys.readouterr().err == f"{word}; previous calibration restored from /b/1.json\n"
    assert signal.getsignal(signum) is previous


def test_a_signal_while_the_command_is_imported_waits_for_the_imports(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # a Ctrl-C inside a C extension's import comes out as an ImportError (numpy's): held
    real = cli_main.build_parser

    def build_parser(verb: str | None = None) -> Any:
        os.kill(os.getpid(), signal.SIGTERM)  # arrives while "importing"
        return real(verb)

    monkeypatch.setattr(cli_main, "build_parser", build_parser)
    assert cli_main.main(["plan"]) == 143
    assert capsys.readouterr().err == "terminated\n"


def test_a_second_signal_cannot_replace_the_first_and_its_notes(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from canimucal.cli import plan_cmd

    def run(args: Any) -> NoReturn:
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt as interrupt:
            interrupt.add_note("previous calibration restored from /b/2.json")
            os.kill(os.getpid(), signal.SIGINT)  # a second Ctrl-C, in the clean-up
            os.kill(os.getpid(), signal.SIGTERM)
            raise
        raise AssertionError("Ctrl-C was not turned into KeyboardInterrupt")

    monkeypatch.setattr(plan_cmd, "run", run)
    assert cli_main.main(["plan"]) == 130
    assert capsys.readouterr().err == "interrupted; previous calibration restored from /b/2.json\n"


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
