"""The `canimucal` entry point: a subparser per verb, errors mapped to docs/design.md §7 exit codes.

Subcommand modules are imported lazily by name so that `canimucal --help` loads neither
Textual nor the CAN stack.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import traceback
from collections.abc import Sequence

from canimucal.cli.heap import keep_heap_for_arrays
from canimucal.errors import CanimucalError
from canimucal.flag_words import worded_for_flags
from canimucal.signals import (
    SignalHandling,
    deferred_signals,
    describe,
    exit_status,
    handle_signals,
    ignore_signals,
    interrupt_for,
)
from canimucal.version import __version__

# verb -> (module under canimucal.cli providing `add_subparser` and `run`, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "solve": ("solve_cmd", "solve a recording for the calibration parameters"),
    "plan": ("plan_cmd", "Cramér–Rao bound of every parameter for a plan"),
    "allan": ("allan_cmd", "Allan deviation, noise terms and recommended averaging time"),
    "demo": ("demo_cmd", "the whole job against the built-in simulated IMU"),
    "sim": ("sim_cmd", "run the simulated IMU node on a CAN bus until Ctrl-C"),
    "read-params": ("read_params_cmd", "read identity and calibration from the node"),
    "write-params": ("write_params_cmd", "write a calibration to the node, transactionally"),
    "record": ("record_cmd", "record one position or a whole plan to a recording CSV"),
    "analyze": ("analyze_cmd", "what the sensor model gets wrong on measured data"),
    "import-log": ("import_log_cmd", "turn a CAN bus log into a recording CSV"),
    "tui": ("tui_cmd", "the guided calibration in the terminal UI (the default)"),
}

LIBRARY_LOGGERS = ("can", "canopen")
"""Their log lines (canopen's ERROR/WARNING before our own one-line error) show only with -v."""
_TOP_FLAGS = ("--debug", "-v", "--verbose")


def build_parser(verb: str | None = None) -> argparse.ArgumentParser:
    """Build the argument parser; only ``verb``'s module is imported (``None``: none).

    The other verbs get a stub subparser carrying their help line, so ``canimucal --help``
    lists them all while loading neither the CAN stack nor Textual, and each command starts
    without importing every other command's dependencies.
    """
    parser = argparse.ArgumentParser(
        prog="canimucal",
        description="Field calibration of a CANopen IMU from small rotations.",
    )
    parser.add_argument("--version", action="version", version=f"canimucal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="show informational log lines, the CAN libraries' too",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_line) in COMMANDS.items():
        if name == verb:
            importlib.import_module(f"canimucal.cli.{module_name}").add_subparser(subparsers)
        else:
            subparsers.add_parser(name, help=help_line)
    for sub in subparsers.choices.values():
        _add_top_flags(sub)
    return parser


def _add_top_flags(sub: argparse.ArgumentParser) -> None:
    """Accept ``--debug`` and ``-v`` after the verb too (``canimucal solve -v rec.csv``).

    ``SUPPRESS``: the verb's parser sets them only when given, so a flag before the verb is
    not reset by the verb's default.
    """
    sub.add_argument(
        "--debug", action="store_true", default=argparse.SUPPRESS, help="as before the verb"
    )
    sub.add_argument(
        "-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help="as before the verb"
    )


def _verb_of(argv: Sequence[str]) -> str | None:
    """Return the verb ``argv`` runs: the first word naming one, ``tui`` when there is none.

    ``canimucal --channel can0`` and ``canimucal --sim`` are the TUI's own options: a word
    right after a ``--option`` (other than the top-level flags) is taken as its value.
    ``None`` for top-level help or version (nothing to import) and for an unknown word
    (argparse then reports it).
    """
    previous = ""
    for arg in argv:
        if arg in COMMANDS:
            return arg
        if arg in ("-h", "--help", "--version"):
            return None
        is_value = previous.startswith("--") and "=" not in previous
        if not arg.startswith("-") and not (is_value and previous not in _TOP_FLAGS):
            return None
        previous = arg
    return "tui"


def _with_verb(argv: list[str], verb: str | None) -> list[str]:
    """Insert ``tui`` after the top-level flags when the TUI's options came without it."""
    if verb != "tui" or "tui" in argv:
        return argv
    top = [a for a in argv if a in _TOP_FLAGS]
    return [*top, "tui", *(a for a in argv if a not in _TOP_FLAGS)]


def configure_logging(verbose: bool, debug: bool) -> None:
    """WARNING and up from canimucal; INFO with ``-v``, DEBUG with ``--debug``.

    The CAN libraries' own lines are hidden unless ``-v`` or ``--debug``: every error they
    cause reaches the user as canimucal's one-line error.
    """
    level = logging.DEBUG if debug else logging.INFO if verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    for name in LIBRARY_LOGGERS:
        logging.getLogger(name).setLevel(level if verbose or debug else logging.CRITICAL + 1)


def main(argv: Sequence[str] | None = None, *, early: Sequence[int] = ()) -> int:
    """Run one command; return its exit status.

    Ctrl-C gives 130, SIGTERM 143 and SIGHUP 129 (``sim``: 0, its normal stop) at any
    moment, imports and argument parsing included, with one line naming what was done
    (never a traceback). ``early``: signals the entry point held before this ran
    (:mod:`canimucal.cli.entry`); the first is raised here as if it had just arrived.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    handling = handle_signals()
    try:
        if early:
            raise interrupt_for(early[0])
        return _main(argv, handling)
    except KeyboardInterrupt as interrupt:
        ignore_signals()  # a second interrupt must not cut the report short
        return _interrupted(interrupt, _verb_of(argv))
    finally:
        handling()


def _main(argv: list[str], handling: SignalHandling) -> int:
    verb = _verb_of(argv)
    # the command's modules are imported here (numpy, scipy, canopen: up to a second or
    # more): a Ctrl-C inside a C extension's import comes out as an ImportError, so the
    # signals wait until the imports are done
    with deferred_signals() as held:
        parser = build_parser(verb)
        args = parser.parse_args(_with_verb(argv, verb))  # `canimucal [TUI options]`: the TUI
    interrupt = held.interrupt()
    if interrupt is not None:
        raise interrupt
    configure_logging(args.verbose, args.debug)
    if verb in BULK_ARRAY_VERBS:
        keep_heap_for_arrays()
    try:
        return int(args.run(args))
    except CanimucalError as error:
        _report(error, args.debug)
        return error.exit_code
    except BrokenPipeError:
        return 0
    except MemoryError:  # an input too large for this machine: say so, never a traceback
        print("error: out of memory (input too large for this machine?)", file=sys.stderr)
        return 2
    except Exception as error:
        if handling.first is not None:  # the interrupt's own doing (a lazy import it cut)
            raise interrupt_for(handling.first) from error
        _report(error, args.debug, prefix="internal error: ")  # a bug: say so, in one line
        return 1


BULK_ARRAY_VERBS = frozenset({"solve", "allan", "analyze"})
"""Commands that sweep a whole recording's arrays, block by block (:mod:`.heap`)."""


def _interrupted(interrupt: KeyboardInterrupt, verb: str | None) -> int:
    """Report an interrupt in one line (its notes say what was done); return the status."""
    if verb == "sim":
        return 0
    words = [describe(interrupt), *getattr(interrupt, "__notes__", [])]
    try:
        print("; ".join(words), file=sys.stderr)
    except OSError:  # the terminal is gone (SIGHUP): the status still tells
        pass
    return exit_status(interrupt)


def _report(error: BaseException, debug: bool, prefix: str = "") -> None:
    if debug:
        traceback.print_exception(error, file=sys.stderr)
    message = " ".join(worded_for_flags(error).split()) or type(error).__name__
    print(f"error: {prefix}{message}", file=sys.stderr)
