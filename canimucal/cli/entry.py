"""The process entry point of ``canimucal`` and ``python -m canimucal`` (docs/design.md §9).

It holds SIGINT, SIGTERM and SIGHUP from its first line, before the command line's modules
are imported, so a Ctrl-C that early cannot print a traceback: :func:`canimucal.cli.main.main`
raises the first held signal inside its own handling (one line, exit 130/143/129). The
holding handlers stay in place after ``main`` returns, and the signals are blocked for the
interpreter's finalisation, so a late signal cannot turn the chosen exit status into a death
by signal. Only this module installs them on a process;
``main`` itself, called in process (tests, scripts), puts back what it found.
"""

from __future__ import annotations

import os
import signal
import sys

TYPE_CHECKING = False  # typing not imported: every millisecond before the hold counts
if TYPE_CHECKING:
    from collections.abc import Sequence
    from types import FrameType

_HOLD = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""One BLAS thread unless the user says otherwise (docs/design.md §7): the tool's matrices are
at most a few hundred rows, where threads gain nothing, and on a busy machine OpenBLAS's
waiting threads made ``analyze`` 2.4× slower (a look-alike case: 11.1 s against 4.7 s)."""


def run_main(argv: Sequence[str]) -> int:
    """Run ``canimucal ARGV`` as a whole process would; return its exit status."""
    pending: list[int] = []

    def hold(signum: int, frame: FrameType | None) -> None:
        pending.append(signum)

    for signum in _HOLD:
        if signal.getsignal(signum) is not signal.SIG_IGN:  # nohup, a background job
            signal.signal(signum, hold)
    for name in _BLAS_THREADS:  # read when numpy is first imported, below
        os.environ.setdefault(name, "1")
    from canimucal.cli.main import main
    from canimucal.signals import describe, exit_status

    try:
        return main(list(argv), early=pending)
    except KeyboardInterrupt as interrupt:  # in the instant before main disarms its handler
        try:
            print(describe(interrupt), file=sys.stderr)
        except OSError:  # the terminal is gone (SIGHUP): the status still tells
            pass
        return exit_status(interrupt)


def run() -> None:
    """Run the command and exit with its status (the console script).

    The held signals are blocked before the interpreter finalises: finalisation puts SIG_DFL
    back for every signal with a Python handler, so a Ctrl-C in its last milliseconds killed
    a finished command (status -2 after its whole output, once in CI). Blocked, the signal
    stays pending and goes with the process; the command's own status stands.
    """
    status = run_main(sys.argv[1:])
    signal.pthread_sigmask(signal.SIG_BLOCK, _HOLD)
    sys.exit(status)
