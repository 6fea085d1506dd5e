"""Signals that stop a command: `Stopped`, and the process-wide handler of the `rigtool` command
that raises it until the command's run has ended, and after that only notes the signal.

A handler may run in the middle of anything, a print or an import included: it writes with
os.write (never through the console the main code may be inside), and it records the signal,
so that an import it broke (which then fails with some other error) still ends as that stop.
"""

from __future__ import annotations

import os
import signal

from rigtool.errors import EXIT_FAILED, EXIT_INTERRUPTED

_ended = False  # the run or the command has ended: its exit status is settled
_requested: int | None = None  # the first signal that stopped the command


class Stopped(KeyboardInterrupt):
    """A signal stopped the command outside a run (opening devices): SIGINT exits 130, others
    1, as a run stopped by them does."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def ending(signum: int) -> tuple[str, int]:
    """The line a command stopped by `signum` prints, and its exit status: Ctrl-C 130, the
    others 1 (docs/cli.md)."""
    if signum == signal.SIGINT:
        return "rigtool: interrupted", EXIT_INTERRUPTED
    return f"rigtool: stopped by {signal.Signals(signum).name}", EXIT_FAILED


def mark_ended() -> None:
    """The run (or the command) has ended, the actuator sent to neutral: later signals no
    longer stop it."""
    global _ended
    _ended = True


def requested() -> int | None:
    """The signal that stopped the command, if one did."""
    return _requested


def note_closing(signum: int) -> None:
    """Say, safely from a signal handler, that a signal came after the run (or the command)
    ended."""
    os.write(2, f"rigtool: {signal.Signals(signum).name} while closing: the run has ended; "
                "finishing\n".encode())


def stop(signum: int) -> None:
    """Record the signal and raise `Stopped`."""
    global _requested
    if _requested is None:
        _requested = signum
    raise Stopped(signum)


def on_signal(signum: int, frame: object) -> None:
    """Raise `Stopped`, or once the run has ended, say that the signal changes nothing."""
    if _ended:
        note_closing(signum)
        return
    stop(signum)
