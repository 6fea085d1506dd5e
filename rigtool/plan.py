"""Expand a protocol into a Plan: every step known before the run starts."""

from __future__ import annotations

import random
from collections.abc import Iterator
from dataclasses import asdict, dataclass

from rigtool.protocol import Protocol

DEPTH_MOVE_S = 10.0  # time budgeted per depth change in duration estimates
VOLTAGE_CHANGE_S = 2.0  # time budgeted per supply ramp in duration estimates
CAPTIVE_CHANGE_S = 5.0  # time budgeted per carriage speed or angle change in duration estimates


@dataclass(frozen=True)
class PlanStep:
    """One point of a sweep: command at a depth (and supply voltage), which repeat, which
    sweep direction."""

    idx: int
    command: float
    depth_m: float
    repeat: int
    direction: str  # "up", "down" or "random"
    voltage_v: float | None = None  # supply voltage; None when the protocol sets none
    speed_mps: float | None = None  # flow or tow speed of a captive run; None: no captive axis
    angle_deg: float | None = None  # its yaw or attack angle

    def as_dict(self) -> dict:
        """The stored form; optional axes only where set, so plans stored before them match."""
        out = asdict(self)
        for name in ("voltage_v", "speed_mps", "angle_deg"):
            if out[name] is None:
                del out[name]
        return out


def _command_sequence(protocol: Protocol, repeat: int) -> list[tuple[float, str]]:
    axis = protocol.command
    values = axis.command_values()
    if axis.steps is not None:
        return [(v, "down" if i and v < values[i - 1] else "up") for i, v in enumerate(values)]
    if axis.order == "up":
        return [(v, "up") for v in values]
    if axis.order == "down":
        return [(v, "down") for v in reversed(values)]
    if axis.order == "up-down":
        return [(v, "up") for v in values] + [(v, "down") for v in reversed(values)]
    shuffled = list(values)
    random.Random(axis.seed * 1_000_003 + repeat).shuffle(shuffled)
    return [(v, "random") for v in shuffled]


def _voltages(protocol: Protocol) -> list[float | None]:
    return protocol.voltage.voltages_v() if protocol.voltage is not None else [None]


def _flows(protocol: Protocol) -> list[tuple[float | None, float | None]]:
    """(speed, angle) settings of a captive run in the order visited; one (None, None) else."""
    return protocol.captive.settings() if protocol.captive is not None else [(None, None)]


Combo = tuple[float, float | None, tuple[float | None, float | None], int, float, str]


def _combos(protocol: Protocol) -> Iterator[Combo]:
    """(depth, voltage, flow, repeat, command, direction) in execution order. Depth outer
    (default): depth, then voltage, flow setting, repeat, command. Depth inner: voltage, flow
    setting, repeat, command, then depth."""
    depths = protocol.depth.depths_m()
    repeats = range(protocol.command.repeats)
    if protocol.depth.loop == "outer":
        for depth in depths:
            for volts in _voltages(protocol):
                for flow in _flows(protocol):
                    for rep in repeats:
                        for c, d in _command_sequence(protocol, rep):
                            yield depth, volts, flow, rep, c, d
    else:
        for volts in _voltages(protocol):
            for flow in _flows(protocol):
                for rep in repeats:
                    for c, d in _command_sequence(protocol, rep):
                        for depth in depths:
                            yield depth, volts, flow, rep, c, d


def expand(protocol: Protocol) -> list[PlanStep]:
    """All steps in execution order (at most MAX_POINTS: the protocol validator counts them)."""
    return [PlanStep(i, c, depth, rep, d, volts, *flow)
            for i, (depth, volts, flow, rep, c, d) in enumerate(_combos(protocol))]


def step_at(protocol: Protocol, idx: int) -> PlanStep:
    """Step `idx` of the plan, found arithmetically (for --dry-run: the plan is never built)."""
    n_depths, per_rep = len(protocol.depth.values), protocol.command.per_repeat()
    per_flow = protocol.command.repeats * per_rep
    per_volt = protocol.n_captive() * per_flow
    if protocol.depth.loop == "outer":
        i_depth, rest = divmod(idx, protocol.n_voltages() * per_volt)
        i_volt, rest = divmod(rest, per_volt)
        i_flow, rest = divmod(rest, per_flow)
        i_rep, i_cmd = divmod(rest, per_rep)
    else:
        i_volt, rest = divmod(idx, per_volt * n_depths)
        i_flow, rest = divmod(rest, per_flow * n_depths)
        i_rep, rest = divmod(rest, per_rep * n_depths)
        i_cmd, i_depth = divmod(rest, n_depths)
    command, direction = _command_sequence(protocol, i_rep)[i_cmd]
    return PlanStep(idx, command, protocol.depth.depths_m()[i_depth], i_rep, direction,
                    _voltages(protocol)[i_volt], *_flows(protocol)[i_flow])


def _voltage_changes(protocol: Protocol) -> int:
    """Supply voltage changes in the plan, the first setting included (0 without a voltage axis)."""
    if protocol.voltage is None:
        return 0
    n = protocol.n_voltages()
    if protocol.depth.loop == "outer":
        return len(protocol.depth.values) * n
    return n


def _depth_changes(protocol: Protocol) -> int:
    """Depth moves in the plan, the first one included."""
    depths = protocol.depth.depths_m()
    inside = sum(1 for a, b in zip(depths, depths[1:], strict=False) if a != b)
    if protocol.depth.loop == "outer":
        return 1 + inside
    cycles = (protocol.n_voltages() * protocol.n_captive() * protocol.command.repeats
              * protocol.command.per_repeat())
    return 1 + cycles * inside + (cycles - 1) * (depths[-1] != depths[0])


def estimate_duration_s(protocol: Protocol, neutral: float | None = None) -> float:
    """Upper-bound estimate of the run's duration from the timing block and slew limit.

    Counted arithmetically from the protocol, so even the largest plan is never built.
    """
    timing = protocol.timing
    n = protocol.n_points()
    total = timing.point_s() * n
    slew = protocol.limits.slew_per_s
    if slew and neutral is not None:
        visits = n // protocol.command.n_values()  # every command is visited this often
        total += visits * sum(2 * abs(v - neutral) for v in protocol.command.command_values()) / slew
    depth_changes = _depth_changes(protocol)
    total += depth_changes * DEPTH_MOVE_S
    if protocol.voltage is not None:
        total += _voltage_changes(protocol) * (protocol.voltage.settle_s + VOLTAGE_CHANGE_S)
    if protocol.captive is not None:
        changes = protocol.n_captive() * (protocol.n_voltages() if protocol.depth.loop == "inner"
                                          else len(protocol.depth.values) * protocol.n_voltages())
        total += changes * (protocol.captive.settle_s + CAPTIVE_CHANGE_S)
    if timing.tare == "per_point":
        total += timing.tare_s * n
    elif timing.tare == "per_depth":
        total += timing.tare_s * depth_changes
    elif timing.tare == "at_start":
        total += timing.tare_s
    return total


# a sensor this close to the protocol's rate (or a multiple of it) is taken to run at exactly
# that rate: a rate measured from arrival times jitters by about 1 %
RATE_MATCH_FRAC = 0.02
MIN_POINT_SAMPLES = 10  # fewer samples per point at the sensor's rate: refused
MIN_WINDOW_SAMPLES = 2  # fewer samples per settling window at the sensor's rate: refused


class TimingRefused(ValueError):
    """The sensor's rate cannot meet the protocol's timing; `field` is the protocol field."""

    def __init__(self, field: tuple[str, ...], message: str) -> None:
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class SensorTiming:
    """The acquisition a sweep actually makes with its sensor (docs/protocols.md, "Sensor rate").

    `how`: "as planned" (the sensor samples at the protocol's rate, within RATE_MATCH_FRAC),
    "decimated" (a sensor at an integer multiple of it, within RATE_MATCH_FRAC: each
    `decimate` samples are averaged into one stored sample),
    or "duration" (any other rate: the protocol's acquisition time at the sensor's rate).
    """

    protocol_rate_hz: float
    sensor_rate_hz: float  # the sensor's real rate; every duration is counted in it, and
    # the stored rate is it / decimate: what is stored is what was acquired
    decimate: int  # sensor samples per stored sample
    n_read: int  # sensor samples read per point
    how: str

    @property
    def stored_rate_hz(self) -> float:
        """The rate of the stored samples (each point's `rate_hz`)."""
        return self.sensor_rate_hz / self.decimate

    @property
    def n_stored(self) -> int:
        return self.n_read // self.decimate

    @property
    def acquire_s(self) -> float:
        return self.n_read / self.sensor_rate_hz

    def describe(self) -> str:
        """One line for --dry-run and the run's events."""
        plan = (f"{self.n_stored} samples at {self.stored_rate_hz:g} Hz "
                f"({self.n_stored / self.stored_rate_hz:g} s) per point")
        if self.how == "as planned":
            return plan if self.sensor_rate_hz == self.protocol_rate_hz else (
                f"{plan}: the sensor's rate, within {RATE_MATCH_FRAC:.0%} of the protocol's "
                f"{self.protocol_rate_hz:g} Hz")
        if self.how == "decimated":
            return (f"{plan}: the sensor's {self.sensor_rate_hz:g} Hz averaged {self.decimate} "
                    "to 1")
        return (f"{plan}: the protocol's {self.protocol_rate_hz:g} Hz is not the sensor's, "
                "so the protocol's duration is acquired at the sensor's rate")


def sensor_timing(protocol: Protocol, sensor_rate_hz: float | None) -> SensorTiming:
    """How a point is acquired from a sensor at `sensor_rate_hz` (None: it samples at the rate
    asked, like the twin); TimingRefused when that rate cannot meet the protocol."""
    acquire = protocol.timing.acquire
    proto, n = acquire.rate_hz, acquire.n_samples
    if sensor_rate_hz is None:
        return SensorTiming(proto, proto, 1, n, "as planned")
    if abs(sensor_rate_hz / proto - 1) <= RATE_MATCH_FRAC:  # the protocol's count, its rate
        return SensorTiming(proto, sensor_rate_hz, 1, n, "as planned")
    ratio = sensor_rate_hz / proto
    k = round(ratio)
    if k >= 2 and abs(ratio / k - 1) <= RATE_MATCH_FRAC:
        return SensorTiming(proto, sensor_rate_hz, k, n * k, "decimated")
    n_read = max(1, round(n / proto * sensor_rate_hz))
    if n_read < MIN_POINT_SAMPLES:
        raise TimingRefused(("timing", "acquire", "rate_hz"), (
            f"the rig's sensor streams at {sensor_rate_hz:g} Hz: the protocol's "
            f"{n / proto:g} s acquisition gives only {n_read} sample(s) per point (at least "
            f"{MIN_POINT_SAMPLES}); acquire longer, or use a faster sensor"))
    steady = protocol.timing.settle.until_steady
    if steady is not None and steady.window_s * sensor_rate_hz < MIN_WINDOW_SAMPLES:
        raise TimingRefused(("timing", "settle", "until_steady", "window_s"), (
            f"the rig's sensor streams at {sensor_rate_hz:g} Hz: a {steady.window_s:g} s "
            f"settling window holds fewer than {MIN_WINDOW_SAMPLES} samples"))
    return SensorTiming(proto, sensor_rate_hz, 1, n_read, "duration")
