"""uuv_simulator's thruster plugin (Gazebo classic): the <plugin> block with the propeller
speed -> thrust table as its LinearInterp conversion (Bessa's coefficients beside it), the
identified lag as FirstOrder dynamics, the measured speed and thrust ranges as clamps
(docs/formats-simulators.md). Also the speed table and lag helpers the Stonefish format uses.
"""

from __future__ import annotations

import math

import numpy as np

from rigtool.artefacts.encode import xml_text
from rigtool.artefacts.vehicle import RAD_S_PER_RPM, ExportInput

FILE = "thruster_uuv.xml"
FOLLOWS = ("uuv_simulator 0.6.13 (uuvsimulator/uuv_simulator at bfb40cb, "
           "uuv_gazebo_plugins: ThrusterPlugin.cc, Dynamics.cc, ThrusterConversionFcn.cc)")
PLUGIN_FILE = "libuuv_thruster_ros_plugin.so"
QUADRATIC_SPEED = ("yoerger", "healey")  # rigtool models whose speed follows Yoerger's law
DYNAMICS_TEXTS = ("dynamics_model", "dynamics_source_run")
DYNAMICS_NUMBERS = ("command_delay_s", "first_order_error_frac", "yoerger_error_frac")


def num(v: float) -> str:
    """A number as the consumers read it (9 significant digits; never NaN)."""
    return f"{float(v):.9g}"


def numbers(values: np.ndarray) -> str:
    """Space-separated numbers (LinearInterp's inputValues/outputValues, Stonefish's lists)."""
    return " ".join(num(v) for v in values)


def speed_table(x: ExportInput) -> tuple[np.ndarray, np.ndarray]:
    """(propeller speed in rad/s ascending, thrust N) of the section's command curve: each
    measured command's mean speed and fitted thrust (the numbers cal.thrust interpolates),
    dead commands as (0, 0). Walking out from (0, 0) in each direction, a point is kept only
    when both its speed and its thrust go beyond the last kept one (noise near zero speed
    cannot fold the table); empty without speed feedback."""
    curve = x.sec.curve
    if curve is None:
        return np.zeros(0), np.zeros(0)
    speed = np.asarray(curve.speed_mean_rpm, dtype=float) * RAD_S_PER_RPM
    thrust = np.asarray(curve.thrust_fit_n, dtype=float)
    ok = np.isfinite(speed) & np.isfinite(thrust) & (np.asarray(curve.state) != "dead")
    if not ok.any():
        return np.zeros(0), np.zeros(0)
    w, f = speed[ok], thrust[ok]
    side = []
    for sign in (1.0, -1.0):
        last_w = last_f = 0.0
        for i in np.argsort(sign * w):
            if sign * w[i] > sign * last_w and sign * f[i] > sign * last_f:
                side.append((w[i], f[i]))
                last_w, last_f = w[i], f[i]
    if not side:
        return np.zeros(0), np.zeros(0)
    table = np.array(sorted([*side, (0.0, 0.0)]))
    return table[:, 0], table[:, 1]


def speed_needs(x: ExportInput) -> list[str]:
    """Why there is no speed -> thrust table (the simulators' conversion input is rotor
    speed)."""
    w, _ = speed_table(x)
    if w.size >= 2:
        return []
    return ["no propeller speed measured at a live command (the rig has no speed feedback): "
            "the simulator converts rotor speed (rad/s) to thrust; sweep on a rig with a "
            "speed sensor (rig key speed)"]


def rotor_constants(x: ExportInput) -> tuple[float, float] | None:
    """(forward, reverse) thrust = k w|w| coefficients in N/(rad/s)^2 from C_p_fwd, C_p_rev
    (None unless both were fitted)."""
    fwd, rev = x.coef("C_p_fwd"), x.coef("C_p_rev")
    if not (math.isfinite(fwd) and math.isfinite(rev) and fwd > 0 and rev > 0):
        return None
    return fwd / RAD_S_PER_RPM**2, rev / RAD_S_PER_RPM**2


def time_constant(dp: dict[str, float | str] | None) -> float:
    """The single time constant for a first-order lag (NaN: none): the best single lag
    (first_order_time_constant_s) where the dynamics give it, else time_constant_s."""
    for key in ("first_order_time_constant_s", "time_constant_s"):
        tau = float(dp.get(key, math.nan)) if dp else math.nan
        if math.isfinite(tau) and tau > 0:
            return tau
    return math.nan


def yoerger_rad_s(dp: dict[str, float | str] | None) -> tuple[float, float, float] | None:
    """Yoerger's (alpha, beta forward, beta reverse) for w' = beta f_cmd - alpha w|w| with w
    in rad/s and f_cmd in N, from rigtool's r/min ones (None: not fitted, or no C_p)."""
    if not dp or dp.get("yoerger_state_unit") != "r/min":
        return None
    vals = [float(dp.get(k, math.nan)) for k in ("yoerger_alpha", "yoerger_beta_forward",
                                                 "yoerger_beta_reverse")]
    if not all(math.isfinite(v) and v > 0 for v in vals):
        return None
    alpha, b_fwd, b_rev = vals
    return alpha / RAD_S_PER_RPM, b_fwd * RAD_S_PER_RPM, b_rev * RAD_S_PER_RPM


def dynamics_elements(dp: dict[str, float | str] | None, indent: str) -> str:
    """rigtool_* elements naming the dynamics' source and what the simulator leaves out."""
    if dp is None:
        return ""
    texts = "".join(f"{indent}<rigtool_{k}>{xml_text(str(dp[k]))}</rigtool_{k}>\n"
                    for k in DYNAMICS_TEXTS if k in dp)
    nums = "".join(f"{indent}<rigtool_{k}>{num(float(dp[k]))}</rigtool_{k}>\n"
                   for k in DYNAMICS_NUMBERS if math.isfinite(float(dp.get(k, math.nan))))
    return texts + nums


def comment(text: str) -> str:
    """An XML comment of fixed text and numbers (no stored text): `--` cannot occur in one."""
    return "<!-- " + text.replace("--", "- -") + " -->\n"


def no_lag(x: ExportInput, dp: dict[str, float | str] | None) -> str:
    """Why the export has no lag."""
    if dp is not None:
        return "no time constant identified"
    if x.dynamics is None:
        return "no step-response run was given (export-cal's dynamics option)"
    return "the step-response run gave no identified dynamics"


def text_elements(x: ExportInput, indent: str) -> str:
    """The stored texts as rigtool_* elements (values, encoded; never comments)."""
    return "".join(f"{indent}<rigtool_{k}>{xml_text(v)}</rigtool_{k}>\n"
                   for k, v in x.texts.items())


def needs(x: ExportInput) -> list[str]:
    """The link, joint and thruster number (the plugin dereferences the joint), and speed
    feedback."""
    out = speed_needs(x)
    if not x.options.link:
        out.append("no thruster link: give --link NAME (the link the thrust acts on, "
                   "<linkName>)")
    if not x.options.joint:
        out.append("no propeller joint: give --joint NAME (<jointName>; the plugin reads the "
                   "thrust axis from it)")
    if not x.options.index:
        out.append("no thruster number: give --index N (from 1; <thrusterID> is N - 1, as "
                   "uuv_thruster_manager numbers thrusters from 0)")
    return out


def _dynamics(x: ExportInput, dp: dict[str, float | str] | None) -> tuple[str, str]:
    """The <dynamics> block and its comment."""
    tau = time_constant(dp)
    if not math.isfinite(tau):
        return "    <type>ZeroOrder</type>\n", f"ZeroOrder dynamics (no lag): {no_lag(x, dp)}."
    yo = yoerger_rad_s(dp)
    note = (f"FirstOrder dynamics: speed lag with timeConstant {tau:.6g} s (rigtool's "
            "single time constant); the command delay, an inflow overshoot and a separate "
            "spin-down constant are not in this plugin.")
    if yo is not None:
        note += (" rigtool_yoerger_alpha/beta_*: Yoerger's w' = beta f_cmd - alpha w|w| "
                 "(w rad/s, f_cmd N); not written as <type>Yoerger</type> because this "
                 "plugin's Yoerger update never advances its previous time (dt grows with "
                 "simulation time).")
    return f"    <type>FirstOrder</type>\n    <timeConstant>{num(tau)}</timeConstant>\n", note


def _yoerger_elements(dp: dict[str, float | str] | None) -> str:
    """Yoerger's alpha and betas in the plugin's units, for a plugin whose Yoerger works."""
    yo = yoerger_rad_s(dp)
    if yo is None:
        return ""
    names = ("yoerger_alpha", "yoerger_beta_forward", "yoerger_beta_reverse")
    return "".join(f"  <rigtool_{k}>{num(v)}</rigtool_{k}>\n"
                   for k, v in zip(names, yo, strict=True))


def render(x: ExportInput) -> str:
    """The <plugin> block's text."""
    w, f = speed_table(x)
    dp = x.dynamics_params()
    dyn, dyn_note = _dynamics(x, dp)
    k = rotor_constants(x)
    bessa = "" if k is None else (
        f"    <rotorConstantL>{num(k[1])}</rotorConstantL>\n"
        f"    <rotorConstantR>{num(k[0])}</rotorConstantR>\n"
        "    <deltaL>0</deltaL>\n    <deltaR>0</deltaR>\n")
    bessa_note = ("" if k is None else
                  " For Bessa's coefficient model instead set <type>Bessa</type>: "
                  "thrust = rotorConstantR w|w| forward, rotorConstantL w|w| reverse "
                  "(C_p of each direction in N/(rad/s)^2; no dead band in speed).")
    ns = x.options.namespace
    thruster_id = (x.options.index or 1) - 1
    name = f"{ns}_{thruster_id}_thruster_model" if ns else f"thruster_{thruster_id}_model"
    head = " ".join(x.head([f"rigtool_{k}" for k in x.texts]))
    return (comment(head) + comment(
            "Input (thrusters/ID/input): the propeller speed setpoint in rad/s, as "
            "uuv_thruster_manager sends it; the dynamics' state is the speed the joint turns "
            "at. The LinearInterp conversion maps speed (rad/s) to thrust (N): each measured "
            f"command's mean speed and fitted thrust, {w.size} points.{bessa_note} "
            f"{dyn_note} clampMin/clampMax: the measured speed range (rad/s); "
            "thrustMin/thrustMax: the measured thrust range (N).") +
            f'<plugin name="{xml_text(name)}" filename="{PLUGIN_FILE}">\n'
            f"  <linkName>{xml_text(x.options.link or '')}</linkName>\n"
            f"  <jointName>{xml_text(x.options.joint or '')}</jointName>\n"
            f"  <thrusterID>{thruster_id}</thrusterID>\n"
            f"  <clampMin>{num(w[0])}</clampMin>\n  <clampMax>{num(w[-1])}</clampMax>\n"
            f"  <thrustMin>{num(f[0])}</thrustMin>\n  <thrustMax>{num(f[-1])}</thrustMax>\n"
            "  <gain>1</gain>\n"
            f"  <dynamics>\n{dyn}  </dynamics>\n"
            "  <conversion>\n    <type>LinearInterp</type>\n"
            f"    <inputValues>{numbers(w)}</inputValues>\n"
            f"    <outputValues>{numbers(f)}</outputValues>\n{bessa}  </conversion>\n"
            + _yoerger_elements(dp) + dynamics_elements(dp, "  ") + text_elements(x, "  ")
            + "</plugin>\n")
