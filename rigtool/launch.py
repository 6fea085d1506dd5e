"""The `rigtool` console command: signals before the command has started (while Python imports
it) or after it has ended neither print a traceback nor change the exit status.

Kept apart from `rigtool.cli`, whose import is the slow part: the handlers are in place
before it starts.
"""

from __future__ import annotations

import os
import signal
import sys

from rigtool import stopping

_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def run() -> None:
    """Run the command line and exit with its status.

    SIGINT exits 130 and SIGTERM/SIGHUP 1 wherever they stop the command, as inside a run,
    also when the stop broke an import the command was making (which then fails with another
    error); once the command has returned, signals are ignored while the process exits.
    """
    for sig in _SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, stopping.on_signal)
    status = None
    try:
        try:
            from rigtool.cli import main

            status = main()
        finally:
            stopping.mark_ended()  # from here a signal is only noted, then ignored
            for sig in _SIGNALS:
                signal.signal(sig, signal.SIG_IGN)
    except BaseException as exc:
        signum = getattr(exc, "signum", None) or stopping.requested()
        if isinstance(exc, SystemExit) or signum is None and not isinstance(
                exc, KeyboardInterrupt):
            raise
        if status is None:  # else the command had returned: its status stands
            line, status = stopping.ending(signum or signal.SIGINT)
            os.write(2, f"{line}\n".encode())
    sys.exit(status)
