"""``python -m tests.support.hub_cli ARGS``: ``canimucal ARGS`` with the ``canimucal-tcp`` bus.

For a command started in a fresh interpreter (a terminal under tmux, a pty) that must join a
:class:`~tests.support.tcpbus.TcpHub`: registers the interface, then runs the CLI's own entry
point, so the exit status and everything printed are the command's.
"""

from __future__ import annotations

import sys

from tests.support import tcpbus

if __name__ == "__main__":
    tcpbus.register()
    from canimucal.cli.entry import run_main

    sys.exit(run_main(sys.argv[1:]))
