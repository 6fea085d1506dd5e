"""A Stonefish thruster actuator (<actuator type="thruster">): the propeller speed -> thrust
table as its linear_interpolation thrust model (the deadband model's coefficients beside it),
the identified lag as first_order or yoerger rotor dynamics, a normalised setpoint whose full
scale is the largest speed measured (docs/formats-simulators.md)."""

from __future__ import annotations

import math

import numpy as np

from rigtool.artefacts.encode import xml_text
from rigtool.artefacts.formats.uuv import (
    QUADRATIC_SPEED,
    comment,
    dynamics_elements,
    no_lag,
    num,
    numbers,
    rotor_constants,
    speed_needs,
    speed_table,
    text_elements,
    time_constant,
    yoerger_rad_s,
)
from rigtool.artefacts.vehicle import RAD_S_PER_RPM, ExportInput

FILE = "thruster_stonefish.xml"
FOLLOWS = ("Stonefish 1.6 (patrykcieslak/stonefish at b21eb8e: core/ScenarioParser.cpp, "
           "actuators/ActuatorDynamics.h, actuators/Thruster.cpp, docs/actuators.rst)")


def needs(x: ExportInput) -> list[str]:
    """The link, the propeller diameter and speed feedback."""
    out = speed_needs(x)
    if not x.options.link:
        out.append("no link: give --link NAME (the robot link the thruster is attached to)")
    if not x.options.mesh:
        out.append("no propeller mesh: give --mesh FILE (the scenario parser requires one)")
    if not x.options.material:
        out.append("no propeller material: give --material NAME (one of your scenario's "
                   "materials; the scenario parser requires one)")
    if not x.cal.propeller_diameter_m:
        out.append("no propeller diameter: set metadata.propeller_diameter_m in the protocol "
                   "(<propeller diameter>, required by the scenario parser)")
    return out


def _rotor_dynamics(x: ExportInput, w_ref: float) -> tuple[str, str]:
    """The <rotor_dynamics> element and its comment."""
    dp = x.dynamics_params()
    tau = time_constant(dp)
    yo = yoerger_rad_s(dp)
    if dp is not None and dp.get("dynamics_model") in QUADRATIC_SPEED and yo is not None:
        alpha = yo[0]
        return ('  <rotor_dynamics type="yoerger">\n'
                f'    <alpha value="{num(alpha)}"/>\n'
                f'    <beta value="{num(alpha * w_ref)}"/>\n'
                "  </rotor_dynamics>\n",
                "yoerger rotor dynamics w' = beta s max_setpoint - alpha w|w| (w rad/s): the "
                "setpoint s is the thrust demand as a fraction of "
                f"{x.coef('C_p_fwd') / RAD_S_PER_RPM**2 * w_ref**2:.6g} N (forward "
                "C_p at max_setpoint); reverse gives C_p_rev/C_p_fwd of the demand.")
    if not math.isfinite(tau):
        return ('  <rotor_dynamics type="zero_order"/>\n',
                f"zero_order rotor dynamics (no lag): {no_lag(x, dp)}; the setpoint s is the speed "
                "as a fraction of max_setpoint.")
    return ('  <rotor_dynamics type="first_order">\n'
            f'    <time_constant value="{num(tau)}"/>\n  </rotor_dynamics>\n',
            f"first_order rotor dynamics, time constant {tau:.6g} s (rigtool's single "
            "time constant; explicit Euler, so keep the step well below it): the setpoint "
            "s is the speed as a fraction of max_setpoint; the command delay and an inflow "
            "overshoot are not in this model.")


def render(x: ExportInput) -> str:
    """The <actuator> element's text."""
    w, f = speed_table(x)
    w_ref = float(np.max(np.abs(w)))
    rotor, rotor_note = _rotor_dynamics(x, w_ref)
    k = rotor_constants(x)
    coeffs = "" if k is None else (
        f'    <thrust_coeff forward="{num(k[0])}" reverse="{num(k[1])}"/>\n'
        '    <deadband lower="0" upper="0"/>\n')
    coeff_note = ("" if k is None else
                  ' For the coefficient model set type="deadband": thrust = forward w|w| or '
                  "reverse w|w| (C_p of each direction in N/(rad/s)^2; no dead band in "
                  "speed).")
    name = x.cal.thruster_id or "thruster"
    head = " ".join(x.head([f"rigtool_{k}" for k in x.texts]))
    return (comment(head) + comment(
            f"Setpoint: normalised, s in [-1, 1] times max_setpoint = {w_ref:.6g} rad/s "
            f"(the largest speed measured). {rotor_note} The linear_interpolation thrust "
            "model maps propeller speed (rad/s) to thrust (N): each measured command's mean "
            f"speed and fitted thrust, {w.size} points.{coeff_note} Keep right=\"true\" (a "
            "left-handed propeller negates the thrust). The origin is the thruster's place on "
            "your vehicle: set it where you include this element.") +
            f'<actuator name="{xml_text(name)}" type="thruster">\n'
            f'  <specs max_setpoint="{num(w_ref)}" inverted_setpoint="false" '
            'normalized_setpoint="true"/>\n'
            f'  <propeller diameter="{num(x.cal.propeller_diameter_m or math.nan)}" '
            'right="true">\n'
            f'    <mesh filename="{xml_text(x.options.mesh or "")}" scale="1.0"/>\n'
            f'    <material name="{xml_text(x.options.material or "")}"/>\n'
            "  </propeller>\n"
            f"{rotor}"
            '  <thrust_model type="linear_interpolation">\n'
            f'    <input value="{numbers(w)}"/>\n'
            f'    <output value="{numbers(f)}"/>\n'
            f"{coeffs}  </thrust_model>\n"
            '  <origin xyz="0 0 0" rpy="0 0 0"/>\n'
            f'  <link name="{xml_text(x.options.link or "")}"/>\n'
            + dynamics_elements(x.dynamics_params(), "  ") + text_elements(x, "  ")
            + "</actuator>\n")
