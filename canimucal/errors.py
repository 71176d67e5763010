"""One exception root, a subclass per layer; each error knows its CLI exit status.

Exit statuses are the contract of DESIGN §7: 1 internal error, 2 bad input or usage,
3 device refused / verification failed / rollback incomplete, 4 no device or no bus.
"""

from __future__ import annotations


class CanimucalError(Exception):
    """Root of every error the tool raises on purpose.

    ``title`` is a short heading for the TUI's error modal; ``str(error)`` is the one-line
    message the CLI prints after ``error: ``.
    """

    exit_code: int = 1
    title: str = "Error"


class InputError(CanimucalError):
    """Bad input: a malformed file, a bad argument, a plan that cannot be solved (exit 2)."""

    exit_code = 2
    title = "Bad input"


class ModelError(InputError):
    """The numerics cannot answer with the data given (too few positions, degenerate plan)."""

    title = "Cannot solve"


class DeviceError(CanimucalError):
    """The device refused, verification failed, or a rollback was incomplete (exit 3)."""

    exit_code = 3
    title = "Device error"


class NoDeviceError(CanimucalError):
    """No bus, or no node answering on it (exit 4)."""

    exit_code = 4
    title = "No device"
