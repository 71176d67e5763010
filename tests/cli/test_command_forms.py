"""The README's command forms, quiet library logs, and one-line bus errors with a hint.

The TUI forms are tested by parsing only: the TUI itself never starts here.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import pytest

from canimucal.cli.main import _verb_of, _with_verb, build_parser, configure_logging
from canimucal.simnode.node import SimulatedImuNode

Cli = Callable[[Sequence[Any]], Any]


def parse(*argv: str) -> Any:
    verb = _verb_of(list(argv))
    return build_parser(verb).parse_args(_with_verb(list(argv), verb))


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        ((), {}),
        (("--channel", "can0"), {"channel": "can0", "sim": False}),
        (("--sim",), {"sim": True}),
        (("-v", "--interface", "virtual", "--channel", "x"), {"interface": "virtual"}),
        (("--debug", "--sim", "--plan", "five"), {"plan": "five", "debug": True}),
        (("--channel=can1",), {"channel": "can1"}),
    ],
)
def test_tui_options_without_the_verb_open_the_tui(argv: tuple[str, ...], expected: dict) -> None:
    args = parse(*argv)
    assert args.command == "tui"
    for key, value in expected.items():
        assert getattr(args, key) == value, key


def test_other_verbs_and_unknown_words_are_unchanged() -> None:
    assert parse("-v", "plan", "--plan", "vehicle").command == "plan"
    assert _verb_of(["solv"]) is None  # argparse reports the unknown verb
    with pytest.raises(SystemExit) as exc:
        parse("solv")
    assert exc.value.code == 2


@pytest.fixture
def _restore_library_loggers() -> Iterator[None]:
    levels = {name: logging.getLogger(name).level for name in ("can", "canopen")}
    yield
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


@pytest.mark.usefixtures("_restore_library_loggers")
@pytest.mark.parametrize(
    ("argv", "verbose", "debug"),
    [
        (("plan", "-v", "--plan", "two"), True, False),
        (("-v", "plan", "--plan", "two"), True, False),
        (("solve", "rec.csv", "--debug"), False, True),
        (("--debug", "solve", "rec.csv", "--verbose"), True, True),
        (("solve", "rec.csv"), False, False),
        (("--sim", "-v"), True, False),
    ],
)
def test_verbose_and_debug_before_or_after_the_verb(
    argv: tuple[str, ...], verbose: bool, debug: bool
) -> None:
    args = parse(*argv)
    assert (args.verbose, args.debug) == (verbose, debug)


def test_verbose_after_the_verb_runs(cli: Cli) -> None:
    run = cli(["plan", "--plan", "two", "-v"])
    assert run.code == 0, run.err


def test_library_log_lines_show_only_with_verbose() -> None:
    configure_logging(verbose=False, debug=False)
    assert not logging.getLogger("canopen.sdo.client").isEnabledFor(logging.ERROR)
    assert not logging.getLogger("can").isEnabledFor(logging.ERROR)
    configure_logging(verbose=True, debug=False)
    assert logging.getLogger("canopen.sdo.client").isEnabledFor(logging.WARNING)
    assert logging.getLogger("can").isEnabledFor(logging.INFO)


def test_a_missing_node_is_reported_with_the_nodes_heartbeating(
    cli: Cli, make_sim_node: Callable[..., SimulatedImuNode], bus_channel: str
) -> None:
    make_sim_node(0x10, time_scale=5.0)  # heartbeats on the virtual bus
    bus = ["--interface", "virtual", "--channel", bus_channel, "--sdo-timeout", "0.2"]
    run = cli(["read-params", *bus, "--node-id", "0x20"])
    assert run.code == 4
    assert run.err.count("\n") == 1 and run.err.startswith("error: no CANopen node 32")
    assert "heartbeating on virtual/" in run.err and "node 16 (0x10)" in run.err
    assert "check --node-id" in run.err


def test_a_driver_that_is_not_installed_is_one_line_exit_4(cli: Cli) -> None:
    run = cli(["read-params", "--interface", "kvaser", "--channel", "0"])
    assert run.code == 4
    assert run.err.count("\n") == 1 and run.err.startswith("error: cannot open CAN bus kvaser/0")
    assert "internal error" not in run.err


def test_socketcan_errors_carry_a_hint(cli: Cli) -> None:
    run = cli(["read-params", "--interface", "socketcan", "--channel", "nosuchcan7"])
    assert run.code == 4 and run.err.count("\n") == 1
    assert "[Errno" in run.err and ("ip link" in run.err or "modprobe" in run.err)
