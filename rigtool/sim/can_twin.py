"""What the simulated CAN drives share: a python-can bus, receive/transmit threads, faults."""

from __future__ import annotations

import contextlib
import threading

import can

from rigtool.devices.canbus import open_bus
from rigtool.sim.live import LiveTwin


class CanBusTwin:
    """Base of the CAN drive twins: subclasses implement `_rx_loop` and `_tx_loop`."""

    thread_name = "can-twin"

    def __init__(self, live: LiveTwin, channel: str, interface: str, bitrate: int | None) -> None:
        self.live = live
        self.profile = live.twin.profile
        self.interface = interface
        self.channel = channel
        self.bitrate = bitrate
        self.silent = False  # fault switch: transmit nothing
        self.garbage = False  # fault switch: add truncated and error frames
        self.deaf = False  # fault switch: hear nothing (commands stop arriving; its timeout acts)
        self._fault_code = 0
        self._bus: can.BusABC | None = None
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    @property
    def fault_code(self) -> int:
        return self._fault_code

    @fault_code.setter
    def fault_code(self, code: int) -> None:
        """Set a fault code (0 clears it); a fault stops the motor at once."""
        self._fault_code = int(code)
        if code:
            self.live.set_command(self.profile.neutral)

    def start(self):  # noqa: ANN201 - returns the subclass instance
        self._bus = open_bus(self.interface, self.channel, self.bitrate)
        for target, role in ((self._rx_loop, "rx"), (self._tx_loop, "status")):
            thread = threading.Thread(target=target, name=f"{self.thread_name}-{role}", daemon=True)
            self._threads.append(thread)
            thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=1.0)
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def _rx_loop(self) -> None:
        raise NotImplementedError

    def _tx_loop(self) -> None:
        raise NotImplementedError

    def _send_frame(self, arbitration_id: int, data: bytes, *, extended: bool,
                    error: bool = False) -> bool:
        """Transmit one frame unless silenced; bus errors are ignored like a real drive's."""
        if self.silent or self._bus is None:
            return False
        msg = can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=extended,
                          is_error_frame=error)
        with self._send_lock, contextlib.suppress(can.CanError):
            self._bus.send(msg)
        return True
