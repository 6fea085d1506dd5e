"""uuv_simulator's thruster plugin (Gazebo classic): the <plugin> block with the propeller
speed -> thrust table as its LinearInterp conversion (Bessa's coefficients beside it), the
identified lag as FirstOrder dynamics, the measured speed and thrust ranges as clamps
(docs/formats-simulators.md). Also the speed table and lag helpers the Stonefish format uses.

The lag written is judged as uuv runs it, on a step sequence the fit did not see: the speed
setpoint uuv_thruster_manager sends (models/thruster_custom.py get_command_value, line 72:
numpy.interp(thrust, output, input)) through Dynamics.cc DynamicsFirstOrder::update (lines
109-125: the first call only stores the time; state = state e^(-dt/tau) + (1 - e^(-dt/tau)) cmd)
and ThrusterConversionFcn.cc LinearInterp, against the identified model. The manager inverts its
own conversion_fcn, so the block carries the matching `conversion_fcn: custom` parameters
(thruster_manager.py lines 143-161 and 262-276 pass conversion_fcn_params to it).
"""

from __future__ import annotations

import math

import numpy as np

from rigtool.analysis.dynamics import simulate
from rigtool.artefacts.encode import xml_text
from rigtool.artefacts.vehicle import RAD_S_PER_RPM, ExportInput
from rigtool.artefacts.yaml_params import yaml_value

FILE = "thruster_uuv.xml"
FOLLOWS = ("uuv_simulator 0.6.13 (uuvsimulator/uuv_simulator at bfb40cb, "
           "uuv_gazebo_plugins: ThrusterPlugin.cc, Dynamics.cc, ThrusterConversionFcn.cc)")
PLUGIN_FILE = "libuuv_thruster_ros_plugin.so"
QUADRATIC_SPEED = ("yoerger", "healey")  # rigtool models whose speed follows Yoerger's law
DYNAMICS_TEXTS = ("dynamics_model", "dynamics_source_run")
DYNAMICS_NUMBERS = ("command_delay_s", "first_order_error_frac", "yoerger_error_frac")
# The held-out step sequence: fractions of the command range on each side of the neutral
# (0, 50, 20, 80, 0, -40, -90, -10, 65, 0 % on a -100..100 % thruster), HOLD_S each, on the
# simulator step STEP_S; the step runs of docs/dynamics.md hold other levels for 3 s.
HELD_OUT = (0.0, 0.5, 0.2, 0.8, 0.0, -0.4, -0.9, -0.1, 0.65, 0.0)
HOLD_S = 1.2
STEP_S = 0.001


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


def dynamics_elements(dp: dict[str, float | str] | None, indent: str,
                      keys: tuple[str, ...] = DYNAMICS_NUMBERS) -> str:
    """rigtool_* elements naming the dynamics' source and what the simulator leaves out (the
    numbers `keys` of the dynamics' parameters)."""
    if dp is None:
        return ""
    texts = "".join(f"{indent}<rigtool_{k}>{xml_text(str(dp[k]))}</rigtool_{k}>\n"
                    for k in DYNAMICS_TEXTS if k in dp)
    nums = "".join(f"{indent}<rigtool_{k}>{num(float(dp[k]))}</rigtool_{k}>\n"
                   for k in keys if math.isfinite(float(dp.get(k, math.nan))))
    return texts + nums


def held_out(x: ExportInput) -> tuple[np.ndarray, np.ndarray]:
    """(t, command) of the held-out sequence: HELD_OUT's fractions of the measured command
    range on each side of the neutral, HOLD_S each, every STEP_S."""
    curve = x.sec.curve
    neutral = float(x.cal.neutral_command)
    up, down = float(np.max(curve.command)) - neutral, neutral - float(np.min(curve.command))
    levels = np.array([neutral + f * (up if f >= 0 else down) for f in HELD_OUT])
    t = np.arange(0.0, HOLD_S * len(HELD_OUT), STEP_S)
    return t, levels[np.minimum((t / HOLD_S).astype(int), len(HELD_OUT) - 1)]


def first_order_state(tau: float, setpoint: np.ndarray, t: np.ndarray) -> np.ndarray:
    """DynamicsFirstOrder::update once per step, as Dynamics.cc runs it."""
    out = np.empty(t.size)
    state, prev = 0.0, None
    for i, (u, now) in enumerate(zip(setpoint, t, strict=True)):
        if prev is not None:
            a = math.exp(-(now - prev) / tau)
            state = state * a + (1.0 - a) * u
        prev, out[i] = now, state
    return out


def yoerger_state(yo: tuple[float, float, float], demand: np.ndarray, dt: float) -> np.ndarray:
    """Yoerger's w' = beta f_cmd - alpha w|w| stepped explicitly (as a fixed plugin would),
    one beta: a reverse demand scaled by beta_reverse / beta_forward."""
    alpha, b_fwd, b_rev = yo
    u = np.where(demand >= 0, demand, demand * b_rev / b_fwd)
    out, w = np.empty(u.size), 0.0
    for i, ui in enumerate(u):
        w += dt * (b_fwd * ui - alpha * w * abs(w))
        out[i] = w
    return out


def heldout_errors(x: ExportInput) -> dict[str, float]:
    """Largest and RMS error (fractions of full scale, the largest thrust measured) on the
    held-out sequence of what the block writes, against the identified model driven by the
    steady curve: `first_order_*` (the manager's setpoint through FirstOrder and
    LinearInterp), `yoerger_*` (rigtool_yoerger_* through Yoerger's equation and LinearInterp);
    empty without identified dynamics."""
    dp = x.dynamics_params()
    tau = time_constant(dp)
    if dp is None or not math.isfinite(tau):
        return {}
    w, f = speed_table(x)
    curve = x.sec.curve
    t, cmd = held_out(x)
    demand = np.interp(cmd, curve.command, curve.thrust_fit_n)
    truth = simulate(x.dynamics.dynamics.model, t, cmd,
                     lambda c: np.interp(c, curve.command, curve.thrust_fit_n))
    scale = float(np.max(np.abs(f)))
    states = {"first_order": first_order_state(tau, np.interp(demand, f, w), t)}
    yo = yoerger_rad_s(dp)
    if yo is not None:
        states["yoerger"] = yoerger_state(yo, demand, STEP_S)
    out = {}
    for name, state in states.items():
        err = np.interp(state, w, f) - truth
        out[f"{name}_heldout_max_frac"] = float(np.max(np.abs(err))) / scale
        out[f"{name}_heldout_rms_frac"] = float(np.sqrt(np.mean(err**2))) / scale
    return out


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


def _dynamics(x: ExportInput, dp: dict[str, float | str] | None,
              errors: dict[str, float]) -> tuple[str, str]:
    """The <dynamics> block and its comment (with the held-out errors of what is written)."""
    tau = time_constant(dp)
    if not math.isfinite(tau):
        return "    <type>ZeroOrder</type>\n", f"ZeroOrder dynamics (no lag): {no_lag(x, dp)}."
    yo = yoerger_rad_s(dp)
    note = (f"FirstOrder dynamics: speed lag with timeConstant {tau:.6g} s (rigtool's single "
            "time constant); the command delay, an inflow overshoot and a separate "
            f"spin-down constant are not in this plugin. {_heldout_note(x, dp, errors)}")
    if yo is not None:
        note += (" rigtool_yoerger_alpha/beta_*: Yoerger's w' = beta f_cmd - alpha w|w| "
                 "(w rad/s, f_cmd N); not written as <type>Yoerger</type> because this "
                 "plugin's Yoerger update never advances its previous time (dt grows with "
                 "simulation time). On the same sequence, stepped every "
                 f"{STEP_S * 1e3:g} ms: {_figure(errors, 'yoerger')}.")
    return f"    <type>FirstOrder</type>\n    <timeConstant>{num(tau)}</timeConstant>\n", note


def _figure(errors: dict[str, float], name: str) -> str:
    """'largest X % (RMS Y %) of full scale' of one held-out result."""
    return (f"largest error {100 * errors[f'{name}_heldout_max_frac']:.2f} % of full scale "
            f"(RMS {100 * errors[f'{name}_heldout_rms_frac']:.2f} %)")


def _heldout_note(x: ExportInput, dp: dict[str, float | str], errors: dict[str, float]) -> str:
    """What the held-out figure of the FirstOrder lag is and how it was measured."""
    _, f = speed_table(x)
    levels = ", ".join(f"{100 * v:g}" for v in HELD_OUT)
    return (f"Held out (a step sequence the fit did not see: {levels} % of the command range "
            f"on each side of the neutral, {HOLD_S:g} s each; the manager's speed setpoint "
            "through this FirstOrder and LinearInterp against the identified "
            f"{dp.get('dynamics_model')} model): {_figure(errors, 'first_order')}, full "
            f"scale {float(np.max(np.abs(f))):.6g} N (rigtool_first_order_heldout_*_frac).")


def manager_comment(w: np.ndarray, f: np.ndarray) -> str:
    """The uuv_thruster_manager parameters that invert this block's table (an XML comment of
    YAML: numbers and fixed text only)."""
    table = {"input": [float(num(v)) for v in w], "output": [float(num(v)) for v in f]}
    return ("<!-- uuv_thruster_manager inverts its own conversion_fcn, not this plugin's "
            "table: for speed setpoints on this thruster's curve, set these in its "
            "thruster_manager.yaml (the launch file's config_file; with thrusters of different "
            "models, make conversion_fcn and conversion_fcn_params lists and put these at "
            "the index that is this block's thrusterID). The stock conversion_fcn proportional "
            "describes another curve. max_thrust (N) clips each thrust before the inversion; "
            "beyond the table numpy.interp holds its ends.\n"
            "thruster_manager:\n  conversion_fcn: custom\n  conversion_fcn_params:\n"
            + "".join(f"    {k}: {yaml_value(v)}\n" for k, v in table.items()) + "-->\n")


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
    errors = heldout_errors(x)
    dyn, dyn_note = _dynamics(x, dp, errors)
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
            "thrustMin/thrustMax: the measured thrust range (N).")
            + manager_comment(w, f) +
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
            + _yoerger_elements(dp) + dynamics_elements(dp, "  ", ("command_delay_s",))
            + "".join(f"  <rigtool_{k}>{num(v)}</rigtool_{k}>\n" for k, v in errors.items())
            + text_elements(x, "  ")
            + "</plugin>\n")
