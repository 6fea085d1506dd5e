"""The protocol file: what to sweep and how to measure each point.

Validated strictly by pydantic: unknown fields are errors, so a typo can never
silently change an experiment. Units are explicit in the file and converted to SI here.
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)

from rigtool.bounds import (
    MAX_CAPTIVE_SETTINGS,
    MAX_COMMAND,
    MAX_COMMAND_VALUES,
    MAX_CURRENT_A,
    MAX_DEBOUNCE_SAMPLES,
    MAX_DEPTH_M,
    MAX_DURATION_S,
    MAX_FLOW_MPS,
    MAX_POINTS,
    MAX_POWER_W,
    MAX_RATE_HZ,
    MAX_RUN_S,
    MAX_SAMPLES_PER_POINT,
    MAX_SCALE,
    MAX_SPEED_RPM,
    MAX_SUPPLY_V,
    MAX_TEMPERATURE_C,
    MAX_THRUST_N,
    MAX_TORQUE_NM,
    MAX_VOLTAGES,
    MIN_RATE_HZ,
    MIN_WINDOW_S,
    Command,
    PositiveSeconds,
    Scale,
    Seconds,
    Seed,
)
from rigtool.config import FieldError, load_model
from rigtool.errors import UsageError
from rigtool.ids import folder_problem, label_problem
from rigtool.thruster_profiles import PROFILES, profile_with_overrides
from rigtool.units import COMMAND_UNITS

CommandUnit = Literal["percent", "pwm_counts", "pulse_us", "rpm", "amps"]
assert set(CommandUnit.__args__) == set(COMMAND_UNITS)  # type: ignore[attr-defined]

DEPTH_TO_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
RateHz = Annotated[float, Field(ge=MIN_RATE_HZ, le=MAX_RATE_HZ, allow_inf_nan=False)]


def _label(text: str) -> str:
    """A name or id that ends up in generated files: every character visible."""
    problem = label_problem(text)
    if problem:
        raise ValueError(problem)
    return text


Label = Annotated[str, AfterValidator(_label)]


def _thruster_id(text: str) -> str:
    """A thruster id the lab dataset can file its runs under (a partition folder name)."""
    problem = folder_problem("thruster_id", text)
    if problem:
        raise ValueError(f"{problem}, so `rigtool export --all` could not file this run")
    return text


ThrusterId = Annotated[Label, AfterValidator(_thruster_id)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class CommandRange(_Strict):
    """Evenly spaced commands from start to stop inclusive."""

    start: Command
    stop: Command
    step: Annotated[float, Field(gt=0, le=2 * MAX_COMMAND, allow_inf_nan=False)]

    @model_validator(mode="after")
    def _ordered(self) -> CommandRange:
        if self.stop < self.start:
            raise ValueError(f"stop ({self.stop}) must not be below start ({self.start}); "
                             "use order: down to sweep downwards")
        if (self.stop - self.start) / self.step >= MAX_COMMAND_VALUES:
            raise FieldError(("step",), f"more than {MAX_COMMAND_VALUES:,} commands: check "
                                        "start/stop/step")
        return self

    def count(self) -> int:
        """How many values `values()` gives, without building them."""
        n = int(round((self.stop - self.start) / self.step + 1e-9)) + 1
        return n - (round(self.start + (n - 1) * self.step, 9) > self.stop + 1e-9)

    def values(self) -> list[float]:
        vals = [round(self.start + i * self.step, 9) for i in range(self.count())]
        return [v for v in vals if v <= self.stop + 1e-9]


class CommandAxis(_Strict):
    """The swept command: unit, values (list or range), order and repeats."""

    unit: CommandUnit
    values: list[Command] | None = Field(default=None, min_length=1, max_length=MAX_COMMAND_VALUES)
    range: CommandRange | None = None
    # Step responses: levels visited as listed, each a step from the one before (no neutral
    # in between), acquired from the step on (docs/dynamics.md).
    steps: list[Command] | None = Field(default=None, min_length=2, max_length=MAX_COMMAND_VALUES)
    order: Literal["up", "down", "up-down", "random"] = "up"
    repeats: Annotated[int, Field(ge=1, le=MAX_POINTS)] = 1
    seed: Seed = 0

    @model_validator(mode="after")
    def _one_source(self) -> CommandAxis:
        if sum(x is not None for x in (self.values, self.range, self.steps)) != 1:
            raise ValueError("give exactly one of `values` (a list), `range` (start/stop/step) "
                             "or `steps` (levels for step responses)")
        if self.steps is not None and "order" in self.model_fields_set:
            raise FieldError(("order",), "`steps` are visited as listed; leave `order` out")
        return self

    def command_values(self) -> list[float]:
        if self.steps is not None:
            return list(self.steps)
        return sorted(self.values) if self.values is not None else self.range.values()  # type: ignore[union-attr]

    def n_values(self) -> int:
        """Distinct positions in one pass (duplicates in `values` count), without building them."""
        if self.steps is not None:
            return len(self.steps)
        return len(self.values) if self.values is not None else self.range.count()  # type: ignore[union-attr]

    def per_repeat(self) -> int:
        """Points in one repeat of the command sequence (up-down visits every value twice)."""
        return self.n_values() * (2 if self.order == "up-down" else 1)


class DepthAxis(_Strict):
    """Immersion depths of the propeller centre below the surface."""

    unit: Literal["m", "cm", "mm"]
    values: list[Annotated[float, Field(ge=0, le=MAX_DEPTH_M * 1000, allow_inf_nan=False)]] = Field(
        min_length=1, max_length=MAX_POINTS)
    mode: Literal["preset", "manual", "stage"] = "preset"
    loop: Literal["outer", "inner"] = "outer"

    @model_validator(mode="after")
    def _in_reach(self) -> DepthAxis:
        deepest = max(self.values) * DEPTH_TO_M[self.unit]
        if deepest > MAX_DEPTH_M:
            raise FieldError(("values",), f"depth {deepest:g} m is beyond {MAX_DEPTH_M:g} m")
        return self

    def depths_m(self) -> list[float]:
        return [round(v * DEPTH_TO_M[self.unit], 9) for v in self.values]


class VoltageAxis(_Strict):
    """Supply voltages to sweep, each set before its points: by the rig's programmable supply
    (`preset`) or by the operator, who confirms each one (`manual`)."""

    unit: Literal["V"]
    values: list[Annotated[float, Field(gt=0, le=MAX_SUPPLY_V, allow_inf_nan=False)]] = Field(
        min_length=1, max_length=MAX_VOLTAGES)
    order: Literal["up", "down", "random"] = "up"
    mode: Literal["preset", "manual"] = "preset"
    settle_s: Seconds = 1.0  # wait at neutral after a voltage change
    seed: Seed = 0
    # the measured bus voltage must stay within this fraction of the set one (at least 0.5 V)
    tolerance_frac: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.25

    def voltages_v(self) -> list[float]:
        """The voltages in the order they are visited."""
        values = sorted(self.values)
        if self.order == "down":
            return values[::-1]
        if self.order == "random":
            random.Random(self.seed).shuffle(values)
        return values


FlowSpeed = Annotated[float, Field(ge=-MAX_FLOW_MPS, le=MAX_FLOW_MPS, allow_inf_nan=False,
                                   strict=True)]
AngleDeg = Annotated[float, Field(ge=-180, le=180, allow_inf_nan=False, strict=True)]


class CaptiveAxis(_Strict):
    """A held vehicle in a flow or tow (docs/vehicle.md): the signed speeds set by the rig's
    carriage, at each of the angles (yaw or attack) its rotary stage sets; the actuator stays
    at each command of the command axis (usually its neutral: thrusters off)."""

    speeds_mps: list[FlowSpeed] = Field(min_length=1, max_length=MAX_CAPTIVE_SETTINGS)
    angles_deg: list[AngleDeg] = Field(default_factory=lambda: [0.0], min_length=1,
                                       max_length=MAX_CAPTIVE_SETTINGS)
    angle: Literal["yaw", "attack"] = "yaw"  # yaw: the flow turns in x-y; attack: in x-z
    mode: Literal["preset", "manual"] = "preset"  # preset: the rig's `carriage:` sets them
    settle_s: Seconds = 2.0  # wait after a speed or angle change, before the point settles

    @model_validator(mode="after")
    def _distinct(self) -> CaptiveAxis:
        for name in ("speeds_mps", "angles_deg"):
            values = getattr(self, name)
            if len(set(values)) != len(values):
                raise FieldError((name,), "a value is listed twice; use `command.repeats` "
                                          "to repeat the whole sequence")
        return self

    def n_settings(self) -> int:
        """Speed and angle settings in one pass."""
        return len(self.speeds_mps) * len(self.angles_deg)

    def settings(self) -> list[tuple[float, float]]:
        """(speed m/s, angle deg) in the order visited: angle outer, speeds as listed."""
        return [(u, a) for a in self.angles_deg for u in self.speeds_mps]


class SteadySettle(_Strict):
    """Settle until the thrust mean of two consecutive windows differs by < tolerance."""

    window_s: Annotated[float, Field(ge=MIN_WINDOW_S, le=MAX_DURATION_S,
                                     allow_inf_nan=False)] = 0.5
    tolerance_n: Annotated[float, Field(gt=0, le=MAX_THRUST_N, allow_inf_nan=False)] = 0.1
    min_s: Seconds = 0.0
    timeout_s: PositiveSeconds = 10.0


class Settle(_Strict):
    """Either a fixed wait or a settling criterion on thrust."""

    seconds: Seconds | None = None
    until_steady: SteadySettle | None = None

    @model_validator(mode="after")
    def _one(self) -> Settle:
        if (self.seconds is None) == (self.until_steady is None):
            raise ValueError("give exactly one of `seconds` or `until_steady`")
        return self

    def max_seconds(self) -> float:
        """Longest settle: the engine reads min_s, then windows until two agree or the time
        since the start reaches timeout_s (it always compares at least two windows)."""
        if self.seconds is not None:
            return self.seconds
        c = self.until_steady
        assert c is not None
        ratio = min((c.timeout_s - c.min_s) / c.window_s, 1e15)  # finite even if a bound slips
        loops = max(1, math.ceil(ratio - 1e-9) - 1)
        return c.min_s + c.window_s * (loops + 1)


class Acquire(_Strict):
    """How much to record per point: N samples or T seconds, at a rate."""

    rate_hz: RateHz
    samples: Annotated[int, Field(ge=1, le=MAX_SAMPLES_PER_POINT)] | None = None
    seconds: PositiveSeconds | None = None

    @model_validator(mode="after")
    def _one(self) -> Acquire:
        if (self.samples is None) == (self.seconds is None):
            raise ValueError("give exactly one of `samples` or `seconds`")
        if self.n_samples > MAX_SAMPLES_PER_POINT:
            raise FieldError(("seconds",), f"{self.seconds:g} s at {self.rate_hz:g} Hz is "
                                           f"{self.n_samples:,} samples per point; the limit is "
                                           f"{MAX_SAMPLES_PER_POINT:,}")
        return self

    @property
    def n_samples(self) -> int:
        return self.samples if self.samples is not None else max(1, round(self.seconds * self.rate_hz))  # type: ignore[operator]


class Timing(_Strict):
    """Per-point timing: settle, acquire, rest at neutral, and when to re-tare."""

    settle: Settle
    acquire: Acquire
    rest_s: Seconds = 0.0
    tare: Literal["never", "at_start", "per_depth", "per_point"] = "at_start"
    tare_s: PositiveSeconds = 1.0

    def point_s(self) -> float:
        """Longest time of one point at its command, and its rest: settle, acquire, rest."""
        return self.settle.max_seconds() + self.acquire.n_samples / self.acquire.rate_hz + self.rest_s


NEWER_LIMITS = ("min_bus_v", "max_bus_v", "max_power_w", "max_torque_nm", "torque_channel",
                "max_temperature_c")


class Limits(_Strict):
    """Safety limits checked on every sample block; a trip sends the actuator to neutral.

    Each limit counts its own readings for `debounce_samples`: force samples for thrust and
    torque, feedback frames for current, speed, bus voltage, power and temperature (and one
    reading of a measuring supply counts as one frame of the bus and power limits). Strict
    types: `true` is not a count and '70' is not a number."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)
    max_thrust_n: Annotated[float, Field(gt=0, le=MAX_THRUST_N, allow_inf_nan=False)] | None = None
    max_current_a: Annotated[float, Field(gt=0, le=MAX_CURRENT_A, allow_inf_nan=False)] | None = None
    max_speed_rpm: Annotated[float, Field(gt=0, le=MAX_SPEED_RPM, allow_inf_nan=False)] | None = None
    # bus voltage (actuator feedback and/or the supply's terminals); power = voltage x current
    min_bus_v: Annotated[float, Field(ge=0, le=MAX_SUPPLY_V, allow_inf_nan=False)] | None = None
    max_bus_v: Annotated[float, Field(gt=0, le=MAX_SUPPLY_V, allow_inf_nan=False)] | None = None
    max_power_w: Annotated[float, Field(gt=0, le=MAX_POWER_W, allow_inf_nan=False)] | None = None
    # torque about the thruster axis (tx for thrust on fx...), or the channel named
    max_torque_nm: Annotated[float, Field(gt=0, le=MAX_TORQUE_NM, allow_inf_nan=False)] | None = None
    torque_channel: Literal["axis", "tx", "ty", "tz"] = "axis"
    # an auxiliary temperature channel (gauge line, bridge telemetry or thermistor)
    max_temperature_c: Annotated[float, Field(gt=-273.15, le=MAX_TEMPERATURE_C,
                                              allow_inf_nan=False)] | None = None
    max_staleness_s: PositiveSeconds = 1.0
    slew_per_s: Annotated[float, Field(gt=0, le=MAX_SCALE, allow_inf_nan=False)] | None = None  # see Protocol
    debounce_samples: Annotated[int, Field(ge=1, le=MAX_DEBOUNCE_SAMPLES)] = 5
    on_trip: Literal["abort", "pause"] = "abort"  # pause: neutral, ask the operator, retry the point

    @model_serializer(mode="wrap")
    def _without_unset_new_limits(self, handler: SerializerFunctionWrapHandler) -> dict:
        """The limits added later are left out of the stored protocol while unset, so a run's
        stored protocol reads as it did before they existed."""
        data = handler(self)
        for name in NEWER_LIMITS:
            if data.get(name) == Limits.model_fields[name].default:
                del data[name]
        return data

    @model_validator(mode="after")
    def _bus_band(self) -> Limits:
        if self.min_bus_v is not None and self.max_bus_v is not None and \
                self.min_bus_v >= self.max_bus_v:
            raise FieldError(("min_bus_v",), f"min_bus_v ({self.min_bus_v:g} V) must be below "
                                             f"max_bus_v ({self.max_bus_v:g} V)")
        return self


def _drop_defaults(data: dict, model: type[BaseModel], names: tuple[str, ...]) -> dict:
    """`data` without the fields `names` that hold their default."""
    for name in names:
        if name in data and data[name] == model.model_fields[name].default:
            del data[name]
    return data


class Metadata(_Strict):
    """Stored with the run; diameter and density enable K_T in calibrations."""

    thruster_id: ThrusterId | None = None
    propeller: Label | None = None
    operator: Label | None = None
    notes: str | None = None
    propeller_diameter_m: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] | None = None
    water_density_kg_m3: Annotated[float, Field(gt=0, le=10_000, allow_inf_nan=False)] | None = None
    extra: dict[str, str] = Field(default_factory=dict)


class SimulatorSpec(_Strict):
    """Which simulator twin profile to run with `--sim`, its seed and parameter overrides."""

    profile: str
    seed: Seed = 1
    overrides: dict[str, Scale | str | list[Scale | str]] = Field(default_factory=dict)
    # the held vehicle of a captive run (rigtool/sim/vehicle_params.py) and the flow's
    # unsteadiness: the force fluctuates by this fraction of itself (docs/vehicle.md)
    vehicle: Literal["bluerov2", "bluerov2-heavy"] = "bluerov2"
    flow_noise_frac: Annotated[float, Field(ge=0, le=0.5, allow_inf_nan=False, strict=True)] = 0.03

    @model_serializer(mode="wrap")
    def _without_unset_vehicle(self, handler: SerializerFunctionWrapHandler) -> dict:
        """The captive twin's settings are left out of the stored spec while at their defaults,
        so a thruster run's stored protocol reads as it did before they existed."""
        return _drop_defaults(handler(self), SimulatorSpec, ("vehicle", "flow_noise_frac"))

    @field_validator("overrides")
    @classmethod
    def _known(cls, overrides: dict, info: ValidationInfo) -> dict:
        """Unknown parameters and bad values are file errors, found before any device opens."""
        profile = info.data.get("profile")
        if profile is not None:
            try:
                profile_with_overrides(profile, overrides)
            except UsageError as exc:
                raise ValueError(str(exc)) from None
        return overrides

    @field_validator("profile")
    @classmethod
    def _profile(cls, profile: str) -> str:
        if profile not in PROFILES:
            raise ValueError(f"unknown thruster profile {profile!r}; known: {', '.join(PROFILES)}")
        return profile


class Protocol(_Strict):
    """A whole sweep protocol file."""

    rigtool_protocol: Literal[1] = 1
    name: Label = Field(min_length=1)
    description: str = ""
    rig: str | None = None
    simulator: SimulatorSpec | None = None
    metadata: Metadata = Field(default_factory=Metadata)
    command: CommandAxis
    depth: DepthAxis
    voltage: VoltageAxis | None = None
    captive: CaptiveAxis | None = None
    timing: Timing
    limits: Limits = Field(default_factory=Limits)

    @model_serializer(mode="wrap")
    def _without_unset_captive(self, handler: SerializerFunctionWrapHandler) -> dict:
        """No `captive` in the stored protocol of a run without one (as before it existed)."""
        return _drop_defaults(handler(self), Protocol, ("captive",))

    @model_validator(mode="after")
    def _bounded(self) -> Protocol:
        """The whole run must fit MAX_POINTS and MAX_RUN_S; counted, never expanded."""
        n = self.n_points()
        if n > MAX_POINTS:
            raise FieldError(("command", "repeats"), (
                f"the plan has {n:,} points ({len(self.depth.values)} depth(s) x "
                f"{self.n_voltages()} voltage(s) x {self.n_captive()} flow setting(s) x "
                f"{self.command.repeats} repeat(s) x {self.command.per_repeat():,} command(s)); "
                f"the limit is {MAX_POINTS:,}"))
        self._steps_timing()
        if self.captive is not None and self.command.steps is not None:
            raise FieldError(("captive",), "a captive run holds each flow setting for a steady "
                             "point; step responses (`command.steps`) are another protocol")
        self._voltages_in_bus_band()
        least = self.min_duration_s()
        if least > MAX_RUN_S:
            where = ("limits", "slew_per_s") if self._ramps_s() > least / 2 else ("timing",)
            raise FieldError(where, (
                f"the run would take at least {least / 86_400:,.3g} days ({n:,} points); the "
                f"limit is {MAX_RUN_S / 86_400:g} days (single durations are limited to "
                f"{MAX_DURATION_S:g} s)"))
        return self

    def _steps_timing(self) -> None:
        """A step response is acquired from the step on, and levels follow each other."""
        if self.command.steps is None:
            return
        if self.timing.settle.seconds != 0:
            raise FieldError(("timing", "settle"), "with `command.steps` each level is acquired "
                             "from its step on: set `settle: {seconds: 0}`")
        if self.timing.rest_s != 0:
            raise FieldError(("timing", "rest_s"), "with `command.steps` levels follow each "
                             "other without a rest at neutral: set `rest_s: 0`")
        if self.timing.tare == "per_point":
            raise FieldError(("timing", "tare"), "with `command.steps` a tare per point would "
                             "go to neutral between levels: use `at_start` or `per_depth`")

    def _voltages_in_bus_band(self) -> None:
        """A swept voltage outside the bus limits would trip at every point: a file error."""
        if self.voltage is None:
            return
        lo, hi = self.limits.min_bus_v, self.limits.max_bus_v
        for v in self.voltage.values:
            if (lo is not None and v < lo) or (hi is not None and v > hi):
                field = "min_bus_v" if lo is not None and v < lo else "max_bus_v"
                raise FieldError(("limits", field), f"voltage.values has {v:g} V, outside the "
                                 f"bus limits ({lo if lo is not None else '-'}.."
                                 f"{hi if hi is not None else '-'} V): every point there would trip")

    @property
    def is_steps(self) -> bool:
        """A step-response protocol (`command.steps`)."""
        return self.command.steps is not None

    def n_voltages(self) -> int:
        """Supply voltages in the plan (1 when the protocol sets none)."""
        return len(self.voltage.values) if self.voltage is not None else 1

    def n_captive(self) -> int:
        """Flow settings (speeds x angles) in the plan (1 when the protocol sets none)."""
        return self.captive.n_settings() if self.captive is not None else 1

    def n_points(self) -> int:
        """Points in the plan: depths x voltages x flow settings x repeats x commands per repeat."""
        return (len(self.depth.values) * self.n_voltages() * self.n_captive()
                * self.command.repeats * self.command.per_repeat())

    def _ramps_s(self) -> float:
        """Least total slew time whatever the neutral: each point ramps out and back, and the
        sum of distances to any neutral is smallest at the median command."""
        slew = self.limits.slew_per_s
        if slew is None:
            return 0.0
        values = sorted(self.command.command_values())
        median = values[len(values) // 2]
        per_pass = sum(abs(v - median) for v in values) * (2 if self.command.order == "up-down" else 1)
        return (2 * per_pass * self.command.repeats * len(self.depth.values) * self.n_voltages()
                * self.n_captive() / slew)

    def min_duration_s(self) -> float:
        """A lower bound of the run's length: every point's timing and ramps, the first tare."""
        n = self.n_points()
        tares = n if self.timing.tare == "per_point" else int(self.timing.tare != "never")
        return n * self.timing.point_s() + tares * self.timing.tare_s + self._ramps_s()


def load_protocol(path: str | Path) -> tuple[Protocol, dict]:
    """Read and validate a protocol file; ConfigError names file, line and field."""
    return load_model(Path(path), Protocol)
