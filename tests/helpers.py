"""Small helpers shared by the tests over real transports: polling, and `rigtool sim` run as
its own process."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import can

SIM_START_S = 120.0  # a `rigtool sim` starting up (imports, sockets) on a loaded machine: a
# wait for it to be ready, not a measurement (seconds at load 20 on two cores)


def wait_for(predicate, timeout_s: float = 3.0, poll_s: float = 0.02) -> bool:
    """Poll `predicate` until it holds or `timeout_s` passes."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


def drain(bus: can.BusABC, seconds: float = 0.0) -> list[can.Message]:
    """Every frame a recording bus has seen (waiting `seconds` for more)."""
    out, deadline = [], time.monotonic() + seconds
    while True:
        msg = bus.recv(timeout=max(0.0, deadline - time.monotonic()))
        if msg is None:
            return out
        out.append(msg)


def stop_process(proc: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGTERM, then SIGKILL if it has not exited within `timeout_s`: no test leaves a child
    running (an orphan `rigtool sim` keeps its sockets, and the pipes of whatever started the
    suite, open). Returns the exit status; a kill is an AssertionError after the cleanup."""
    if proc.poll() is None:
        proc.terminate()
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"{proc.args[:4]} did not stop within {timeout_s} s of SIGTERM") from None


def stop_processes(*procs: subprocess.Popen | None) -> None:
    """stop_process on each (None: never started), every one of them even when an earlier
    one had to be killed; then the first such failure is raised."""
    failures = []
    for proc in procs:
        if proc is not None:
            try:
                stop_process(proc)
            except AssertionError as exc:
                failures.append(exc)
    if failures:
        raise failures[0]


@contextmanager
def sim_process(rig: Path, profile: str, *extra: str,
                stdout: int = subprocess.PIPE) -> Iterator[subprocess.Popen]:
    """`rigtool sim --profile PROFILE --netft 127.0.0.1:0 --rig-out RIG EXTRA` as a process,
    yielded once it has written its rig file, and always stopped after (stop_process)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "rigtool.cli", "sim", "--profile", profile, "--netft",
         "127.0.0.1:0", "--rig-out", str(rig), *extra],
        stdout=stdout, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + SIM_START_S
        while not rig.exists():
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, "rigtool sim did not write its rig file"
            time.sleep(0.05)
        yield proc
    finally:
        stop_process(proc)
