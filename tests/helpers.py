"""Small polling helpers shared by the driver tests over real transports."""

from __future__ import annotations

import time

import can


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
