"""uuv_simulator's underwater-object plugin (libuuv_underwater_object_ros_plugin.so) with one
<link> whose <hydrodynamic_model> is the `fossen` type (HMFossen): added_mass (the 36 numbers
of M_A, row by row), linear_damping and quadratic_damping (6 numbers each, the diagonal),
volume, center_of_buoyancy, and the plugin's fluid_density.

From the source (FOLLOWS): HMFossen fills Ma(row, col) = added_mass[6 row + col] and applies
-Ma nu_dot, so added_mass is M_A = -diag(X_udot, ...), positive for a real hull. Its damping
matrix is D = -DLin - DNonLin |nu| and the force -D nu = (DLin + DNonLin |nu|) nu, so
linear_damping and quadratic_damping are the SNAME X_u ... and X_u|u| ... with their own sign
(negative, as in rexrov.gazebo.xacro). The model works in FRD: it turns the link's Gazebo
velocities with ToNED (y and z negated, a half turn about x) and the forces back with FromNED,
so diagonal terms carry over unchanged. The centre of buoyancy is not converted: SetCoB keeps
it in the link frame (x forward, y left, z up) and the buoyancy force (volume x fluid density
x the world's gravity, upward) is applied there, relative to the link origin; so cob_m has y
and z negated here. volume = buoyancy_n / (water density x gravity). The link origin must be
the model's origin (the centre of gravity). The namespace option is not used: the ROS plugin
names its topics and services after the Gazebo model.
"""

from __future__ import annotations

from typing import Any

from rigtool.artefacts.encode import xml_text
from rigtool.artefacts.hydro_formats.common import (
    HydroOptions,
    comment,
    frd_to_flu,
    link_needs,
    missing,
    num,
    numbers,
    text_element,
    values,
)

FILE = "hydrodynamics_uuv.xml"
FOLLOWS = ("uuv_simulator 0.6.13 (uuvsimulator/uuv_simulator at bfb40cb, uuv_gazebo_plugins: "
           "HydrodynamicModel.cc (HMFossen; last changed at 72aebc0), BuoyantObject.cc, "
           "UnderwaterObjectPlugin.cc; uuv_descriptions/urdf/rexrov.gazebo.xacro)")
PLUGIN_FILE = "libuuv_underwater_object_ros_plugin.so"
GROUPS = ("added_mass", "linear_damping", "quadratic_damping")


def added_mass_matrix(model: dict[str, Any]) -> list[list[float]]:
    """M_A = -diag(X_udot, Y_vdot, Z_wdot, K_pdot, M_qdot, N_rdot), 6x6."""
    diag = [0.0 - v for v in values(model, "added_mass")]  # 0.0 - v: no "-0.0"
    return [[diag[i] if i == j else 0.0 for j in range(6)] for i in range(6)]


def volume_m3(model: dict[str, Any]) -> float:
    """The displaced volume that gives the model's buoyancy: B / (rho g)."""
    body = model["rigid_body"]
    return body["buoyancy_n"] / (body["water_density_kg_m3"] * body["gravity_m_s2"])


def needs(model: dict[str, Any], options: HydroOptions) -> list[str]:
    """Every diagonal derivative and the link name."""
    return missing(model, GROUPS) + link_needs(options)


def render(model: dict[str, Any], options: HydroOptions) -> str:
    """The <plugin> block's text."""
    body = model["rigid_body"]
    rows = "".join(f"        {numbers(row)}\n" for row in added_mass_matrix(model))
    cob, cog = frd_to_flu(body["cob_m"]), frd_to_flu(body["cog_m"])
    return (comment(
        "rigtool vehicle model (rigtool-vehicle-model v1) for uuv_simulator's HMFossen "
        "(type fossen). added_mass: M_A = -diag(X_udot ...), row by row; linear_damping, "
        "quadratic_damping: SNAME X_u ..., X_u|u| ... with their sign. center_of_buoyancy: "
        "Gazebo link axes (x forward, y left, z up), so FRD y and z negated. volume = "
        f"buoyancy_n / (rho g) = {num(body['buoyancy_n'])} / ({num(body['water_density_kg_m3'])}"
        f" x {num(body['gravity_m_s2'])}); the plugin multiplies by the world's gravity. The "
        "link origin must be the model's origin, the centre of gravity (cog_m in link axes: "
        f"{numbers(cog)} m). Add <box> (width, length, height) to the link for the "
        "surface crossing; uuv warns that Gazebo's own bounding box is wrong.")
        + f'<plugin name="uuv_plugin" filename="{PLUGIN_FILE}">\n'
        f"  <fluid_density>{num(body['water_density_kg_m3'])}</fluid_density>\n"
        "  <flow_velocity_topic>hydrodynamics/current_velocity</flow_velocity_topic>\n"
        f'  <link name="{xml_text(options.link)}">\n'
        "    <neutrally_buoyant>0</neutrally_buoyant>\n"
        f"    <volume>{num(volume_m3(model))}</volume>\n"
        f"    <center_of_buoyancy>{numbers(cob)}</center_of_buoyancy>\n"
        "    <hydrodynamic_model>\n"
        "      <type>fossen</type>\n"
        f"      <added_mass>\n{rows}      </added_mass>\n"
        f"      <linear_damping>{numbers(values(model, 'linear_damping'))}</linear_damping>\n"
        "      <quadratic_damping>"
        f"{numbers(values(model, 'quadratic_damping'))}</quadratic_damping>\n"
        "    </hydrodynamic_model>\n"
        "  </link>\n"
        + text_element("rigtool_model_name", model["name"], "  ")
        + "</plugin>\n")
