"""Every error the tool raises on purpose: one root, a branch per exit status (docs/design.md §7).

Exit statuses: 1 internal error, 2 bad input or usage, 3 device refused / verification
failed / rollback incomplete, 4 no device or no bus. The tree::

    CanimucalError
    ├── InputError (2)        ModelError, SchemaError
    ├── DeviceError (3)       SdoAbort, DeviceSilentError, NodeRebootedError,
    │                         ForeignSdoClientError, RollbackIncompleteError
    └── NoDeviceError (4)     DuplicateNodeError
"""

from __future__ import annotations

from pathlib import Path


class CanimucalError(Exception):
    """Root of every error the tool raises on purpose.

    ``title`` is a short heading for the TUI's error modal; ``str(error)`` is the one-line
    message, in the terms of the Python API (``pass overwrite=True``, ``prior_k_sigma``).
    ``options`` lists the API spellings the message uses for arguments that caused or
    would resolve it, so that a shell can word them its own way (the CLI prints
    ``--overwrite``, ``--prior-k-sigma``: docs/design.md §1).
    """

    exit_code: int = 1
    title: str = "Error"
    options: tuple[str, ...] = ()

    def __init__(self, *args: object, options: tuple[str, ...] = ()) -> None:
        super().__init__(*args)
        if options:
            self.options = options


class InputError(CanimucalError):
    """Bad input: a malformed file, a bad argument, a plan that cannot be solved (exit 2)."""

    exit_code = 2
    title = "Bad input"


class ModelError(InputError):
    """The numerics cannot answer with the data given (too few positions, degenerate plan)."""

    title = "Cannot solve"


class SchemaError(InputError):
    """A value in a JSON document does not fit its schema; the message names the key path."""


class DeviceError(CanimucalError):
    """The device refused, verification failed, or a rollback was incomplete (exit 3)."""

    exit_code = 3
    title = "Device error"


class SdoAbort(DeviceError):
    """The node refused an SDO transfer (abort code in ``code``); never retried."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


class DeviceSilentError(DeviceError):
    """An SDO transfer timed out after every retry."""


class StoreTimeoutError(DeviceSilentError):
    """A 0x1010 store got no answer within its own timeout (never retried, never rolled back)."""


class NodeRebootedError(DeviceError):
    """The node booted during an SDO transfer: its unsaved values are gone (never retried)."""


class ForeignSdoClientError(DeviceError):
    """Another SDO client sent requests to the node during a write transaction (exit 3)."""

    title = "Another SDO client"

    def __init__(self, node_id: int) -> None:
        super().__init__(f"another SDO client is using node {node_id}")
        self.node_id = node_id


class RollbackIncompleteError(DeviceError):
    """The backup could not be written back; the device is left invalid (exit 3)."""

    title = "Rollback incomplete"

    def __init__(self, backup_path: Path) -> None:
        super().__init__(
            f"rollback incomplete; device invalidated; restore with canimucal write-params "
            f"{backup_path}"
        )
        self.backup_path = backup_path


class NoDeviceError(CanimucalError):
    """No bus, or no node answering on it (exit 4)."""

    exit_code = 4
    title = "No device"


class DuplicateNodeError(NoDeviceError):
    """Two or more devices answer as one node-id (exit 4); nothing was written or read.

    Every SDO request then gets two answers and every write lands on both units
    (docs/design.md §9 "One device per node-id").
    """

    title = "Two devices, one node-id"
