"""What the CAN actuator drivers share: opening a python-can bus, its threads, feedback
buffering, and the actuator life cycle (`CanActuator`).

A `CanLink` owns one python-can bus, a receive thread that hands every frame (stamped
with `time.monotonic()` on receipt) to the driver's decoder, and an optional keep-alive
thread that re-sends the command in force so the motor controller's command timeout
never fires while the rig wants the motor running. `FeedbackBuffer` turns the decoded
values into the FeedbackBlock the engine reads.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from rigtool.devices.base import ActuatorInfo, Device, FeedbackBlock
from rigtool.errors import DeviceError

if TYPE_CHECKING:  # the drivers import them when they open a bus
    import can

log = logging.getLogger(__name__)

FEEDBACK_FIELDS = ("speed_rpm", "current_a", "voltage_v")
_RECV_POLL_S = 0.05  # receive thread wakes this often to notice close()
_SEND_TIMEOUT_S = 0.1  # wait this long for room in the interface's transmit queue
# Counter names a frame handler may return; each received frame bumps exactly one of them.
FRAME_COUNTERS = ("frames", "garbage", "ignored")


def check_keepalive(keepalive_s: float, command_timeout_s: float, drive: str) -> float:
    """`keepalive_s` if it re-sends the command at least twice per drive command timeout
    (0: the drive has none); else ValueError saying what to set. Validates rig files."""
    if command_timeout_s <= 0 or 0 < keepalive_s <= command_timeout_s / 2:
        return keepalive_s
    limit = f"at most half of command_timeout_s ({command_timeout_s / 2:g} s)"
    if keepalive_s == 0:
        raise ValueError(f"0 turns the keep-alive off, but the {drive} stops the motor "
                         f"{command_timeout_s:g} s after the last command (command_timeout_s); "
                         f"set keepalive_s {limit}, or command_timeout_s: 0 if the {drive} has "
                         "no command timeout")
    raise ValueError(f"{keepalive_s:g} s is too slow for the {drive}'s command timeout of "
                     f"{command_timeout_s:g} s (command_timeout_s); set keepalive_s {limit}")


def bus_name(interface: str, channel: str) -> str:
    """How a bus is named in messages: interface and channel, e.g. `socketcan:can0`."""
    return f"{interface}:{channel}"


def open_bus(interface: str, channel: str, bitrate: int | None = None) -> can.BusABC:
    """Open a python-can bus (or rigtool's loopback-only `udp_loopback`, see udp_loopback.py);
    any failure becomes a DeviceError naming interface and channel."""
    import can

    from rigtool.devices import udp_loopback
    kwargs = {} if bitrate is None else {"bitrate": bitrate}
    try:
        if interface == udp_loopback.INTERFACE:
            return udp_loopback.UdpLoopbackBus(channel, **kwargs)
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except Exception as exc:  # noqa: BLE001 - backends raise anything from ImportError to OSError
        raise DeviceError(
            f"cannot open CAN bus interface={interface!r} channel={channel!r}: {exc}"
        ) from exc


class CanLink:
    """A python-can bus with a receive thread and an optional keep-alive thread.

    The keep-alive re-sends the last command frame (`command`), so a drive with a command
    timeout keeps its setpoint, and stops when the host dies.

    `on_frame(msg, t)` runs on the receive thread for every frame that is not an error
    frame and returns the name of the counter to bump ("frames", "garbage", "ignored").
    """

    def __init__(
        self,
        interface: str,
        channel: str,
        bitrate: int | None,
        on_frame: Callable[[can.Message, float], str],
        device: str,
    ) -> None:
        self.device = device
        self.where = bus_name(interface, channel)
        self.stats = dict.fromkeys((*FRAME_COUNTERS, "error_frames", "sent", "send_errors"), 0)
        self.rx_error: Exception | None = None  # last failure of the receive side, if any
        self._bus = open_bus(interface, channel, bitrate)
        self._on_frame = on_frame
        self._send_lock = threading.Lock()
        self._frame_lock = threading.Lock()
        self._frame: can.Message | None = None  # what the keep-alive re-sends
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._closed = False

    def start(self, keepalive_s: float, frame: can.Message,
              extra: Callable[[], None] | None = None) -> None:
        """Start receiving; every `keepalive_s` (0: never) re-send the command frame (first
        `frame`, then the last one given to `command`) and call `extra` (e.g. a fault poll)."""
        with self._frame_lock:
            self._frame = frame
        self._spawn(self._rx_loop, "rx")
        if keepalive_s > 0:
            self._spawn(lambda: self._keepalive_loop(keepalive_s, extra), "keepalive")

    def command(self, msg: can.Message, *, retry: bool = False) -> None:
        """Send a command frame and make it the one the keep-alive repeats (`retry`: for
        neutral, see send_retrying)."""
        with self._frame_lock:
            self._frame = msg
        (self.send_retrying if retry else self.send)(msg)

    def send(self, msg: can.Message) -> None:
        """Transmit one frame; a failure is counted and raised as DeviceError naming the bus."""
        import can
        try:
            with self._send_lock:
                self._bus.send(msg, timeout=_SEND_TIMEOUT_S)
        except (can.CanError, OSError, ValueError) as exc:
            self.stats["send_errors"] += 1
            raise DeviceError(f"{self.device}: cannot send on {self.where}: {exc}") from exc
        self.stats["sent"] += 1

    def send_retrying(self, msg: can.Message, attempts: int = 3) -> None:
        """Send, retrying briefly on failure (for neutral); raise only if every attempt failed."""
        error: DeviceError | None = None
        for attempt in range(attempts):
            try:
                self.send(msg)
                return
            except DeviceError as exc:
                log.warning("%s (attempt %d of %d)", exc, attempt + 1, attempts)
                error = exc
            time.sleep(0.01)
        raise error

    def stop_threads(self) -> None:
        """Stop receiving and keeping alive; the bus stays open for final sends."""
        self._stop.set()
        current = threading.current_thread()
        for thread in self._threads:
            if thread is not current:
                thread.join(timeout=1.0)

    def close(self) -> None:
        """Stop the threads and release the bus. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self.stop_threads()
        try:
            self._bus.shutdown()
        except Exception as exc:  # noqa: BLE001 - releasing a broken bus must not mask the cause
            log.warning("%s: closing %s failed: %s", self.device, self.where, exc)

    def _spawn(self, target: Callable[[], None], role: str) -> None:
        thread = threading.Thread(target=target, name=f"rigtool-{self.device}-{role}", daemon=True)
        self._threads.append(thread)
        thread.start()

    def _rx_loop(self) -> None:
        import can
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=_RECV_POLL_S)
            except (can.CanError, OSError, ValueError) as exc:
                self.rx_error = exc
                self._stop.wait(_RECV_POLL_S)
                continue
            if msg is None:
                continue
            t = time.monotonic()
            if msg.is_error_frame:
                self.stats["error_frames"] += 1
                continue
            try:
                counter = self._on_frame(msg, t)
            except Exception as exc:  # noqa: BLE001 - a frame must never kill the reader
                log.debug("%s: undecodable frame %s: %s", self.device, msg, exc)
                counter = "garbage"
            self.stats[counter] += 1

    def _keepalive_loop(self, period_s: float, extra: Callable[[], None] | None) -> None:
        while not self._stop.wait(period_s):
            try:
                with self._frame_lock:
                    frame = self._frame
                if frame is not None:
                    self.send(frame)
                if extra is not None:
                    extra()
            except DeviceError as exc:
                log.warning("%s", exc)


class FeedbackBuffer:
    """Latest decoded feedback values, and the samples taken from them since the last read.

    A sample holds every field in `fields`; none is recorded until each has been received
    once, so a block never starts with half-known samples.
    """

    def __init__(self, fields: tuple[str, ...] = FEEDBACK_FIELDS) -> None:
        self.fields = fields
        self._lock = threading.Lock()
        self._latest = dict.fromkeys(FEEDBACK_FIELDS, float("nan"))
        self._t: list[float] = []
        self._rows: list[tuple[float, ...]] = []
        self.last_t: float | None = None  # receive time of the latest sample

    def update(self, **values: float) -> None:
        """Remember new values of some feedback fields (not yet a sample)."""
        with self._lock:
            self._latest.update(values)

    def sample(self, t: float, **values: float) -> None:
        """Update fields, then record one sample at receive time `t` (once all are known)."""
        with self._lock:
            self._latest.update(values)
            row = tuple(self._latest[k] for k in self.fields)
            if any(math.isnan(x) for x in row):
                return
            self._t.append(t)
            self._rows.append(row)
            self.last_t = t

    def take(self) -> FeedbackBlock:
        """The samples since the previous call; fields not in `fields` are None."""
        with self._lock:
            t, rows = self._t, self._rows
            self._t, self._rows = [], []
        values = np.array(rows, dtype=float).reshape(len(rows), len(self.fields))
        columns = {k: values[:, self.fields.index(k)] if k in self.fields else None
                   for k in FEEDBACK_FIELDS}  # fmt: skip
        return FeedbackBlock(np.array(t, dtype=float), **columns)


class CanActuator(Device):
    """What the CAN actuators share: a CanLink with its keep-alive, the command / neutral /
    close life cycle, silence detection and the wait for the first frame.

    A driver sets `name`, `info` and `config` (with interface, channel, bitrate, keepalive_s
    and timeout_s), calls `_open_link`, and supplies `_command_frame(value)`,
    `_neutral_frame()` and `_on_frame(msg, t)`. `close` (Device) sends neutral, then calls
    `_before_release` between stopping the link's threads and releasing the bus (e.g. to
    disable the drive).
    """

    name: str
    info: ActuatorInfo
    config: Any

    def _open_link(self, keepalive_frame: can.Message,
                   extra: Callable[[], None] | None = None) -> None:
        c = self.config
        self._closed = False
        self._link = CanLink(c.interface, c.channel, c.bitrate, self._on_frame, self.name)
        self.stats = self._link.stats
        self._opened_t = time.monotonic()
        self._link.start(c.keepalive_s, keepalive_frame, extra)

    def _command_frame(self, value: float) -> can.Message:
        raise NotImplementedError

    def _neutral_frame(self) -> can.Message:
        raise NotImplementedError

    def _on_frame(self, msg: can.Message, t: float) -> str:
        raise NotImplementedError

    def set_command(self, value: float) -> None:
        """Command `value` in info.command_unit (clipped to the command range)."""
        if self._closed:
            raise DeviceError(f"{self.name} on {self._link.where}: driver is closed")
        if not math.isfinite(value):
            raise ValueError(f"command must be finite, got {value!r}")
        self._link.command(self._command_frame(value))

    def neutral(self) -> None:
        """Send the neutral command (retried); idempotent, quiet after close."""
        if self._closed:
            return
        self._link.command(self._neutral_frame(), retry=True)

    def _safe_state(self) -> None:
        """Neutral before `close` releases the bus; a failure is logged, not raised."""
        try:
            self.neutral()
        except DeviceError as exc:
            log.warning("%s: could not command neutral on close: %s", self.name, exc)

    def _release(self) -> None:
        """Stop the keep-alive and the receiver, last sends, release the bus."""
        self._link.stop_threads()
        self._before_release()
        self._link.close()

    def _before_release(self) -> None:
        """Last sends before the bus is released (nothing by default)."""

    def _silent_for(self, last_t: float | None) -> bool:
        """True when nothing arrived for longer than the timeout (never after close)."""
        last = last_t or self._opened_t
        return not self._closed and time.monotonic() - last > self.config.timeout_s

    def _wait_for_first(self, received: Callable[[], bool], hint: str) -> None:
        """Block until `received()` or the timeout after opening; DeviceError naming `hint`."""
        deadline = self._opened_t + self.config.timeout_s
        while not received():
            if time.monotonic() > deadline:
                raise DeviceError(self._silence(
                    f"within {self.config.timeout_s:g} s of opening ({hint})"))
            time.sleep(0.01)

    def _silence(self, how: str) -> str:
        raise NotImplementedError
