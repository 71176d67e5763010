"""The `canimucal` entry point: one subparser per verb, errors mapped to DESIGN §7 exit codes.

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

from canimucal import __version__
from canimucal.errors import CanimucalError

# verb -> module under canimucal.cli providing `add_subparser(subparsers)` and `run(args)`
COMMANDS: dict[str, str] = {
    "solve": "solve_cmd",
    "plan": "plan_cmd",
    "allan": "allan_cmd",
    "demo": "demo_cmd",
}

EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    """Build the full argument parser (every verb registered)."""
    parser = argparse.ArgumentParser(
        prog="canimucal",
        description="Field calibration of a CANopen IMU from small rotations.",
    )
    parser.add_argument("--version", action="version", version=f"canimucal {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_name in COMMANDS.values():
        module = importlib.import_module(f"canimucal.cli.{module_name}")
        module.add_subparser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; return its exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return int(args.run(args))
    except CanimucalError as error:
        _report(error, args.debug)
        return error.exit_code
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0
    except Exception as error:  # a bug: say so, in one line unless --debug
        _report(error, args.debug, prefix="internal error: ")
        return 1


def _report(error: BaseException, debug: bool, prefix: str = "") -> None:
    if debug:
        traceback.print_exception(error, file=sys.stderr)
    message = " ".join(str(error).split()) or type(error).__name__
    print(f"error: {prefix}{message}", file=sys.stderr)
