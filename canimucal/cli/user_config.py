"""The user's configuration the commands read and hand to the library (docs/design.md §1, §5).

The library never reads it on its own: ``solve``, ``demo`` and the TUI read
``acceptance.toml`` here and pass the limits in.
"""

from __future__ import annotations

from canimucal.analysis.acceptance import (
    AcceptanceConfig,
    acceptance_config_path,
    read_acceptance_config,
)


def user_acceptance() -> AcceptanceConfig:
    """Return the user's acceptance limits (built-in ones when there is no file).

    A file that is there but wrong is an :class:`~canimucal.errors.InputError` (exit 2).
    """
    return read_acceptance_config(acceptance_config_path())
