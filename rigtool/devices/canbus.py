"""What the CAN actuator drivers share: the bus fields of their rig-file sections, opening a
python-can bus, its threads, feedback buffering, and the actuator life cycle (`CanActuator`).

A section that leaves `interface:` or `channel:` out, or names a `context:`, takes what it
leaves out from python-can's own configuration (can.util.load_config: the CAN_INTERFACE /
CAN_CHANNEL / CAN_BITRATE / CAN_CONFIG variables, with a `_<context>` suffix first, then the
`[<context>]` and `[default]` sections of ~/can.conf, /etc/can.conf, ~/.can, ~/.canrc); a
section that names both is the whole truth and python-can's configuration is not read.
`bus_args:` are passed to python-can's Bus as they are (fd, data_bitrate, can_filters...).

A `CanLink` owns one python-can bus, a receive thread that hands every frame (stamped
with `time.monotonic()` on receipt) to the driver's decoder, and an optional keep-alive
thread that re-sends the command in force so the motor controller's command timeout
never fires while the rig wants the motor running. `FeedbackBuffer` turns the decoded
values into the FeedbackBlock the engine reads.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Union

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictInt,
    field_validator,
    model_validator,
)

from rigtool.bounds import Baudrate, Scale
from rigtool.config import FieldError
from rigtool.devices.base import ActuatorInfo, Device, FeedbackBlock
from rigtool.errors import DeviceError, UsageError
from rigtool.files import MAX_CONFIG_BYTES, read_regular_bytes

if TYPE_CHECKING:  # the drivers import them when they open a bus
    import can

log = logging.getLogger(__name__)

FEEDBACK_FIELDS = ("speed_rpm", "current_a", "voltage_v")
_RECV_POLL_S = 0.05  # receive thread wakes this often to notice close()
_SEND_TIMEOUT_S = 0.1  # wait this long for room in the interface's transmit queue
# Counter names a frame handler may return; each received frame bumps exactly one of them.
FRAME_COUNTERS = ("frames", "garbage", "ignored")


DEFAULT_INTERFACE = "socketcan"  # when neither the rig file nor python-can's config names one
CanId = Annotated[int, Field(ge=0, le=0x1FFFFFFF)]
# bus arguments are single values: a backend takes flags, numbers and names
BusValue = Union[StrictBool, Annotated[StrictInt, Field(ge=-(2**63), le=2**64)],  # noqa: UP007
                 Scale, Annotated[str, Field(max_length=256)]]
# what the section's own fields say; a bus argument may not say it again
_OWN_FIELDS = ("interface", "channel", "bitrate", "context", "config_context", "bustype",
               "ignore_config")


class CanFilter(BaseModel):
    """One receive filter: a frame passes when `id & can_mask == can_id & can_mask`."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    can_id: CanId
    can_mask: CanId
    extended: StrictBool | None = None  # only frames of this id length (None: either)

    @model_validator(mode="after")
    def _fits_standard_ids(self) -> CanFilter:
        if self.extended is False:
            for name in ("can_id", "can_mask"):
                if getattr(self, name) > 0x7FF:
                    raise FieldError((name,), f"{name} 0x{getattr(self, name):X} does not fit "
                                     "the 11 bits of a standard id (extended: false): "
                                     "at most 0x7FF")
        return self


class BusArgs(BaseModel):
    """Extra keyword arguments for python-can's Bus; the common ones typed, any other a
    single value (the backend's own, e.g. `poll_interval`, `app_name`)."""

    model_config = ConfigDict(extra="allow", frozen=True, allow_inf_nan=False)
    __pydantic_extra__: dict[str, BusValue] = Field(init=False)
    fd: StrictBool | None = None  # CAN FD frames
    data_bitrate: Baudrate | None = None  # the FD data phase's bit rate
    can_filters: list[CanFilter] | None = Field(None, max_length=256)
    receive_own_messages: StrictBool | None = None

    @model_validator(mode="after")
    def _names(self) -> BusArgs:
        for key in self.__pydantic_extra__ or {}:
            if key in _OWN_FIELDS:
                raise FieldError((key,), f"{key!r} is a field of the section itself, not a "
                                 "bus argument")
            if not key.isidentifier() or len(key) > 64:
                raise FieldError((key,), f"{key[:64]!r} is not an argument name")
        return self

    def kwargs(self) -> dict[str, Any]:
        """The arguments as python-can takes them (unset ones left out)."""
        return self.model_dump(exclude_none=True)


class CanBusFields(BaseModel):
    """The bus fields of a CAN driver's rig-file section (vesc-can, dbc-can)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    # python-can: socketcan, slcan, pcan, virtual...; left out: python-can's config, else socketcan
    interface: str | None = Field(None, min_length=1, max_length=64)
    # python-can channel: can0, /dev/ttyACM0, a virtual bus name; left out: python-can's config
    channel: str | None = Field(None, min_length=1, max_length=256)
    bitrate: Baudrate | None = 500000  # bit/s (VESC default); null: the interface's own
    # a python-can config section / environment suffix (CAN_CHANNEL_<context>) to read
    context: str | None = Field(None, pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    bus_args: BusArgs = BusArgs()  # passed to python-can's Bus: fd, data_bitrate, can_filters...

    @field_validator("interface")
    @classmethod
    def _known_interface(cls, name: str | None) -> str | None:
        """An interface python-can has (or rigtool's own UDP loopback bus)."""
        from can.interfaces import VALID_INTERFACES

        from rigtool.devices import udp_loopback

        if name is not None and name not in VALID_INTERFACES | {udp_loopback.INTERFACE}:
            raise ValueError(f"unknown CAN interface {name[:64]!r}; python-can has "
                             f"{', '.join(sorted(VALID_INTERFACES))} (and rigtool "
                             f"{udp_loopback.INTERFACE})")
        return name


@dataclass(frozen=True)
class BusSettings:
    """A bus as it will be opened: interface, channel and the other Bus arguments."""

    interface: str
    channel: str | int  # python-can's config turns a channel of digits into a number
    kwargs: dict[str, Any]
    from_config: bool  # python-can's configuration was read


def bus_settings(config: CanBusFields) -> BusSettings:
    """The bus a rig-file section means, python-can's configuration filling what it leaves
    out (see the module docstring). A configuration python-can refuses, or no channel
    anywhere, is a UsageError."""
    from rigtool.devices import udp_loopback

    given: dict[str, Any] = {k: getattr(config, k) for k in ("interface", "channel")
                             if getattr(config, k) is not None}
    if "bitrate" in config.model_fields_set and config.bitrate is not None:
        given["bitrate"] = config.bitrate
    given.update(config.bus_args.kwargs())
    from_config = (config.interface is None or config.channel is None
                   or config.context is not None) and config.interface != udp_loopback.INTERFACE
    resolved = _python_can_config(given, config.context) if from_config else dict(given)
    if resolved.get("interface") is None:
        resolved["interface"] = DEFAULT_INTERFACE
    if "bitrate" not in config.model_fields_set and config.bitrate is not None:
        resolved.setdefault("bitrate", config.bitrate)
    elif config.bitrate is None:
        resolved.pop("bitrate", None)
    interface, channel = resolved.pop("interface"), resolved.pop("channel", None)
    if channel is None:
        where = f"CAN_CHANNEL_{config.context} or " if config.context else ""
        raise UsageError(f"no CAN channel for interface {interface!r}: give `channel:` in the "
                         f"rig file, or set {where}CAN_CHANNEL or `channel =` in a python-can "
                         "config file (~/can.conf, /etc/can.conf, ~/.can, ~/.canrc)")
    return BusSettings(str(interface), channel, resolved, from_config)


def _python_can_config(given: dict[str, Any], context: str | None) -> dict[str, Any]:
    """python-can's own merge of `given` over its environment and config files, each value
    it supplies checked with the types of the rig-file fields (a UsageError naming where the
    value came from)."""
    import configparser

    import can

    _check_config_files()
    try:
        sources = _config_sources(context)
        typed = _typed_config(given, sources)
        if "interface" not in given and "interface" not in typed:
            given = {**given, "interface": DEFAULT_INTERFACE}
        resolved = dict(can.util.load_config(config=given, context=context))
    except (can.CanError, ValueError, TypeError, configparser.Error) as exc:
        ctx = f" (context {context!r})" if context else ""
        raise UsageError(f"python-can configuration{ctx} refused: {exc}") from None
    resolved.update(typed)
    return resolved


def _check_config_files() -> None:
    """Refuse (UnreadableFile, exit 2) a python-can config file that is there but is not a
    regular file of at most MAX_CONFIG_BYTES, before python-can's configparser reads it:
    a ~/.canrc linked to /dev/zero would be read forever, and one linked to /proc/self/pagemap
    (a regular file of size 0 to stat) without bound: the file is read, at most the cap."""
    import can

    for name in can.util.CONFIG_FILES:
        path = os.path.expanduser(name)
        if os.path.exists(path):  # follows links; python-can skips what is not there too
            # Read, not only stat: a /proc file is "regular" with size 0 yet reads without end.
            read_regular_bytes(path, MAX_CONFIG_BYTES)


def _config_sources(context: str | None) -> list[tuple[str, dict[str, Any]]]:
    """python-can's configuration sources in its own order, each named for messages: can.rc,
    the CAN_* variables (with the context's suffix first), the config files' sections."""
    import can

    files = ", ".join(can.util.CONFIG_FILES)
    suffixes = ([f"_{context}"] if context else []) + [""]
    sections = ([context] if context else []) + ["default"]
    return ([("can.rc", dict(can.rc))]
            + [item for suffix in suffixes for item in _environment(suffix)]
            + [(f"section [{section}] of python-can's config files ({files})",
                can.util.load_file_config(None, section)) for section in sections])


def _environment(suffix: str) -> list[tuple[str, dict[str, Any]]]:
    """The CAN_CONFIG<suffix> object and the CAN_INTERFACE/CHANNEL/BITRATE<suffix> variables
    (which win over it, as in python-can)."""
    name = f"CAN_CONFIG{suffix}"
    text = os.environ.get(name)
    found: list[tuple[str, dict[str, Any]]] = []
    for key in ("interface", "channel", "bitrate"):
        value = os.environ.get(f"CAN_{key.upper()}{suffix}")
        if value:
            found.append((f"environment variable CAN_{key.upper()}{suffix}", {key: value}))
    if text is not None:
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise UsageError(f"environment variable {name} is not JSON ({exc})") from None
        if not isinstance(data, dict):
            raise UsageError(f"environment variable {name} must be a JSON object of Bus "
                             f"arguments, not {type(data).__name__} {text[:80]!r}")
        found.append((f"environment variable {name}", data))
    return found


def _typed_config(given: dict[str, Any], sources: list[tuple[str, dict[str, Any]]]
                  ) -> dict[str, Any]:
    """The values python-can's configuration supplies for what `given` leaves out (the first
    source naming a key wins), checked and typed as the rig file's fields are."""
    typed: dict[str, Any] = {}
    seen = set(given)
    for where, values in sources:
        for key, value in values.items():
            name = "interface" if key == "bustype" else key
            if name in seen:
                continue
            seen.add(name)
            typed[name] = _typed_value(name, value, where)
    typed.pop("channel", None)  # python-can's own reading of a channel is kept (digits: int)
    return typed


def _typed_value(key: str, value: Any, where: str) -> Any:
    """One configured value as the rig-file field `key` types it; UsageError naming `where`."""
    from can.util import cast_from_string
    from pydantic import ValidationError

    original = value
    if isinstance(value, str):
        if key in _BOOL_KEYS:
            value = _BOOL_WORDS.get(value.strip().lower(), value)
        elif key in _INT_KEYS:
            value = int(value) if re.fullmatch(r"[0-9]{1,12}", value.strip()) else value
        elif key not in ("interface", "channel"):
            value = cast_from_string(value)
    if key == "channel" and type(value) is int:
        value = str(value)
    model = CanBusFields if key in ("interface", "channel", "bitrate") else BusArgs
    try:
        checked = model.model_validate({key: value})
    except ValidationError as exc:
        problem = "; ".join(e["msg"] for e in exc.errors())
        raise UsageError(f"python-can configuration: {where} gives {key} = {original!r}: "
                         f"{problem}") from None
    return checked.model_dump(exclude_none=True).get(key, value)


_BOOL_KEYS = ("fd", "receive_own_messages")
_INT_KEYS = ("bitrate", "data_bitrate")
_BOOL_WORDS = {"1": True, "yes": True, "true": True, "on": True,
               "0": False, "no": False, "false": False, "off": False}


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


def bus_name(interface: str, channel: str | int) -> str:
    """How a bus is named in messages: interface and channel, e.g. `socketcan:can0`."""
    return f"{interface}:{channel}"


def open_bus(interface: str, channel: str | int, bitrate: int | None = None,
             **bus_args: Any) -> can.BusABC:
    """Open a python-can bus with exactly these arguments (python-can's configuration is not
    read here: see bus_settings), or rigtool's loopback-only `udp_loopback`
    (udp_loopback.py); any failure becomes a DeviceError naming interface and channel."""
    import can

    from rigtool.devices import udp_loopback
    kwargs = bus_args if bitrate is None else {**bus_args, "bitrate": bitrate}
    try:
        if interface == udp_loopback.INTERFACE:
            return udp_loopback.UdpLoopbackBus(channel, **kwargs)
        return can.Bus(interface=interface, channel=channel, ignore_config=True, **kwargs)
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
        settings: BusSettings,
        on_frame: Callable[[can.Message, float], str],
        device: str,
    ) -> None:
        self.device = device
        self.where = bus_name(settings.interface, settings.channel)
        self.stats = dict.fromkeys((*FRAME_COUNTERS, "error_frames", "sent", "send_errors"), 0)
        self.rx_error: Exception | None = None  # last failure of the receive side, if any
        self._bus = open_bus(settings.interface, settings.channel, **settings.kwargs)
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

    A driver sets `name`, `info` and `config` (CanBusFields with keepalive_s and timeout_s),
    calls `_open_link`, and supplies `_command_frame(value)`, `_neutral_frame()` and
    `_on_frame(msg, t)`. `close` (Device) sends neutral, then calls `_before_release` between
    stopping the link's threads and releasing the bus (e.g. to disable the drive).
    """

    name: str
    info: ActuatorInfo
    config: Any

    def _open_link(self, keepalive_frame: can.Message,
                   extra: Callable[[], None] | None = None) -> None:
        c = self.config
        self._closed = False
        self._link = CanLink(bus_settings(c), self._on_frame, self.name)
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
