"""A gz-sim Thruster system block in force-command mode: the thrust command (N) is clamped to
the measured thrust range and zeroed below the smallest thrust the thruster makes (<deadband>,
N); the propeller turns at w with C_T rho D^4 w|w| = thrust, C_T = C_p / (rho D^4 (2 pi /
60)^2) from C_p_fwd in N/(r/min)^2 (the system takes one coefficient; docs/formats-simulators.md).
Beside the clamps, the speed clamps (rad/s) angular-velocity mode needs: Thruster.cc clamps an
angular-velocity command with the same two elements (OnCmdAngVel, lines 549-558 at
gz-sim8_8.9.0; OnCmdThrust 517-526, ApplyDeadband 624-631 on the thrust in both modes, the
clamps read at 430-451, cmdMin/cmdMax -1000/1000 at 115-119).
"""

from __future__ import annotations

import math

from rigtool.artefacts.encode import xml_text
from rigtool.artefacts.vehicle import RAD_S_PER_RPM, ExportInput, model_text

FILE = "thruster_gazebo.sdf"
FOLLOWS = ("gz-sim 8 (Harmonic; gazebosim/gz-sim tag gz-sim8_8.9.0, "
           "src/systems/thruster/Thruster.cc, unchanged in behaviour on main at 93bbf3e)")


def needs(x: ExportInput) -> list[str]:
    """C_p forward, the propeller diameter and water density, the joint and namespace."""
    out = []
    if not math.isfinite(x.coef("C_p_fwd")):
        out.append("no C_p_fwd (no forward branch, or no speed feedback), so there is no thrust "
                   "coefficient")
    if not x.cal.propeller_diameter_m:
        out.append("no propeller diameter: set metadata.propeller_diameter_m in the protocol")
    if not x.cal.water_density_kg_m3:
        out.append("no water density: set metadata.water_density_kg_m3 in the protocol")
    if not x.options.joint:
        out.append("no propeller joint: give --joint NAME (the joint in your model)")
    if not x.options.namespace:
        out.append("no namespace: give --namespace NAME (the thruster's topic namespace)")
    return out


LAG_KEYS = ("time_constant_s", "rise_time_constant_s", "fall_time_constant_s",
            "inflow_time_constant_s", "inflow_gain", "command_delay_s", "dynamics_reverse_ratio",
            "yoerger_alpha", "yoerger_beta_forward", "yoerger_beta_reverse")


def _num(v: float | str) -> str:
    return f"{float(v):.9g}"


def thrust_limits(x: ExportInput) -> tuple[float, float, float] | None:
    """(min thrust, max thrust, dead band) in N from the thrust map: the measured range (0
    included, so a one-way thruster is not pushed off zero) and the smaller of the two
    directions' smallest thrusts (below it the vehicle's map gives the neutral command)."""
    ends = [(d, float(f[0]), float(f[-1])) for d, f, _ in x.map.tables if len(f)]
    if not ends:
        return None
    lo = min(0.0, *(a for _, a, _ in ends))
    hi = max(0.0, *(b for _, _, b in ends))
    smallest = [a if d == "forward" else -b for d, a, b in ends]
    band = min((s for s in smallest if s > 0), default=0.0)
    return lo, hi, band


def angvel_limits(x: ExportInput) -> tuple[float, float] | None:
    """(min, max) angular-velocity command in rad/s for use_angvel_cmd true: the speeds at
    which the block's one coefficient gives the measured thrust range (thrust = C_T rho D^4
    w|w|, AngularVelToThrust), so that mode clamps to the same thrusts force mode does."""
    limits = thrust_limits(x)
    k = x.coef("C_p_fwd") / RAD_S_PER_RPM**2  # C_T rho D^4, N/(rad/s)^2
    if limits is None or not k > 0:
        return None
    lo, hi, _ = limits
    return -math.sqrt(-lo / k), math.sqrt(hi / k)


def _angvel(x: ExportInput) -> tuple[str, str]:
    """The rigtool_angvel_* elements and the comment saying what changes with the mode."""
    speeds = angvel_limits(x)
    if speeds is None:
        return "", ""
    w_lo, w_hi = speeds
    return (f"  <rigtool_angvel_min_cmd>{w_lo:.9g}</rigtool_angvel_min_cmd>\n"
            f"  <rigtool_angvel_max_cmd>{w_hi:.9g}</rigtool_angvel_max_cmd>\n",
            " Angular-velocity mode: gz-sim clamps that command (rad/s) with the same "
            "max_thrust_cmd and min_thrust_cmd, so change three elements together: "
            "use_angvel_cmd true, max_thrust_cmd to rigtool_angvel_max_cmd "
            f"({w_hi:.6g}) and min_thrust_cmd to rigtool_angvel_min_cmd ({w_lo:.6g}), the "
            "speeds (rad/s) at which C_T gives the measured thrust range; keeping the "
            "thrusts (N) there clamps the speed to their square root and loses most of the "
            "thrust. thrust_coefficient, fluid_density, propeller_diameter and deadband (N, "
            "applied to the thrust in both modes) stay.")


def render(x: ExportInput) -> str:
    """The <plugin> block's text."""
    cp, rev = x.coef("C_p_fwd"), x.coef("C_p_rev")
    rho, d = x.cal.water_density_kg_m3, x.cal.propeller_diameter_m
    c_t = cp / (rho * d**4 * RAD_S_PER_RPM**2)
    rev_note = ("" if not math.isfinite(rev) else
                f" Reverse: C_T = {rev / (rho * d**4 * RAD_S_PER_RPM**2):.6g}, but the system "
                "takes one coefficient, so in reverse the joint turns at sqrt(C_p_rev/C_p_fwd) "
                "of the measured speed (the force is the command, not from the speed).")
    texts = {f"rigtool_{k}": v for k, v in x.texts.items()}
    comment = " ".join(x.head(list(texts)))
    limits = thrust_limits(x)
    clamp, clamp_note = "", ""
    if limits is not None:
        lo, hi, band = limits
        clamp = (f"  <max_thrust_cmd>{hi:.9g}</max_thrust_cmd>\n"
                 f"  <min_thrust_cmd>{lo:.9g}</min_thrust_cmd>\n"
                 + (f"  <deadband>{band:.9g}</deadband>\n" if band > 0 else ""))
        clamp_note = (" Thrust commands (N) are clamped to the measured range; deadband: a "
                      "command of smaller magnitude gives no thrust (N; the smaller of the "
                      "two directions' smallest thrusts).")
    angvel, angvel_note = _angvel(x)
    dp = x.dynamics_params()
    lag, lag_note = "", " No time constant identified."
    if dp is not None:
        lag_note = (" The rigtool_* dynamics elements are those of the model "
                    f"rigtool_dynamics_model: {model_text(dp)}. The Thruster system has no lag "
                    "and ignores them.")
        texts |= {f"rigtool_{k}": str(dp[k]) for k in ("dynamics_model", "dynamics_source_run",
                                                       "yoerger_state_unit") if k in dp}
        lag = "".join(f"  <rigtool_{k}>{_num(dp[k])}</rigtool_{k}>\n" for k in LAG_KEYS
                      if k in dp and math.isfinite(float(dp[k])))
    return (f"<!-- {comment} -->\n"
            f"<!-- Force mode (use_angvel_cmd false): the thrust command in N is the force "
            "applied. The joint turns at w with C_T rho D^4 w|w| = thrust, w in rad/s, C_T "
            f"from C_p_fwd = {cp:.6g} N/(r/min)^2.{rev_note}{clamp_note}{angvel_note}{lag_note} -->\n"
            '<plugin filename="gz-sim-thruster-system" name="gz::sim::systems::Thruster">\n'
            f"  <namespace>{xml_text(x.options.namespace or '')}</namespace>\n"
            f"  <joint_name>{xml_text(x.options.joint or '')}</joint_name>\n"
            "  <use_angvel_cmd>false</use_angvel_cmd>\n"
            f"  <thrust_coefficient>{c_t:.9g}</thrust_coefficient>\n"
            f"  <fluid_density>{rho:.9g}</fluid_density>\n"
            f"  <propeller_diameter>{d:.9g}</propeller_diameter>\n"
            f"{clamp}{angvel}{lag}"
            + "".join(f"  <{tag}>{xml_text(text)}</{tag}>\n" for tag, text in texts.items())
            + "</plugin>\n")
