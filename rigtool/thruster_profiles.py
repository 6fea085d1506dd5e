"""Thruster profiles: every physical parameter of the simulator twin, and the three built-in rigs.

Units are SI with the unit in the name, except propeller speed in r/min (as the rigs
report it) and commands in the actuator's native unit. Thrust is f = C_p |n| n with
C_p = cp_forward for n > 0 and cp_reverse for n < 0; current is I = cn (U0/U) |n|^3 + idle
at supply voltage U (nominal U0 = supply_voltage_v): the shaft power C |n|^3 drawn at U.

Plain data, outside rigtool/sim: protocol and rig files name a profile and override its
parameters, and are validated here without importing the simulator that runs it.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

from rigtool.errors import UsageError

FEEDBACK_CHANNELS = ("speed_rpm", "current_a", "voltage_v", "temperature_c")
COMMAND_MAPS = ("speed", "pwm_table")
SPEED_LAWS = ("linear", "quadratic")
INFLOW_LAWS = ("linear", "healey")
PROFILE_COMMAND_UNITS = ("percent", "pwm_counts", "pulse_us")


@dataclass(frozen=True)
class ThrusterProfile:
    """All physical parameters of one simulated thruster, its driver and its force sensor."""

    # --- identity and command space (what the device layer exposes) ---
    name: str
    description: str
    command_unit: str  # "percent" | "pwm_counts" | "pulse_us"
    neutral: float  # safe command: propeller stopped
    command_min: float  # commands are clipped to [command_min, command_max]
    command_max: float
    feedback: tuple[str, ...]  # what the actuator reports: subset of FEEDBACK_CHANNELS
    # --- propeller and motor ---
    max_speed_rpm: float  # "speed" map: |target speed| at command_min / command_max
    cp_forward: float  # N/(r/min)^2, thrust coefficient for n > 0
    cp_reverse: float  # N/(r/min)^2, thrust coefficient for n < 0 (magnitude)
    cn: float  # A/(r/min)^3, current coefficient
    idle_current_a: float  # driver + motor current at zero speed
    supply_voltage_v: float  # nominal supply voltage U0: max_speed_rpm and cn hold at U0
    tau_s: float  # first-order time constant of propeller speed
    # --- feedback and sensor noise (standard deviations of white noise) ---
    speed_noise_rpm: float
    current_noise_a: float
    force_noise_n: float  # sensor noise on every force channel
    torque_noise_nm: float  # sensor noise on every torque channel
    vibration_noise_frac: float  # extra thrust-channel noise std per newton of |thrust|
    # --- sensor offset and mounting ---
    bias_n: float  # constant offset on the thrust channel (removed by taring)
    drift_n_per_h: float  # linear drift of that offset, N per hour since t0
    thrust_channel: int  # index into fx, fy, fz, tx, ty, tz where thrust appears
    thrust_sign: int  # +1 or -1: sensor reading = thrust_sign * thrust on that channel
    cavitation: bool  # quasi-cavitation (ventilation) near the surface on/off
    # --- command map ---
    command_map: str = "speed"  # "speed": linear outside a deadband; "pwm_table": STM32 table
    deadband: float = 0.0  # "speed": |command - neutral| <= deadband gives exactly zero speed
    # "pwm_table": steady-state thrust vs integer PWM value (speed follows from f = C_p|n|n)
    pwm_fwd_start: int = 207  # first forward PWM (below: stopped)
    pwm_fwd_sat_end: int = 396  # last PWM of the saturated forward plateau
    pwm_fwd_end: int = 427  # last forward PWM (inverted branch ends here)
    pwm_rev_creep_start: int = 446  # first reverse (creeping) PWM; stopped in between
    pwm_rev_breakaway: int = 451  # PWM of the reverse break-away jump
    pwm_rev_sat_start: int = 470  # first PWM of the saturated reverse plateau
    thrust_fwd_max_n: float = 5.0  # forward plateau, and inverted branch start at pwm_fwd_sat_end
    thrust_fwd_min_n: float = 0.15  # inverted branch end at pwm_fwd_end
    thrust_rev_creep_start_n: float = -0.08  # at pwm_rev_creep_start
    thrust_rev_creep_end_n: float = -0.15  # at pwm_rev_breakaway - 1
    thrust_rev_breakaway_n: float = -0.8  # at pwm_rev_breakaway
    thrust_rev_max_n: float = -3.0  # at pwm_rev_sat_start and above
    # --- other channels and electrics ---
    # thrust seen on each channel: N/N for forces, N m/N for torques (reaction torque)
    crosstalk: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    supply_resistance_ohm: float = 0.05  # voltage sag = R * current
    # an unregulated supply (or a charger-fed battery) floats this far above its setpoint at
    # no load: the bus is U + supply_rise_v - R * current, above U at light load
    supply_rise_v: float = 0.0
    # motor temperature (feedback "temperature_c"): dT/dt = heating * I^2 - (T - ambient) / tau
    heating_c_per_a2_s: float = 0.0
    thermal_tau_s: float = 300.0
    ambient_c: float = 20.0
    # speed loop in the driver: speed per command holds at any supply voltage; otherwise (duty
    # cycle, PWM) the speed reached scales with the supply voltage (back-EMF)
    speed_loop: bool = False
    voltage_noise_v: float = 0.05
    # --- quasi-cavitation ([Luo2020], docs/references.md) ---
    cav_ref_speed_rpm: float = 1404.0  # speed at which the onset/duration tables hold
    cav_min_speed_rpm: float = 300.0  # no onset below this |speed|; events end when stopped
    cav_speed_exponent: float = 1.2  # onset rate scales as (|n| / cav_ref_speed_rpm) ** this
    cav_max_depth_m: float = 0.6  # no onset at or below this depth
    cav_depth_table_m: tuple[float, ...] = (0.20, 0.30, 0.45, 0.55)  # increasing depths
    cav_mean_onset_s: tuple[float, ...] = (6.0, 10.5, 13.3, 40.0)  # 1/rate at ref speed
    cav_mean_duration_s: tuple[float, ...] = (30.0, 5.5, 2.7, 1.0)  # mean event length
    cav_duration_shape: float = 2.0  # gamma shape of the duration (1 = exponential)
    cav_drop_min: float = 0.25  # thrust drop fraction ~ Uniform(min, max)
    cav_drop_max: float = 0.75
    cav_ramp_in_s: float = 0.2  # thrust falls over the first ramp_in of the event
    cav_ramp_out_s: float = 0.3  # and recovers over its last ramp_out
    cav_current_drop: float = 0.08  # mean current drops by this * drop_frac
    cav_noise_frac: float = 0.03  # extra thrust noise std per newton of unventilated thrust
    # Axial inflow (second state, [Healey1995]): the inflow speed m follows the propeller speed
    # n with time constant inflow_tau_s, and thrust is C_p (n|n| + inflow_gain (n|n| - m|m|)):
    # a step overshoots while the inflow builds up. inflow_gain 0 is the first-order thruster.
    inflow_gain: float = 0.0
    inflow_tau_s: float = 0.5
    command_delay_s: float = 0.0  # dead time between a command reaching the driver and acting
    # Thrusters that follow other models (docs/dynamics.md), integrated numerically:
    # "quadratic" speed is Yoerger's one-state law J n' = b u - a n|n|, written
    # n' = (N|N| - n|n|) / (2 tau_s max_speed_rpm) towards the target speed N, so tau_s is the
    # time constant at full speed and a step to a fraction k of it takes 1/k as long;
    # "healey" inflow is Healey's: m' = (n|n| - m|m|) / (2 inflow_tau_s max_speed_rpm) and
    # thrust C_p (n|n| + inflow_gain |n| (n - m)) (C_1 n|n| - C_2 |n| u_a).
    speed_law: str = "linear"
    inflow_law: str = "linear"

    def __post_init__(self) -> None:
        problems = _problems(self)
        if problems:
            raise UsageError(f"thruster profile {self.name!r}: " + "; ".join(problems))


_NON_NEGATIVE = (
    "cn", "idle_current_a", "speed_noise_rpm", "current_noise_a", "force_noise_n",
    "torque_noise_nm", "vibration_noise_frac", "voltage_noise_v", "supply_resistance_ohm",
    "cav_noise_frac", "cav_current_drop", "cav_ramp_in_s", "cav_ramp_out_s", "inflow_gain",
    "command_delay_s", "supply_rise_v", "heating_c_per_a2_s",
)  # fmt: skip
_POSITIVE = ("cp_forward", "cp_reverse", "max_speed_rpm", "tau_s", "supply_voltage_v", "cav_ref_speed_rpm",
             "cav_duration_shape", "inflow_tau_s", "thermal_tau_s")  # fmt: skip
_PWM_BREAKPOINTS = ("pwm_fwd_start", "pwm_fwd_sat_end", "pwm_fwd_end", "pwm_rev_creep_start",
                    "pwm_rev_breakaway", "pwm_rev_sat_start")  # fmt: skip


def _increasing(xs: tuple | list) -> bool:
    """True if every value is larger than the one before."""
    return all(a < b for a, b in zip(xs, xs[1:], strict=False))


def _problems(p: ThrusterProfile) -> list[str]:
    """Inconsistencies that would make the twin meaningless, as readable messages."""
    pwm = [getattr(p, k) for k in _PWM_BREAKPOINTS]
    depths = p.cav_depth_table_m
    checks = [
        (p.command_unit in PROFILE_COMMAND_UNITS, f"command_unit not in {PROFILE_COMMAND_UNITS}"),
        (p.command_map in COMMAND_MAPS, f"command_map must be one of {COMMAND_MAPS}"),
        (p.speed_law in SPEED_LAWS, f"speed_law must be one of {SPEED_LAWS}"),
        (p.inflow_law in INFLOW_LAWS, f"inflow_law must be one of {INFLOW_LAWS}"),
        (p.command_min <= p.neutral <= p.command_max, "need command_min <= neutral <= command_max"),
        (set(p.feedback) <= set(FEEDBACK_CHANNELS), f"feedback must be within {FEEDBACK_CHANNELS}"),
        (p.thrust_channel in range(6), "thrust_channel must be 0..5"),
        (p.thrust_sign in (1, -1), "thrust_sign must be +1 or -1"),
        (len(p.crosstalk) == 6, "crosstalk needs 6 values"),
        (pwm[0] <= pwm[1] and _increasing(pwm[1:]), "PWM breakpoints must increase"),
        (len(depths) == len(p.cav_mean_onset_s) == len(p.cav_mean_duration_s) >= 1,
         "cavitation tables need equal, non-zero lengths"),
        (_increasing(depths), "cav_depth_table_m must increase"),
        (min(p.cav_mean_onset_s + p.cav_mean_duration_s, default=1) > 0, "cavitation times <= 0"),
        (0 <= p.cav_drop_min <= p.cav_drop_max <= 1, "need 0 <= cav_drop_min <= cav_drop_max <= 1"),
    ]  # fmt: skip
    problems = [message for ok, message in checks if not ok]
    problems += [f"{k} must be >= 0" for k in _NON_NEGATIVE if getattr(p, k) < 0]
    problems += [f"{k} must be > 0" for k in _POSITIVE if getattr(p, k) <= 0]
    return problems


_CAN_BLDC = ThrusterProfile(
    name="can-bldc",
    description="Pool rig [Luo2020]: 350 W 48 V BLDC, speed control over CAN, ATI mini45",
    command_unit="percent",
    neutral=0.0,
    command_min=-100.0,
    command_max=100.0,
    feedback=("speed_rpm", "current_a", "voltage_v"),
    max_speed_rpm=1800.0,
    cp_forward=1.926e-5,  # Luo's fit: 1404 r/min -> 38 N, 1800 r/min -> 62 N
    cp_reverse=0.8 * 1.926e-5,
    cn=1.2e-9,  # 1800 r/min -> 7.0 A + idle = 7.3 A ~ 350 W / 48 V
    idle_current_a=0.3,
    supply_voltage_v=48.0,
    tau_s=0.3,
    speed_noise_rpm=15.0,  # ~1 % at 1404 r/min: Hall-sensor speed jitter at 1 kHz
    current_noise_a=0.15,  # ~4 % at 1404 r/min: current is the noisier estimate
    force_noise_n=0.12,
    torque_noise_nm=0.004,
    vibration_noise_frac=0.01,
    bias_n=3.0,
    drift_n_per_h=0.6,
    thrust_channel=0,  # fx
    thrust_sign=1,
    cavitation=True,
    crosstalk=(0.0, 0.015, -0.02, 0.02, 0.0, 0.004),  # tx: reaction torque about the axis
    supply_resistance_ohm=0.08,
    speed_loop=True,
)

_STM32_PWM = ThrusterProfile(
    name="stm32-pwm",
    description="Bench rig, Zheng 2017: STM32 PWM driver (ARR 799), two dead zones, no feedback",
    command_unit="pwm_counts",
    neutral=0.0,
    command_min=0.0,
    command_max=799.0,
    feedback=(),
    max_speed_rpm=3000.0,
    command_map="pwm_table",
    cp_forward=5.0 / 3000.0**2,  # 5 N at 3000 r/min
    cp_reverse=0.8 * 5.0 / 3000.0**2,  # -3 N at about 2600 r/min
    cn=1.8e-10,  # 3000 r/min -> 4.9 A + idle on 12 V
    idle_current_a=0.2,
    supply_voltage_v=12.0,
    tau_s=0.15,
    speed_noise_rpm=10.0,
    current_noise_a=0.1,
    force_noise_n=0.01,
    torque_noise_nm=0.001,
    vibration_noise_frac=0.006,  # 500 samples: max-mean ~0.1 N at 5 N, ~0.05 N at -2 N
    bias_n=0.2,
    drift_n_per_h=0.05,
    thrust_channel=2,  # fz, sensor mounted upside down
    thrust_sign=-1,
    cavitation=False,
    crosstalk=(0.01, -0.01, 0.0, 0.0, 0.0, 0.01),
    cav_ref_speed_rpm=2340.0,
    cav_min_speed_rpm=500.0,
)

_ESC_1100_1900 = ThrusterProfile(
    name="esc-1100-1900",
    description="ESC thruster (Blue Robotics style): 1100-1900 us, 1500 us stop, +-25 us deadband",
    command_unit="pulse_us",
    neutral=1500.0,
    command_min=1100.0,
    command_max=1900.0,
    feedback=("speed_rpm", "current_a"),
    max_speed_rpm=3800.0,
    deadband=25.0,
    cp_forward=50.0 / 3800.0**2,  # 50 N at 3800 r/min
    cp_reverse=0.8 * 50.0 / 3800.0**2,
    cn=4.4e-10,  # 3800 r/min -> 24 A on 16 V
    idle_current_a=0.1,
    supply_voltage_v=16.0,
    tau_s=0.15,
    speed_noise_rpm=15.0,
    current_noise_a=0.3,
    force_noise_n=0.05,
    torque_noise_nm=0.002,
    vibration_noise_frac=0.01,
    bias_n=1.0,
    drift_n_per_h=0.3,
    thrust_channel=0,  # fx
    thrust_sign=1,
    cavitation=True,
    crosstalk=(0.0, 0.01, 0.01, 0.015, 0.0, 0.0),
    supply_resistance_ohm=0.02,
    cav_ref_speed_rpm=2964.0,  # same fraction of max speed as 1404/1800
    cav_min_speed_rpm=630.0,
)

PROFILES: dict[str, ThrusterProfile] = {p.name: p for p in (_CAN_BLDC, _STM32_PWM, _ESC_1100_1900)}


def _coerce(key: str, kind: str, value: object) -> object:
    """Convert one override value to its field's type, or raise UsageError naming the key."""

    def number(v: object) -> float:
        if isinstance(v, bool) or not isinstance(v, (numbers.Real, str)):
            raise UsageError(f"override {key!r}: expected a number, got {v!r}")
        try:
            x = float(v)
        except ValueError:
            raise UsageError(f"override {key!r}: expected a number, got {v!r}") from None
        if not math.isfinite(x):
            raise UsageError(f"override {key!r}: expected a finite number, got {v!r}")
        return x

    if kind == "float":
        return number(value)
    if kind == "int":
        x = number(value)
        if x != int(x):
            raise UsageError(f"override {key!r}: expected an integer, got {value!r}")
        return int(x)
    if kind == "bool":
        if isinstance(value, bool) or value in (0, 1):
            return bool(value)
        raise UsageError(f"override {key!r}: expected true or false, got {value!r}")
    if kind == "str":
        if not isinstance(value, str):
            raise UsageError(f"override {key!r}: expected a string, got {value!r}")
        return value
    if not isinstance(value, (list, tuple)):
        raise UsageError(f"override {key!r}: expected a list, got {value!r}")
    if kind == "tuple[str, ...]":
        if not all(isinstance(v, str) for v in value):
            raise UsageError(f"override {key!r}: expected a list of strings, got {value!r}")
        return tuple(value)
    return tuple(number(v) for v in value)


def profile_with_overrides(name: str, overrides: dict) -> ThrusterProfile:
    """Built-in profile `name` with some parameters replaced (e.g. from a rig file)."""
    if name not in PROFILES:
        raise UsageError(f"unknown thruster profile {name!r}; known: {', '.join(PROFILES)}")
    kinds = {f.name: str(f.type) for f in dataclasses.fields(ThrusterProfile)}
    changes = {}
    for key, value in (overrides or {}).items():
        if key not in kinds:
            raise UsageError(
                f"unknown thruster parameter {key!r} for profile {name!r}; "
                f"valid: {', '.join(kinds)}"
            )
        changes[key] = _coerce(key, kinds[key], value)
    return dataclasses.replace(PROFILES[name], **changes)
