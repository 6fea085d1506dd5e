"""The `rigtool` console command: signals before the command has started (while Python imports
it) or after it has ended neither print a traceback nor change the exit status.

Kept apart from `rigtool.cli`, whose import is the slow part: the handlers are in place
before it starts.
"""

from __future__ import annotations

import signal
import sys

from rigtool.errors import EXIT_FAILED, EXIT_INTERRUPTED

_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def run() -> None:
    """Run the command line and exit with its status.

    SIGINT exits 130 and SIGTERM/SIGHUP 1 wherever they stop the command, as inside a run;
    once the command has returned, further signals are ignored while the process exits.
    """
    from rigtool import stopping

    for sig in _SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, stopping.on_signal)
    try:
        from rigtool.cli import main

        status = main()
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        sys.stderr.write("rigtool: interrupted\n" if signum == signal.SIGINT
                         else f"rigtool: stopped by {signal.Signals(signum).name}\n")
        status = EXIT_INTERRUPTED if signum == signal.SIGINT else EXIT_FAILED
    for sig in _SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    sys.exit(status)
