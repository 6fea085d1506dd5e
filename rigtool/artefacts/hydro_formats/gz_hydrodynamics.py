"""gz-sim's Hydrodynamics system block (gz::sim::systems::Hydrodynamics) for the vehicle's
body link: the diagonal added mass (xDotU ...), linear damping (xU ...) and quadratic damping
(xUabsU ...) derivatives.

From the source (FOLLOWS): Configure reads each derivative as an SDF element named by the
SNAME letters, force/moment axis "xyzkmn" then velocity "UVWPQR": `<xU>` (linear),
`<xUabsU>` (the |v| quadratic; `<xUU>` is a different, unstable term), `<xDotU>` (added mass);
every absent one is 0. PreUpdate takes the link's velocity in the link's own frame and applies
the force -(-Ma nu_dot) - D(nu) nu with D(i,i) = -(xU + xUabsU |u|), so the force is
xDotU u_dot + (xU + xUabsU |u|) u: the SNAME derivatives go in with their own sign (negative
for a real hull; the header says so for the added mass). The frame is the link frame (Gazebo:
x forward, y left, z up), a half turn about x from FRD, which leaves every diagonal term
unchanged. Velocities are taken and the wrench applied at the link origin, so the link origin
must be the model's origin (the centre of gravity). Buoyancy is not this system's (use
gz-sim's Buoyancy system); <namespace> makes it listen to /model/NS/ocean_current. The system
also applies an added-mass Coriolis term built from the xDotU terms (HydrodynamicsUtils.hh
buildCoriolisMatrix); as written at 93bbf3e it is +C_A(nu) nu, the opposite sign of Fossen's
-C_A(nu) nu (gz-sim 8's is another, not skew-symmetric, matrix). The block keeps the system's
default and says so; <disable_coriolis>true</disable_coriolis> removes the term.
"""

from __future__ import annotations

from typing import Any

from rigtool.artefacts.hydro_formats.common import (
    HydroOptions,
    comment,
    frd_to_flu,
    link_needs,
    missing,
    num,
    text_element,
    values,
)

FILE = "hydrodynamics_gz.sdf"
FOLLOWS = ("gz-sim main at 93bbf3e (gazebosim/gz-sim: src/systems/hydrodynamics/"
           "Hydrodynamics.cc, Hydrodynamics.hh, HydrodynamicsUtils.hh; last changed at "
           "57e28a0); names and signs the same in gz-sim8_8.9.0")
GROUPS = ("added_mass", "linear_damping", "quadratic_damping")
FORCES = "xyzkmn"
VELOCITIES = "UVWPQR"


def element_names(group: str) -> list[str]:
    """The six diagonal element names the system reads for one group."""
    if group == "added_mass":
        return [f"{f}Dot{v}" for f, v in zip(FORCES, VELOCITIES, strict=True)]
    if group == "linear_damping":
        return [f"{f}{v}" for f, v in zip(FORCES, VELOCITIES, strict=True)]
    return [f"{f}{v}abs{v}" for f, v in zip(FORCES, VELOCITIES, strict=True)]


def needs(model: dict[str, Any], options: HydroOptions) -> list[str]:
    """Every diagonal derivative and the link name."""
    return missing(model, GROUPS) + link_needs(options)


def render(model: dict[str, Any], options: HydroOptions) -> str:
    """The <plugin> block's text."""
    body = model["rigid_body"]
    cog = frd_to_flu(body["cog_m"])
    params = "".join(f"  <{tag}>{num(v)}</{tag}>\n" for group in GROUPS
                     for tag, v in zip(element_names(group), values(model, group), strict=True))
    ns = "" if options.namespace is None else text_element("namespace", options.namespace, "  ")
    return (comment(
        "rigtool vehicle model (rigtool-vehicle-model v1) for gz-sim's Hydrodynamics system. "
        "Fossen/SNAME derivatives with their sign: force = xDotU u_dot + (xU + xUabsU |u|) u "
        "in the link frame (x forward, y left, z up; diagonal terms are the same as in FRD). "
        "The link origin must be the model's origin, the centre of gravity the derivatives "
        f"refer to (cog_m in link axes: {' '.join(num(c) for c in cog)} m). Add gz-sim's "
        "Buoyancy system for the restoring forces. With DART, <fluid_added_mass> on the link "
        "(xx = -xDotU ...) can replace the xDotU terms: never both. The system also adds a "
        "Coriolis term built from the xDotU terms; read at 93bbf3e it applies +C_A(nu) nu, "
        "the opposite of Fossen's -C_A(nu) nu (docs/vehicle-formats.md); "
        "<disable_coriolis>true</disable_coriolis> removes it.")
        + '<plugin filename="gz-sim-hydrodynamics-system" '
        'name="gz::sim::systems::Hydrodynamics">\n'
        + text_element("link_name", options.link, "  ") + ns + params
        + text_element("rigtool_model_name", model["name"], "  ")
        + "</plugin>\n")
