"""Signals around a command: a stop outside a run, and the quiet close after a run ended."""

from __future__ import annotations

import contextlib
import signal

from rigtool.stopping import mark_ended, note_closing, stop


@contextlib.contextmanager
def closing_signals(reporter: object):
    """Around a sweep: a signal before the run starts stops the command (devices closed); once
    the run has ended (the actuator sent to neutral), a further signal while the rig closes and
    the outcome prints is only noted, so the exit status stays the run's (and, under the
    `rigtool` command, until the process has exited: rigtool.launch)."""
    def _on_signal(signum: int, frame: object) -> None:
        if getattr(reporter, "finished", False):
            note_closing(signum)
            return
        stop(signum)

    sigs = [s for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
            if signal.getsignal(s) is not signal.SIG_IGN]
    old = {sig: signal.signal(sig, _on_signal) for sig in sigs}
    try:
        yield
    finally:
        if getattr(reporter, "finished", False):
            mark_ended()
        for sig, handler in old.items():
            signal.signal(sig, handler)


@contextlib.contextmanager
def stop_on_signals():
    """Turn SIGTERM/SIGHUP into KeyboardInterrupt (`Stopped`, which names the signal, so the
    command exits 1 as for a sweep, not Ctrl-C's 130) so `finally` blocks (neutral) still run."""
    def _raise(signum, frame):
        stop(signum)

    old = {sig: signal.signal(sig, _raise) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
