"""Any CAN motor driver described by a DBC file: which signal takes the command, which report back.

The DBC (read with cantools) gives frame layouts; the rig file maps rigtool's actuator
onto them: the command signal and its unit, feedback signals for speed, current and
voltage, an optional fault signal, run-state signal and enable signal. Frame ids in the DBC are offset by
`node_id << node_id_shift` (CANopen style: id + node; ODrive: node << 5 | command). Without a
`dbc:` the shipped servo_driver.dbc and its mapping servo_driver.yaml describe a
speed/current servo like the pool rig's; `mapping: NAME` picks another shipped mapping
(rigtool/dbc/NAME.yaml, which names its DBC), e.g. odrive_velocity. Rig sections given
explicitly replace the shipped ones. A keep-alive thread re-sends the command in force
for drives with a command watchdog.
"""

from __future__ import annotations

import functools
import logging
import math
import re
import time
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictInt,
    ValidationInfo,
    field_validator,
    model_validator,
)

from rigtool.bounds import Command, PositiveSeconds, Scale, Seconds
from rigtool.devices.base import ActuatorInfo, FeedbackBlock
from rigtool.devices.canbus import (
    FEEDBACK_FIELDS,
    CanActuator,
    CanBusFields,
    FeedbackBuffer,
    check_keepalive,
)
from rigtool.errors import DeviceError, UsageError
from rigtool.files import MAX_DBC_BYTES, UnreadableFile, read_regular_bytes
from rigtool.units import COMMAND_UNITS

if TYPE_CHECKING:  # the drivers import them when they open a bus
    import can
    import cantools

log = logging.getLogger(__name__)

DBC_DIR = Path(__file__).resolve().parent.parent / "dbc"  # shipped DBC files and mappings
SHIPPED_DBC = DBC_DIR / "servo_driver.dbc"
SHIPPED_MAPPING = SHIPPED_DBC.with_suffix(".yaml")
SHIPPED_WATCHDOG_S = 0.5  # the shipped servo stops this long after its last SERVO_CONTROL
_SECTIONS = ("command", "feedback", "fault", "run_state", "enable")
# what a shipped mapping may give besides the sections (`dbc`: a file name in DBC_DIR)
_MAPPING_FIELDS = ("dbc", "node_id_shift", "command_timeout_s", *_SECTIONS)
_MAPPING_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
STANDARD_ID_MAX = 0x7FF
EXTENDED_ID_MAX = 0x1FFFFFFF


def shipped_mappings() -> list[str]:
    """Names of the mappings shipped in rigtool/dbc/ (for `mapping:`)."""
    return sorted(p.stem for p in DBC_DIR.glob("*.yaml"))


@functools.lru_cache(maxsize=8)
def shipped_mapping(name: str) -> dict:
    """The shipped mapping NAME (rigtool/dbc/NAME.yaml), its `dbc` made a path; ValueError
    listing the shipped mappings when there is no such one."""
    path = DBC_DIR / f"{name}.yaml"
    if not _MAPPING_NAME.fullmatch(name) or not path.is_file():
        raise ValueError(f"no shipped mapping {name!r} (shipped: {', '.join(shipped_mappings())})")
    data = yaml.safe_load(path.read_text())
    mapping = {k: data[k] for k in _MAPPING_FIELDS if k in data}
    if "dbc" in mapping:
        mapping["dbc"] = str(DBC_DIR / mapping["dbc"])
    return mapping


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class SignalRef(_Strict):
    """A DBC signal read as a feedback value: value = signal x scale."""

    message: str = Field(min_length=1)  # DBC message name
    signal: str = Field(min_length=1)  # DBC signal name (physical value, DBC scaling applied)
    scale: Scale = 1.0  # e.g. 0.2 for motor r/min behind a 5:1 gearbox


class CommandRef(_Strict):
    """The DBC signal that carries the command: signal = command x scale."""

    message: str = Field(min_length=1)  # DBC message name
    signal: str = Field(min_length=1)  # DBC signal name
    unit: Literal[COMMAND_UNITS] = "percent"  # command unit the engine works in
    scale: Scale = 1.0  # signal units per command unit, e.g. 18 for percent -> r/min
    min: Command | None = None  # command limits (command unit); default: DBC range / scale
    max: Command | None = None

    @model_validator(mode="after")
    def _nonzero(self) -> CommandRef:
        if self.scale == 0:
            raise ValueError("scale must not be 0")
        return self


class FeedbackMap(_Strict):
    """Which signals carry feedback; the speed_rpm message (else the first given) paces samples."""

    speed_rpm: SignalRef | None = None
    current_a: SignalRef | None = None
    voltage_v: SignalRef | None = None


class FaultRef(_Strict):
    """A status signal whose value other than `ok` means the drive is in fault."""

    message: str = Field(min_length=1)
    signal: str = Field(min_length=1)
    ok: Scale = 0.0


class RunStateRef(_Strict):
    """A status signal that must read `ok` while the driver runs the drive (e.g. ODrive's
    Axis_State = 8, CLOSED_LOOP_CONTROL): once it has, any other value is a fault."""

    message: str = Field(min_length=1)
    signal: str = Field(min_length=1)
    ok: Scale


class DbcMismatch(UsageError):
    """The rig's mapping disagrees with its DBC; `loc` is the actuator field concerned, so
    load_rig can name the rig file's line."""

    def __init__(self, loc: tuple[str, ...], message: str) -> None:
        super().__init__(message)
        self.loc = loc


class EnableRef(_Strict):
    """A signal written once after opening and once when closing (power stage on/off)."""

    message: str = Field(min_length=1)
    signal: str = Field(min_length=1)
    on_start: Scale = 1.0
    on_close: Scale = 0.0


class DbcCanConfig(_Strict, CanBusFields):
    """Rig-file section for a DBC-described CAN motor driver (`driver: dbc-can`); the bus
    fields (interface, channel, bitrate, context, bus_args) are CanBusFields'."""

    driver: Literal["dbc-can"]
    dbc: str | None = None  # path to the .dbc; null: shipped servo_driver.dbc + servo_driver.yaml
    mapping: str | None = None  # a shipped mapping (rigtool/dbc/NAME.yaml) filling what is left out
    node_id: StrictInt = Field(1, ge=0, le=0x1FFFFFFF)  # frame ids: DBC id + (node_id << shift)
    node_id_shift: int | None = Field(None, ge=0, le=28)  # null: the mapping's, else 0
    command: CommandRef | None = None  # required with your own dbc
    feedback: FeedbackMap | None = None  # none: the actuator reports no feedback
    fault: FaultRef | None = None
    run_state: RunStateRef | None = None
    enable: EnableRef | None = None
    neutral: Command = 0.0  # safe command, in command.unit
    # the drive's command watchdog; null: SHIPPED_WATCHDOG_S with the shipped DBC, else none
    command_timeout_s: Seconds | None = None
    keepalive_s: Seconds = Field(0.1, validate_default=True)  # re-send period; 0 = off
    timeout_s: PositiveSeconds = 1.0  # no valid frame of a listened message this long -> DeviceError

    @field_validator("mapping")
    @classmethod
    def _shipped(cls, value: str | None) -> str | None:
        if value is not None:
            shipped_mapping(value)
        return value

    @field_validator("keepalive_s")
    @classmethod
    def _keeps_alive(cls, value: float, info: ValidationInfo) -> float:
        timeout = info.data.get("command_timeout_s")
        mapping = info.data.get("mapping")
        if timeout is None and mapping is not None:
            timeout = shipped_mapping(mapping).get("command_timeout_s", 0.0)
        if timeout is None:
            timeout = SHIPPED_WATCHDOG_S if info.data.get("dbc") is None else 0.0
        return check_keepalive(value, timeout, "drive")

    @model_validator(mode="after")
    def _has_command(self) -> DbcCanConfig:
        if self.dbc is not None and self.command is None:
            raise ValueError("with your own `dbc`, give `command: {message, signal, unit}`")
        return self


def resolve(config: DbcCanConfig) -> DbcCanConfig:
    """The config with a shipped mapping in what it leaves out: the one `mapping` names, else
    servo_driver's sections when no `dbc` is given."""
    if config.mapping is not None:
        shipped = shipped_mapping(config.mapping)
    elif config.dbc is None:
        shipped = {k: v for k, v in yaml.safe_load(SHIPPED_MAPPING.read_text()).items()
                   if k in _SECTIONS}  # fmt: skip
    else:
        return config
    missing = {k: v for k, v in shipped.items() if getattr(config, k) is None}
    return DbcCanConfig.model_validate({**config.model_dump(exclude_unset=True), **missing})


def load_dbc(path: Path) -> cantools.database.can.Database:
    """Read a DBC file; a missing or invalid file is a UsageError naming it."""
    import cantools
    try:
        text = read_regular_bytes(path, MAX_DBC_BYTES).decode("cp1252", errors="replace")
    except UnreadableFile as exc:
        raise UsageError(f"dbc-can: DBC file {path}: {exc.problem}") from None
    try:  # cp1252 is cantools' own default for DBC files
        return cantools.database.load_string(text, database_format="dbc")
    except Exception as exc:  # noqa: BLE001 - cantools raises parser-specific errors
        # the parser quotes the offending text: name only where it is, never echo the file
        at = re.search(r"line (\d+), column (\d+)", str(exc))
        where = f" (syntax error at line {at[1]}, column {at[2]})" if at else ""
        raise UsageError(f"dbc-can: {path} is not a DBC file cantools can read{where}") from None


def _default(signal) -> float:
    """Value for a signal the mapping does not set: its initial value, else 0 within its range."""
    if signal.initial is not None:
        return signal.initial
    lo = signal.minimum if signal.minimum is not None else -math.inf
    hi = signal.maximum if signal.maximum is not None else math.inf
    return min(max(0.0, lo), hi)


def encode_signal(message, name: str, value: float) -> bytes:
    """Payload of `message` with signal `name` = `value` (clipped to its DBC range).

    Multiplexer signals are set to select `name`; every other signal gets its default.
    """
    signal = message.get_signal_by_name(name)
    data = {s.name: _default(s) for s in message.signals if s.is_multiplexer}
    if signal.multiplexer_signal is not None:
        data[signal.multiplexer_signal] = signal.multiplexer_ids[0]
    for s in message.signals:
        if s.is_multiplexer:
            continue
        if s.multiplexer_signal is None or data.get(s.multiplexer_signal) in s.multiplexer_ids:
            data[s.name] = _default(s)
    lo = signal.minimum if signal.minimum is not None else -math.inf
    hi = signal.maximum if signal.maximum is not None else math.inf
    data[name] = min(max(value, lo), hi)
    return message.encode(data, scaling=True, strict=True)


def signal_message(db: cantools.database.can.Database, path: Path,
                   ref: SignalRef | CommandRef | FaultRef | EnableRef, where: str):
    """The DBC message `ref` names, checking that it has `ref.signal`."""
    try:
        message = db.get_message_by_name(ref.message)
    except KeyError:
        known = ", ".join(m.name for m in db.messages)
        raise UsageError(f"dbc-can {where}: no message {ref.message!r} in {path} "
                         f"(messages: {known})") from None  # fmt: skip
    names = [s.name for s in message.signals]
    if ref.signal not in names:
        raise UsageError(f"dbc-can {where}: message {ref.message} has no signal "
                         f"{ref.signal!r} (signals: {', '.join(names)})")  # fmt: skip
    return message


def command_range(config: DbcCanConfig, message) -> tuple[float, float]:
    """The command range: the rig file's, else the command signal's in the DBC. A rig range
    beyond the signal's is refused: the frame would silently carry the clipped value."""
    cmd = config.command
    signal = message.get_signal_by_name(cmd.signal)
    ends = [x / cmd.scale for x in (signal.minimum, signal.maximum) if x is not None]
    for key in ("min", "max"):
        value = getattr(cmd, key)
        if value is not None and len(ends) == 2 and not min(ends) <= value <= max(ends):
            raise DbcMismatch(("command", key), f"{value:g} {cmd.unit} is beyond the range of "
                              f"{message.name}.{cmd.signal} in the DBC: [{min(ends):g}, "
                              f"{max(ends):g}] {cmd.unit} (signal range [{signal.minimum:g}, "
                              f"{signal.maximum:g}] / scale {cmd.scale:g})")
    lo = cmd.min if cmd.min is not None else (min(ends) if len(ends) == 2 else None)
    hi = cmd.max if cmd.max is not None else (max(ends) if len(ends) == 2 else None)
    if lo is None or hi is None:
        raise UsageError(f"dbc-can command: signal {cmd.signal} has no range in the DBC; "
                         "give command.min and command.max")  # fmt: skip
    if not lo <= config.neutral <= hi:
        raise UsageError(f"dbc-can: neutral {config.neutral:g} outside the command "
                         f"range [{lo:g}, {hi:g}]")  # fmt: skip
    return lo, hi


def mapped_refs(config: DbcCanConfig) -> list[tuple[tuple[str, ...], SignalRef | CommandRef |
                                                     FaultRef | RunStateRef | EnableRef]]:
    """Every signal the (resolved) config names, with the field that names it."""
    fb = config.feedback or FeedbackMap()
    refs = [(("command",), config.command)]
    refs += [(("feedback", k), getattr(fb, k)) for k in FEEDBACK_FIELDS if getattr(fb, k)]
    refs += [((k,), getattr(config, k)) for k in ("fault", "run_state", "enable")
             if getattr(config, k) is not None]
    return refs


def frame_id(config: DbcCanConfig, message, loc: tuple[str, ...] = ("node_id",)) -> int:
    """The message's id on the bus: its DBC id + (node_id << node_id_shift). Under a shift
    the DBC id must be node 0's (no node bits set, else another node would be driven) and
    the result must fit the frame's id bits; DbcMismatch otherwise."""
    shift = config.node_id_shift or 0
    if shift and message.frame_id >> shift:
        raise DbcMismatch((*loc, "message"), f"{message.name} has DBC id {message.frame_id:#x}, "
                          f"which already holds node {message.frame_id >> shift} (id >> "
                          f"node_id_shift {shift}); name node 0's message (id < "
                          f"{1 << shift:#x}) and give the node in node_id")
    bits = 29 if message.is_extended_frame else 11
    top = EXTENDED_ID_MAX if message.is_extended_frame else STANDARD_ID_MAX
    frame = message.frame_id + (config.node_id << shift)
    if frame > top:
        most = (top - message.frame_id) >> shift
        raise DbcMismatch(("node_id",), f"node_id {config.node_id} puts {message.name} at frame "
                          f"id {frame:#x}, beyond the {bits}-bit range (node_id 0..{most} with "
                          f"node_id_shift {shift})")
    return frame


def check_mapping(config: DbcCanConfig, db, path: Path) -> ActuatorInfo:
    """Check the resolved config against its DBC (messages, signals, frame ids, command
    range) and return the command space the engine sees."""
    for loc, ref in mapped_refs(config):
        frame_id(config, signal_message(db, path, ref, ".".join(loc)), loc)
    fb = config.feedback or FeedbackMap()
    fields = tuple(k for k in FEEDBACK_FIELDS if getattr(fb, k) is not None)
    lo, hi = command_range(config, signal_message(db, path, config.command, "command"))
    return ActuatorInfo(config.command.unit, config.neutral, lo, hi, fields)


def actuator_info(config: DbcCanConfig) -> ActuatorInfo:
    """The command space the engine sees, from the rig file and its DBC (no bus opened)."""
    c = resolve(config)
    path = Path(c.dbc) if c.dbc is not None else SHIPPED_DBC
    return check_mapping(c, load_dbc(path), path)


class DbcCanDriver(CanActuator):
    """Actuator on a DBC-described CAN drive."""

    info_for = staticmethod(actuator_info)  # the command space from a config alone (registry)

    def __init__(self, config: DbcCanConfig) -> None:
        self.config = c = resolve(config)
        self.dbc_path = Path(c.dbc) if c.dbc is not None else SHIPPED_DBC
        self.db = load_dbc(self.dbc_path)
        self.name = f"{self.dbc_path.stem} node {c.node_id}"
        self.info = check_mapping(c, self.db, self.dbc_path)
        self._cmd_msg = self._signal_message(c.command, "command")
        fb = c.feedback or FeedbackMap()
        self._fields = tuple(k for k in FEEDBACK_FIELDS if getattr(fb, k) is not None)
        self._rx_messages: dict[int, object] = {}  # frame id -> DBC message we listen to
        self._rx: dict[int, dict[str, SignalRef]] = {}  # frame id -> {feedback field: signal}
        for k in self._fields:
            ref = getattr(fb, k)
            frame_id = self._listen(self._signal_message(ref, f"feedback.{k}"))
            self._rx[frame_id][k] = ref
        self._pace = next(iter(self._rx), None)  # the first feedback field's message
        self._fault_id = None
        if c.fault is not None:
            fault_msg = self._signal_message(c.fault, "fault")
            self._fault_id = self._listen(fault_msg)
            self._fault_signal = fault_msg.get_signal_by_name(c.fault.signal)
        self._state_id = None
        if c.run_state is not None:
            state_msg = self._signal_message(c.run_state, "run_state")
            self._state_id = self._listen(state_msg)
            self._state_signal = state_msg.get_signal_by_name(c.run_state.signal)
        self._enable_msg = self._signal_message(c.enable, "enable") if c.enable else None
        self._used = {i: {ref.signal for ref in refs.values()} for i, refs in self._rx.items()}
        for frame_id, ref in ((self._fault_id, c.fault), (self._state_id, c.run_state)):
            if frame_id is not None:
                self._used[frame_id].add(ref.signal)  # the signals this driver reads, per frame
        self._feedback = FeedbackBuffer(self._fields)
        self._fault: str | None = None
        self._state_fault: str | None = None
        self._state: float | None = None  # the run-state signal's latest value
        self._running = False  # the run state has read `ok` since opening
        self._last_rx: dict[int, float] = {}  # frame id -> receive time of its last valid frame
        self._bad: dict[int, str] = {}  # frame id -> its last non-finite value, e.g. "Vel=nan"
        self._open_link(self._neutral_frame())
        try:
            self.neutral()
            if self._enable_msg is not None:
                self._send_signal(self._enable_msg, c.enable.signal, c.enable.on_start)
            if self._rx:
                self._wait_for_first(lambda: bool(self._last_rx),
                                     "is it powered, on this bus and bitrate, with the right "
                                     "node_id?")
            if self._state_id is not None:
                self._wait_for_run_state()
        except BaseException:
            self._link.close()
            raise

    # ----- Actuator (set_command, neutral, close: CanActuator) -----

    def expected_speed_rpm(self, command: float) -> float | None:
        """A command in r/min is the speed the drive holds; other units: unknown."""
        if self.info.command_unit != "rpm":
            return None
        return min(max(command, self.info.command_min), self.info.command_max)

    def read_feedback(self) -> FeedbackBlock:
        """Feedback samples since the last call; DeviceError on a reported fault or on silence."""
        if self.fault is not None:
            raise DeviceError(f"{self.name} on {self._link.where} reports fault {self.fault}")
        for frame_id in self._rx:
            if self._silent_for(self._last_rx.get(frame_id)):
                bad = self._bad.get(frame_id)
                how = f"for {self.config.timeout_s:g} s" + (
                    f" (only non-finite values, e.g. {bad}, counted as garbage)" if bad else "")
                raise DeviceError(self._silence(how, [self._rx_messages[frame_id].name]))
        return self._feedback.take()

    def _before_release(self) -> None:
        """Disable the drive (if configured) once neutral is sent and the keep-alive stopped."""
        if self._enable_msg is not None:
            try:
                self._send_signal(self._enable_msg, self.config.enable.signal,
                                  self.config.enable.on_close)  # fmt: skip
            except DeviceError as exc:
                log.warning("%s: could not disable on close: %s", self.name, exc)

    @property
    def fault(self) -> str | None:
        """The fault the drive reports, or its run state gone wrong (None: healthy)."""
        return self._fault or self._state_fault

    # ----- internals -----

    def _signal_message(self, ref: SignalRef | CommandRef | FaultRef | EnableRef, where: str):
        return signal_message(self.db, self.dbc_path, ref, where)

    def _frame_id(self, message) -> int:
        """The message's id on the bus (see frame_id)."""
        return frame_id(self.config, message)

    def _listen(self, message) -> int:
        """Register `message` as one we receive; return its frame id on the bus."""
        frame_id = self._frame_id(message)
        self._rx_messages[frame_id] = message
        self._rx.setdefault(frame_id, {})
        return frame_id

    def _neutral_frame(self) -> can.Message:
        return self._command_frame(self.config.neutral)

    def _command_frame(self, value: float) -> can.Message:
        cmd = self.config.command
        v = min(max(value, self.info.command_min), self.info.command_max)
        data = encode_signal(self._cmd_msg, cmd.signal, v * cmd.scale)
        return self._frame_for(self._cmd_msg, data)

    def _frame_for(self, message, data: bytes) -> can.Message:
        import can
        return can.Message(arbitration_id=self._frame_id(message), data=data,
                           is_extended_id=message.is_extended_frame)  # fmt: skip

    def _send_signal(self, message, signal: str, value: float) -> None:
        self._link.send(self._frame_for(message, encode_signal(message, signal, value)))

    def _on_frame(self, msg: can.Message, t: float) -> str:
        """Decode one received frame; return the stats counter it belongs to."""
        import cantools
        fields = self._rx.get(msg.arbitration_id)
        if fields is None or msg.is_remote_frame:
            return "ignored"
        message = self._rx_messages[msg.arbitration_id]
        if msg.is_extended_id != message.is_extended_frame:
            return "ignored"
        try:
            decoded = message.decode(bytes(msg.data), decode_choices=False, scaling=True)
        except (cantools.database.DecodeError, ValueError, KeyError):
            return "garbage"
        used = self._used[msg.arbitration_id]
        bad = next((f"{k}={float(decoded[k])}" for k in used
                    if k in decoded and not math.isfinite(float(decoded[k]))), None)  # fmt: skip
        if bad is not None:  # a NaN must never stand in for a reading: the frame is garbage
            self._bad[msg.arbitration_id] = bad
            return "garbage"
        self._last_rx[msg.arbitration_id] = t
        values = {k: float(decoded[ref.signal]) * ref.scale
                  for k, ref in fields.items() if ref.signal in decoded}  # fmt: skip
        if msg.arbitration_id == self._pace:
            self._feedback.sample(t, **values)
        elif values:
            self._feedback.update(**values)
        if msg.arbitration_id == self._fault_id and self.config.fault.signal in decoded:
            self._check_fault(decoded[self.config.fault.signal])
        if msg.arbitration_id == self._state_id and self.config.run_state.signal in decoded:
            self._check_state(float(decoded[self.config.run_state.signal]))
        return "frames"

    def _check_fault(self, value: float) -> None:
        if value == self.config.fault.ok:
            self._fault = None
            return
        choices = self._fault_signal.choices or {}
        label = choices.get(int(value)) if float(value).is_integer() else None
        self._fault = f"{self.config.fault.signal}={value:g}" + (f" ({label})" if label else "")

    def _check_state(self, value: float) -> None:
        """Arm once the run state reads `ok`; from then on any other value is a fault."""
        self._state = value
        if value == self.config.run_state.ok:
            self._running = True
        elif self._running and self._state_fault is None:
            self._state_fault = (f"{self._label(self._state_signal, value)}, expected "
                                 f"{self._label(self._state_signal, self.config.run_state.ok)}")

    def _wait_for_run_state(self) -> None:
        """Block until the run state reads `ok` (the enable took effect), within timeout_s of
        opening; DeviceError saying what it read instead."""
        deadline = self._opened_t + self.config.timeout_s
        while not self._running:
            if time.monotonic() > deadline:
                seen = "nothing" if self._state is None else self._label(self._state_signal,
                                                                        self._state)
                ok = self._label(self._state_signal, self.config.run_state.ok)
                raise DeviceError(f"{self.name} on {self._link.where} did not reach {ok} within "
                                  f"{self.config.timeout_s:g} s of opening (read {seen})")
            time.sleep(0.01)

    @staticmethod
    def _label(signal, value: float) -> str:
        """`Signal=value (LABEL)` from the DBC's value table."""
        choices = signal.choices or {}
        label = choices.get(int(value)) if float(value).is_integer() else None
        return f"{signal.name}={value:g}" + (f" ({label})" if label else "")

    def _silence(self, how: str, names: list[str] | None = None) -> str:
        names = names or sorted({m.name for m in self._rx_messages.values()})
        rx = f"; receive error: {self._link.rx_error}" if self._link.rx_error else ""
        return f"no {'/'.join(names)} frames from {self.name} on {self._link.where} {how}{rx}"
