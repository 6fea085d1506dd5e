"""ArduSub / ArduPilot `.param` file: MOT_PWM_MIN/MAX (the motor output range around the
1500 us neutral), MOT_SPIN_MIN/MAX (where thrust starts and stops growing, as fractions of
each half range), MOT_SPIN_ARM (0: ArduPilot's metadata and arming check require it not above
MOT_SPIN_MIN, and its default 0.10 is above the dead band edge of a typical ESC) and
MOT_THST_EXPO fitted as ArduPilot's WebTools ThrustExpo page fits it, here on |thrust| of both
directions of a reversible thruster (docs/formats-controllers.md).

Read: libraries/AP_Motors/AP_MotorsMulticopter.cpp (master) metadata of MOT_SPIN_MIN ("Should be
higher than MOT_SPIN_ARM", line 114) and MOT_SPIN_ARM (default 0.1, "Should be lower than
MOT_SPIN_MIN", line 122) and AP_MotorsMulticopter::arming_checks (lines 967-968: refuses
MOT_SPIN_ARM > MOT_SPIN_MIN); AP_Motors6DOF::calc_thrust_to_pwm returns int16_t from the float
1500 + thrust x range, so the pulse is truncated to whole microseconds, which the stated error
includes."""

from __future__ import annotations

import math

import numpy as np

from rigtool.artefacts.vehicle import ExportInput

FILE = "ardusub.param"
FOLLOWS = ("ArduSub: ArduPilot master AP_Motors6DOF::calc_thrust_to_pwm (neutral 1500 us) and "
           "AP_Motors_Thrust_Linearization (MOT_SPIN_*, MOT_THST_EXPO) as open PR #32409 "
           "applies them to Sub; .param syntax of AP_Param::parse_param_line; expo fit of "
           "ArduPilot/WebTools ThrustExpo/ThrustExpo.js (8b697d4)")
NEUTRAL_US = 1500.0  # AP_Motors6DOF writes 1500 us for zero thrust; it is not a parameter
EXPO_GRID = np.arange(-1.0, 1.0 + 1e-9, 0.005)  # WebTools: expo -1..1 in steps of 0.005
THROTTLE_STEP = 0.001  # WebTools: actuator test values 0..1 in steps of 0.001
THROTTLE = np.linspace(0.0, 1.0, 1001)
SPIN_ARM = 0.0  # the neutral (1500 us): never above any thruster's MOT_SPIN_MIN
SPIN_ARM_DEFAULT = 0.1  # AP_MOTORS_SPIN_ARM_DEFAULT, what a file without the line leaves


def needs(x: ExportInput) -> list[str]:
    """A pulse-width calibration (us) about ArduSub's fixed 1500 us neutral, with a forward
    branch and commands above the neutral."""
    if x.cal.command_unit != "pulse_us":
        return ["command unit: MOT_PWM_* are pulse widths in microseconds, so the run must "
                "command pulse_us (protocol command.unit: pulse_us); other units have no "
                "ArduSub motor output to map to"]
    out = []
    if float(x.cal.neutral_command) != NEUTRAL_US:
        out.append(f"neutral command: ArduSub's motor output takes 1500 us as zero thrust "
                   f"(AP_Motors6DOF, not a parameter), this run's neutral is "
                   f"{float(x.cal.neutral_command):g} us")
    if not any(d == "forward" for d, _, _ in x.map.tables):
        out.append("command curve: no forward branch, so there is no thrust curve to fit")
    elif x.sec.curve is not None and float(np.max(x.sec.curve.command)) <= NEUTRAL_US:
        out.append("command range: no command above 1500 us, so MOT_PWM_MAX has no range")
    return out


def thrust_curve_expo(thrust: np.ndarray, expo: float) -> np.ndarray:
    """ArduPilot's apply_thrust_curve_and_volt_scaling at battery scale 1 and lift_max 1: the
    throttle ratio 0..1 that gives `thrust` (0..1) under MOT_THST_EXPO `expo`."""
    t = np.clip(np.asarray(thrust, dtype=float), 0.0, 1.0)
    e = min(max(float(expo), -1.0), 1.0)
    if e == 0.0:
        return t
    root = np.sqrt(np.maximum((1.0 - e) ** 2 + 4.0 * e * t, 0.0))
    return np.clip((e - 1.0 + root) / (2.0 * e), 0.0, 1.0)


def output_pwm(demand: np.ndarray, sign: float, p: dict[str, float]) -> np.ndarray:
    """The pulse (us) ArduSub writes for thrust demands of magnitude `demand` (0..1) on the
    `sign` side (+1 forward: a zero demand counts as forward, -1 reverse: the limit from below)
    with the linearisation of PR #32409: the magnitude through thrust_to_actuator (MOT_SPIN_MIN
    + (MOT_SPIN_MAX - MOT_SPIN_MIN) x thrust_curve_expo), then 1500 us plus that fraction of
    the half range on that side (calc_thrust_to_pwm)."""
    act = p["MOT_SPIN_MIN"] + (p["MOT_SPIN_MAX"] - p["MOT_SPIN_MIN"]) * thrust_curve_expo(
        np.abs(np.asarray(demand, dtype=float)), p["MOT_THST_EXPO"])
    half = p["MOT_PWM_MAX"] - NEUTRAL_US if sign > 0 else NEUTRAL_US - p["MOT_PWM_MIN"]
    return NEUTRAL_US + sign * act * half


def whole_us(pwm: np.ndarray) -> np.ndarray:
    """The pulse ArduSub writes: calc_thrust_to_pwm's float (single precision) converted to
    int16_t, truncated toward zero (whole microseconds)."""
    return np.trunc(np.asarray(pwm, dtype=np.float32)).astype(float)


def _thrust(x: ExportInput, command: np.ndarray) -> np.ndarray:
    """Thrust (N) on the command curve, held at its ends (as the map clamps)."""
    curve = x.sec.curve
    return np.interp(command, curve.command, curve.thrust_fit_n)


def _directions(x: ExportInput) -> list[str]:
    have = {d for d, _, _ in x.map.tables}
    return [d for d in ("forward", "reverse") if d in have]


def _spin(x: ExportInput, pwm_min: float, pwm_max: float) -> tuple[float, float]:
    """MOT_SPIN_MIN: the larger dead band edge of the two directions; MOT_SPIN_MAX: the smaller
    of the two directions' outermost live commands (where thrust stops growing), each as a
    fraction of its half range."""
    starts, ends = [], []
    for direction, _, c in x.map.tables:
        half = pwm_max - NEUTRAL_US if direction == "forward" else NEUTRAL_US - pwm_min
        if half <= 0:
            continue
        frac = np.abs(c - NEUTRAL_US) / half
        starts.append(float(frac.min()))
        ends.append(float(frac.max()))
    lo = min(max(max(starts), 0.0), 0.99)
    return round(lo, 4), round(min(max(min(ends), lo + 0.01), 1.0), 4)


def fit(x: ExportInput) -> dict[str, float]:
    """The parameters and the fit's figures: MOT_* values, `error_pct` (largest deviation of
    the linearised thrust from a straight line in the demand, % of that direction's thrust at
    full demand), `reverse_ratio` (reverse / forward thrust at full demand, NaN without a
    reverse branch)."""
    curve = x.sec.curve
    p: dict[str, float] = {"MOT_PWM_MIN": float(min(math.ceil(float(curve.command.min())),
                                                    int(NEUTRAL_US))),
                           "MOT_PWM_MAX": float(math.floor(float(curve.command.max())))}
    p["MOT_SPIN_MIN"], p["MOT_SPIN_MAX"] = _spin(x, p["MOT_PWM_MIN"], p["MOT_PWM_MAX"])
    signs = [1.0 if d == "forward" else -1.0 for d in _directions(x)]
    if p["MOT_PWM_MIN"] >= NEUTRAL_US:
        signs = [1.0]
    best = (math.inf, 0.0)
    for expo in EXPO_GRID:
        grads = []
        for s in signs:
            f = s * _thrust(x, output_pwm(THROTTLE, s, p | {"MOT_THST_EXPO": expo}))
            grads.append(np.diff(f / f[-1]) / THROTTLE_STEP)
        std = float(np.std(np.concatenate(grads)))
        if std < best[0]:
            best = (std, float(expo))
    p["MOT_THST_EXPO"] = round(best[1], 3)
    p["MOT_SPIN_ARM"] = SPIN_ARM
    err, curve_err = 0.0, 0.0
    full = {}
    for s in signs:
        pwm = output_pwm(THROTTLE, s, p)
        f = s * _thrust(x, pwm)
        full[s] = f[-1]
        curve_err = max(curve_err, float(np.max(np.abs(f - THROTTLE * f[-1])) / f[-1]))
        f_us = s * _thrust(x, whole_us(pwm))
        err = max(err, float(np.max(np.abs(f_us - THROTTLE * f[-1])) / f[-1]))
    p["error_pct"] = 100.0 * err
    p["curve_error_pct"] = 100.0 * curve_err
    p["reverse_ratio"] = full[-1.0] / full[1.0] if -1.0 in full else math.nan
    return p


def _value(name: str, v: float) -> str:
    return f"{int(v)}" if name.startswith("MOT_PWM") else f"{v:.6g}"


def render(x: ExportInput) -> str:
    """The .param text: comment lines start with `#` (AP_Param::parse_param_line skips them),
    parameters are `NAME,value` lines; no stored text (its syntax has no quoting)."""
    p = fit(x)
    names = ("MOT_PWM_MIN", "MOT_PWM_MAX", "MOT_SPIN_ARM", "MOT_SPIN_MIN", "MOT_SPIN_MAX",
             "MOT_THST_EXPO")
    first, _, units = x.head([])
    head = [first, "source run: the folder's name, calibrations/<run-id>/; run name, thruster, "
            "creation time and command unit are in its calibration.json (.param has no quoting "
            "for text).", units]
    lines = [*(f"# {line}" for line in head),
             "# ArduSub writes 1500 us for zero thrust and 1500 us + demand x (MOT_PWM_MAX -",
             "# 1500) forward, 1500 us - |demand| x (1500 - MOT_PWM_MIN) reverse. Every ArduSub",
             "# release reads MOT_PWM_MIN/MAX; MOT_SPIN_MIN/MAX and MOT_THST_EXPO exist in",
             "# them (shared with Copter) but act on the Sub output only with the",
             "# bidirectional linearisation of ArduPilot PR #32409 (not in a release yet).",
             f"# Linearised thrust off a straight line in the demand by at most "
             f"{p['error_pct']:.2f} % of full thrust",
             "# (expo fitted as WebTools ThrustExpo does, on |thrust| of each direction), the",
             "# pulse truncated to whole us as ArduSub writes it (int16); the curve alone",
             f"# {p['curve_error_pct']:.2f} %.",
             "# MOT_SPIN_ARM 0: ArduPilot requires MOT_SPIN_ARM <= MOT_SPIN_MIN (its",
             f"# metadata; the arming check refuses more), its default {SPIN_ARM_DEFAULT:g} is "
             f"{'above' if p['MOT_SPIN_MIN'] < SPIN_ARM_DEFAULT else 'not above'}",
             "# this MOT_SPIN_MIN; 0 (1500 us, no thrust) is never above a thruster's.",
             *(f"{name},{_value(name, p[name])}" for name in names)]
    if math.isfinite(p["reverse_ratio"]):
        lines += ["# Reverse / forward thrust at full demand, for the thrust asymmetry parameter",
                  "# of ArduPilot PR #32577 (open; its name is not final, so it is not set):",
                  f"# reverse_ratio {p['reverse_ratio']:.4f}"]
    return "\n".join(lines) + "\n"
