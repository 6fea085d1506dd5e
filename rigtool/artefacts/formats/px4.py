"""PX4 parameter file as QGroundControl loads it (Parameters > Tools > Load from file):
THR_MDL_FAC and the rotor's CA_ROTOR{n}_CT (and CA_ROTOR{n}_KM when torque was measured),
fitted to PX4's thrust model over the output range it maps the motor to
(docs/formats-controllers.md).

The output range is advised in the driver's units PX4 takes: MixingOutput::
output_limit_calc_single (src/lib/mixer_module/mixer_module.cpp, main) interpolates -1..1 onto
the output's minimum..maximum and returns lroundf of it constrained to 0..65535, so a limit is
an unsigned driver value (PWM_MAIN_MINn/MAXn in us); the DroneCAN ESC driver
(src/drivers/uavcan/actuators/esc.cpp update_outputs) sends those uint16 values as the raw
command, never a negative one."""

from __future__ import annotations

import math

import numpy as np

from rigtool.artefacts.vehicle import ExportInput
from rigtool.units import COMMAND_UNITS

FILE = "px4.params"
FOLLOWS = ("PX4 main: src/lib/mixer_module/functions/FunctionMotors.hpp (THR_MDL_FAC), "
           "mixer_module.cpp output_limit_calc_single (output range), "
           "src/modules/control_allocator module.yaml and ActuatorEffectivenessRotors.cpp "
           "(CA_ROTOR{n}_CT, CA_ROTOR{n}_KM, n from 0); file format of QGroundControl "
           "ParameterManager::readParametersFromStream")
SYSTEM_ID = 1  # QGC refuses a file whose lines name another system id (MAV_SYS_ID, default 1)
COMPONENT_ID = 1  # the autopilot
MAV_PARAM_TYPE_REAL32 = 9
MAX_ROTORS = 12  # control_allocator module.yaml: max_num_mc_motors
CT_MAX_N = 100.0  # control_allocator module.yaml: CA_ROTOR{n}_CT max
MAX_ERROR_PCT = 50.0  # a fit missing by more is no thrust model of this thruster
EXAMPLE_US = (1100.0, 1900.0)  # a PWM-input ESC taking -100..100 percent over this pulse range
U = np.linspace(0.0, 1.0, 1001)  # normalised output magnitude


def needs(x: ExportInput) -> list[str]:
    """A command curve with a forward branch; commands above the neutral; a rotor PX4 has."""
    if (x.options.index or 1) > MAX_ROTORS:
        return [f"--index: PX4 has CA_ROTOR0..CA_ROTOR{MAX_ROTORS - 1} (--index 1..{MAX_ROTORS})"]
    if not any(d == "forward" for d, _, _ in x.map.tables):
        return ["command curve: no forward branch, so there is no thrust curve to fit"]
    if float(np.max(x.sec.curve.command)) <= float(x.cal.neutral_command):
        return ["command range: no command above the neutral command"]
    p = fit(x)
    if not 0.0 < p["CT"] <= CT_MAX_N:
        return [f"CA_ROTOR{{n}}_CT: the fit gives {p['CT']:.4g} N, outside PX4's range 0 .. "
                f"{CT_MAX_N:g} N (PX4's thrust model, rising from the neutral command, does "
                "not describe this thruster's command curve)"]
    if p["error_pct"] > MAX_ERROR_PCT:
        return [f"THR_MDL_FAC: PX4's model misses this thruster's thrust by up to "
                f"{p['error_pct']:.0f} % of its largest (more than {MAX_ERROR_PCT:g} %): the "
                "command curve is not one PX4 can follow"]
    return []


def output_range(x: ExportInput) -> tuple[float, float, bool]:
    """(output minimum, maximum, reversible): a reversible motor (a reverse branch) gets a range
    centred on the neutral command (PX4 maps -1..1 linearly onto it, 0 to its middle), as wide
    as both directions allow; a forward-only one runs from the neutral command up."""
    curve = x.sec.curve
    neutral = float(x.cal.neutral_command)
    lo, hi = float(curve.command.min()), float(curve.command.max())
    if any(d == "reverse" for d, _, _ in x.map.tables) and lo < neutral:
        half = min(neutral - lo, hi - neutral)
        return neutral - half, neutral + half, True
    return neutral, hi, False


def command(u: np.ndarray, lo: float, hi: float, reversible: bool) -> np.ndarray:
    """The command PX4 outputs for the motor value u (-1..1 reversible, 0..1 otherwise) after
    THR_MDL_FAC: reversible, -1..1 linearly onto lo..hi; otherwise 0..1 onto lo..hi."""
    u = np.asarray(u, dtype=float)
    return lo + (u + 1.0) / 2.0 * (hi - lo) if reversible else lo + u * (hi - lo)


def _thrust(x: ExportInput, c: np.ndarray) -> np.ndarray:
    curve = x.sec.curve
    return np.interp(c, curve.command, curve.thrust_fit_n)


def fit(x: ExportInput) -> dict[str, float]:
    """THR_MDL_FAC f and CT (N at full output) by least squares of |thrust| = CT (f u^2 +
    (1-f) u) over both directions, f within 0..1 (PX4 applies it only there); `error_pct` and
    `rms_pct`, the model's largest and RMS error over the range, % of the largest |thrust|;
    `reverse_ratio` (reverse / forward thrust at full output, NaN forward-only)."""
    lo, hi, rev = output_range(x)
    signs = [1.0, -1.0] if rev else [1.0]
    mags = np.concatenate([s * _thrust(x, command(s * U, lo, hi, rev)) for s in signs])
    uu = np.tile(U, len(signs))
    a, b = np.linalg.lstsq(np.column_stack([uu ** 2, uu]), mags, rcond=None)[0]
    ct = a + b
    fac = a / ct if ct > 0 else 0.0
    if not 0.0 <= fac <= 1.0:
        fac = min(max(fac, 0.0), 1.0)
        basis = fac * uu ** 2 + (1.0 - fac) * uu
        ct = float(basis @ mags / (basis @ basis))
    model = ct * (fac * uu ** 2 + (1.0 - fac) * uu)
    scale = float(np.max(np.abs(mags)))
    per = np.abs(model - mags).reshape(len(signs), U.size).max(axis=1) / scale
    out = {"THR_MDL_FAC": round(float(fac), 4), "CT": round(float(ct), 4), "lo": lo, "hi": hi,
           "reversible": float(rev),
           "error_pct": 100.0 * float(np.max(np.abs(model - mags))) / scale,
           "forward_error_pct": 100.0 * float(per[0]),
           "reverse_error_pct": 100.0 * float(per[-1]) if rev else math.nan,
           "rms_pct": 100.0 * float(np.sqrt(np.mean((model - mags) ** 2))) / scale,
           "reverse_ratio": float(mags[-1] / mags[U.size - 1]) if rev else math.nan}
    km = x.coef("C_q_fwd") / x.coef("C_p_fwd")
    if math.isfinite(km) and km > 0:
        out["KM"] = round(float(km), 5)
    return out


def rotor(x: ExportInput) -> int:
    """PX4's rotor number: --index counts from 1, CA_ROTOR{n} from 0."""
    return (x.options.index or 1) - 1


def range_advice(x: ExportInput, lo: float, hi: float) -> list[str]:
    """Comment lines with the output's minimum and maximum in units PX4 takes: whole us for a
    pulse-width run; otherwise the fractions of the driver's span for the run's range (a
    percent run's -100..100 % being the driver's full span) and what that is on a PWM ESC."""
    unit = x.cal.command_unit
    if unit == "pulse_us":
        return [f"# Output range: PWM_MAIN_MIN<ch> {round(lo)}, PWM_MAIN_MAX<ch> {round(hi)} "
                "(us, whole as PX4 stores them; <ch> the motor's output channel, the",
                "# PWM_AUX_ or driver's own prefix on another output)."]
    name = unit if unit in COMMAND_UNITS else "the command unit"
    lines = [f"# Output range: the run's {lo:g} .. {hi:g} {name} cannot be typed: PX4's output "
             "limits are the output driver's units, never negative (0..65535).",
             f"# Set the minimum to the driver value that commands {lo:g} {name} of this "
             f"thruster and the maximum to the one for {hi:g} {name}."]
    if unit == "percent":
        a, b = ((v + 100.0) / 200.0 for v in (lo, hi))
        us = [EXAMPLE_US[0] + v * (EXAMPLE_US[1] - EXAMPLE_US[0]) for v in (a, b)]
        lines += [f"# Those are {a:.4g} and {b:.4g} of the way from the driver's -100 % value to "
                  f"its 100 % value; a PWM-input ESC taking {EXAMPLE_US[0]:g}..{EXAMPLE_US[1]:g} "
                  f"us for -100..100 %: PWM_MAIN_MIN<ch> {round(us[0])}, PWM_MAIN_MAX<ch> "
                  f"{round(us[1])}."]
    return lines + ["# PX4 sends a DroneCAN ESC (UAVCAN_EC_MIN/MAX) raw 0..8191 only, so it "
                    "cannot run one that reverses on negative commands in reverse."]


def _line(name: str, value: float) -> str:
    return f"{SYSTEM_ID}\t{COMPONENT_ID}\t{name}\t{value:.6g}\t{MAV_PARAM_TYPE_REAL32}"


def render(x: ExportInput) -> str:
    """The file: `#` comment lines (QGC skips them), then tab-separated system id, component
    id, name, value, MAV_PARAM_TYPE lines; no stored text (the format has no quoting)."""
    p = fit(x)
    n = rotor(x)
    first, _, units = x.head([])
    kind = ("reversible (set its CA_R_REV bit): -1..1 maps linearly onto the range, 0 to "
            "its middle" if p["reversible"] else "forward only: 0..1 maps onto the range")
    lines = [f"# {first}",
             "# source run: the folder's name, calibrations/<run-id>/; run name, thruster, "
             "creation time and command unit are in its calibration.json (no quoting here).",
             f"# {units}",
             f"# Rotor CA_ROTOR{n} (--index {n + 1}). Motor {kind}.",
             *range_advice(x, p["lo"], p["hi"]),
             "# PX4 model: thrust = CT (THR_MDL_FAC u^2 + (1 - THR_MDL_FAC) u), u the output",
             "# magnitude 0..1; CT in N (thrust at full output). Largest error over the range",
             f"# {p['error_pct']:.2f} % (RMS {p['rms_pct']:.2f} %) of the largest thrust.",
             "# THR_MDL_FAC is one value for all motors."]
    if math.isfinite(p["reverse_ratio"]):
        lines.append(f"# Reverse / forward thrust at full output: {p['reverse_ratio']:.4f} "
                     "(PX4 has one CT for both); largest error forward "
                     f"{p['forward_error_pct']:.2f} %, reverse {p['reverse_error_pct']:.2f} %.")
    if "KM" in p:
        lines.append("# CA_ROTOR KM = C_q/C_p (m): positive for a counter-clockwise rotor, "
                     "make it negative for a clockwise one.")
    else:
        lines.append(f"# No torque measured: CA_ROTOR{n}_KM is not set (PX4 keeps its value, "
                     "default 0.05).")
    lines += ["#", "# Vehicle-Id\tComponent-Id\tName\tValue\tType",
              _line("THR_MDL_FAC", p["THR_MDL_FAC"]), _line(f"CA_ROTOR{n}_CT", p["CT"])]
    if "KM" in p:
        lines.append(_line(f"CA_ROTOR{n}_KM", p["KM"]))
    return "\n".join(lines) + "\n"
