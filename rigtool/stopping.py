"""Signals that stop a command: `Stopped`, and the process-wide handler of the `rigtool` command
that raises it until the command's run has ended, and after that only notes the signal."""

from __future__ import annotations

import signal
import sys

_ended = False  # a sweep of this process has ended: its exit status is settled


class Stopped(KeyboardInterrupt):
    """A signal stopped the command outside a run (opening devices): SIGINT exits 130, others
    1, as a run stopped by them does."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def mark_ended() -> None:
    """The run has ended (the actuator sent to neutral): later signals no longer stop it."""
    global _ended
    _ended = True


def on_signal(signum: int, frame: object) -> None:
    """Raise `Stopped`, or once the run has ended, say that the signal changes nothing."""
    if _ended:
        sys.stderr.write(f"rigtool: {signal.Signals(signum).name} while closing: the run has "
                         "ended; finishing\n")
        return
    raise Stopped(signum)
