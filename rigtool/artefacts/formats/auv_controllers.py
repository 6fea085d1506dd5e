"""ros2_control parameters of Robotic-Decision-Making-Lab auv_controllers' thruster_controllers:
a PolynomialThrustCurveController (thrust -> PWM polynomial fitted to the vehicle map, thrust
limits, PWM dead band, neutral) for a pulse-width run, and a RotationRateController (one thrust
coefficient, propeller diameter, fluid density, speed dead band) when C_p, the diameter and the
water density are known (docs/formats-controllers.md)."""

from __future__ import annotations

import math

import numpy as np
from numpy.polynomial import Polynomial

from rigtool.artefacts.vehicle import RAD_S_PER_RPM, ExportInput
from rigtool.artefacts.yaml_params import comment, yaml_entries

FILE = "auv_controllers.yaml"
FOLLOWS = ("Robotic-Decision-Making-Lab/auv_controllers 9ac9eba (thruster_controllers 0.4.2): "
           "src/polynomial_thrust_curve_controller_parameters.yaml and .cpp, "
           "src/rotation_rate_controller_parameters.yaml and .cpp (generate_parameter_library)")
PWM_UNITS = ("pulse_us", "pwm_counts")
DEGREES = range(1, 12)
N_EVAL = 2001


def _poly_missing(x: ExportInput) -> str | None:
    if x.cal.command_unit not in PWM_UNITS:
        return ("polynomial_thrust_curve_controller: its output is an integer PWM, so the run "
                "must command pulse_us or pwm_counts (protocol command.unit)")
    if not x.map.tables:
        return "polynomial_thrust_curve_controller: no command curve with a live branch"
    neutral = float(x.cal.neutral_command)
    if any((d == "forward") != bool(c.min() > neutral) for d, _, c in x.map.tables if c.size):
        return ("polynomial_thrust_curve_controller: its dead band runs from min_deadband_pwm "
                "below neutral_pwm to max_deadband_pwm above it, so forward thrust must come "
                "from commands above the neutral command and reverse from below; this "
                "thruster's do not")
    return None


def _rate_missing(x: ExportInput) -> str | None:
    gaps = []
    if not x.coef("C_p_fwd") > 0:
        gaps.append("C_p_fwd (a run with speed feedback)")
    if x.cal.propeller_diameter_m is None:
        gaps.append("the propeller diameter (protocol metadata.propeller_diameter_m)")
    if x.cal.water_density_kg_m3 is None:
        gaps.append("the water density (protocol metadata.water_density_kg_m3)")
    if not x.map.tables:
        gaps.append("a command curve with a live branch")
    return ("rotation_rate_controller: needs " + ", ".join(gaps)) if gaps else None


def needs(x: ExportInput) -> list[str]:
    """The thruster's joint name (--joint: both controllers' required `thruster`), and what at
    least one of the two controllers needs."""
    out = [] if x.options.joint else [
        "--joint: the thruster joint the controller commands (its required `thruster`)"]
    poly, rate = _poly_missing(x), _rate_missing(x)
    return out + ([poly, rate] if poly and rate else [])


def _ends(x: ExportInput) -> tuple[float, float, float, float]:
    """(min thrust, max thrust, smallest reverse magnitude, smallest forward thrust), N; a
    missing direction gives 0."""
    fwd, rev = x.map.limits("forward"), x.map.limits("reverse")
    return (-rev[1] if rev else 0.0, fwd[1] if fwd else 0.0, rev[0] if rev else 0.0,
            fwd[0] if fwd else 0.0)


def _thrust(x: ExportInput, c: np.ndarray) -> np.ndarray:
    curve = x.sec.curve
    return np.interp(c, curve.command, curve.thrust_fit_n)


def poly_command(f: np.ndarray, p: dict) -> np.ndarray:
    """What PolynomialThrustCurveController outputs for thrust `f`: clamped to the limits, the
    polynomial (lowest degree first) rounded to an integer, the neutral strictly inside the
    dead band."""
    fc = np.clip(np.asarray(f, dtype=float), p["min_thrust"], p["max_thrust"])
    pwm = np.round(np.polynomial.polynomial.polyval(fc, p["thrust_curve_coefficients"]))
    dead = (pwm > p["min_deadband_pwm"]) & (pwm < p["max_deadband_pwm"])
    return np.where(dead, float(p["neutral_pwm"]), pwm)


def _within(p: dict, probe: np.ndarray, span: tuple[float, float]) -> dict:
    """`p` with its thrust limits drawn in to the widest interval about 0 N whose commands stay
    inside the measured command range `span` (the controller clamps the thrust to them)."""
    pwm = np.round(np.polynomial.polynomial.polyval(probe, p["thrust_curve_coefficients"]))
    bad = (pwm < span[0]) | (pwm > span[1])
    if not bad.any():
        return p
    zero = int(np.abs(probe).argmin())
    below, above = np.flatnonzero(bad[:zero]), np.flatnonzero(bad[zero:]) + zero
    lo = probe[below[-1] + 1] if below.size else p["min_thrust"]
    hi = probe[above[0] - 1] if above.size else p["max_thrust"]
    return p | {"min_thrust": float(min(lo, 0.0)), "max_thrust": float(max(hi, 0.0))}


def polynomial(x: ExportInput) -> dict:
    """The polynomial controller's parameters, the degree whose thrust error is smallest among
    1..11 (least squares of the vehicle map's command on thrust, each residual weighted by the
    thrust slope there, so it counts as the thrust it costs), and its
    `error_pct`: the largest |thrust(command) - requested| over the thrust range, % of the
    largest |thrust|, with the controller's rounding and dead band; where the polynomial would
    leave the measured command range, the thrust limits are drawn in (`_within`), and the
    thrust lost beyond them counts in the error."""
    f_min, f_max, _, _ = _ends(x)
    neutral = float(x.cal.neutral_command)
    below = [float(c.max()) for d, _, c in x.map.tables if d == "reverse" and c.size]
    above = [float(c.min()) for d, _, c in x.map.tables if d == "forward" and c.size]
    base = {"min_thrust": f_min, "max_thrust": f_max,
            "min_deadband_pwm": int(math.floor(max(below))) if below else round(neutral),
            "max_deadband_pwm": int(math.ceil(min(above))) if above else round(neutral),
            "neutral_pwm": round(neutral)}
    probe = np.linspace(f_min, f_max, N_EVAL)
    target, _ = x.map.command(probe)
    curve = x.sec.curve
    weight = np.abs(np.interp(target, curve.command,
                              np.gradient(curve.thrust_fit_n, curve.command)))
    scale = max(abs(f_min), abs(f_max))
    best: dict = {}
    for degree in DEGREES:
        coef = Polynomial.fit(probe, target, degree, w=weight).convert().coef
        p = _within(base | {"thrust_curve_coefficients": [float(v) for v in coef]}, probe,
                    (float(curve.command.min()), float(curve.command.max())))
        err = float(np.max(np.abs(_thrust(x, poly_command(probe, p)) - probe))) / scale
        if not best or err < best["error"] - 1e-12:
            best = p | {"error": err, "degree": degree}
    best["error_pct"] = 100.0 * best.pop("error")
    return best


def rotation_rate(x: ExportInput) -> dict[str, float]:
    """The rotation-rate controller's parameters: thrust = thrust_coefficient x fluid_density x
    omega^2 x diameter^4, omega in rad/s, from C_p_fwd (one coefficient for both directions);
    its dead band is in rad/s (the controller compares it with omega), the speeds of the
    smallest thrust outside the dead band."""
    f_min, f_max, rev_small, fwd_small = _ends(x)
    rho, d = float(x.cal.water_density_kg_m3), float(x.cal.propeller_diameter_m)
    k = x.coef("C_p_fwd") / RAD_S_PER_RPM ** 2  # N/(rad/s)^2
    kt = k / (rho * d ** 4)
    return {"min_thrust": f_min, "max_thrust": f_max,
            "min_deadband": 0.0 - math.sqrt(rev_small / k), "max_deadband": math.sqrt(fwd_small / k),
            "thrust_coefficient": kt, "propeller_diameter": d, "fluid_density": rho,
            "reverse_ratio": x.coef("C_p_rev") / x.coef("C_p_fwd")}


def render(x: ExportInput) -> str:
    """The parameter file: controller_manager's controller types, then each controller's
    parameters (the texts under `rigtool.` as quoted YAML strings)."""
    n = x.options.index or 1
    names = {"poly": f"thruster_{n}_controller", "rate": f"thruster_{n}_rotation_rate_controller"}
    types = {"poly": "thruster_controllers/PolynomialThrustCurveController",
             "rate": "thruster_controllers/RotationRateController"}
    blocks: dict[str, dict] = {}
    notes = [*x.head([f"rigtool.{k}" for k in x.texts]),
             "Load one of the two controllers for the thruster (both claim its reference)."]
    why = _poly_missing(x)
    if why is None:
        p = polynomial(x)
        notes += [f"{names['poly']}: pwm = sum c_i thrust^i (degree {p['degree']}); largest",
                  f"thrust error over the range {p['error_pct']:.2f} % of the largest thrust "
                  "(rounding, dead band included)."]
        blocks["poly"] = {"thruster": x.options.joint or "",
                          **{k: p[k] for k in ("thrust_curve_coefficients", "min_thrust",
                                               "max_thrust", "min_deadband_pwm",
                                               "max_deadband_pwm", "neutral_pwm")}}
    else:
        notes.append(f"No {why}.")
    why = _rate_missing(x)
    if why is None:
        r = rotation_rate(x)
        notes += [f"{names['rate']}: omega (rad/s) = sqrt(|thrust| / (thrust_coefficient",
                  "fluid_density diameter^4)); one coefficient (forward C_p): reverse gives",
                  f"{r['reverse_ratio']:.4f} x the thrust asked. Dead band in rad/s, as its "
                  "code compares it."]
        blocks["rate"] = {"thruster": x.options.joint or "",
                          **{k: v for k, v in r.items() if k != "reverse_ratio"}}
    else:
        notes.append(f"No {why}.")
    text = comment(notes) + "controller_manager:\n  ros__parameters:\n"
    for key in blocks:
        text += f"    {names[key]}:\n      type: {types[key]}\n"
    for key, params in blocks.items():
        text += (f"\n{names[key]}:\n  ros__parameters:\n" + yaml_entries(params, " " * 4)
                 + "    rigtool:\n" + yaml_entries(x.texts, " " * 6))
    return text
