"""Vehicle-simulator blocks from vehicle_model.json, read the way their consumers read them
(issue 48, docs/vehicle-formats.md).

The BlueROV2 (Wu 2018) parameters of the vehicle twin go through each block; each block is
parsed back with xml.etree and its numbers evaluated with the consumer's own equations, as its
source has them: gz-sim's Hydrodynamics system (Configure's element names, PreUpdate's added
mass and damping: force = xDotU u_dot + (xU + xUabsU |u|) u in the link frame) and
uuv_simulator's HMFossen (added_mass row by row, D = -DLin - DNonLin |nu|, the added Coriolis
term, ToNED/FromNED around it, buoyancy at center_of_buoyancy in the link frame). Both must give
Fossen's forces in FRD for the same physical motion seen in Gazebo's link axes (x forward,
y left, z up). Both blocks also go through the real SDFormat parser when libsdformat-dev is
installed. Hostile names, null parameters and crafted documents are refused or encoded.
"""

from __future__ import annotations

import copy
import json
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from rigtool.artefacts.hydro_formats import (
    HYDRO_FORMATS,
    HydroOptions,
    check_hydro_formats,
    gz_hydrodynamics,
    stonefish,
    uuv_fossen,
    write_hydro_formats,
)
from rigtool.artefacts.vehicle_model import GROUPS, validate_model, write_model
from rigtool.errors import ConfigError, UsageError
from rigtool.sim.vehicle_params import BLUEROV2, BLUEROV2_HEAVY, VehicleParams

from .test_export_simulators import sdf_check, sdf_checker  # noqa: F401 (a fixture)

P = np.diag([1.0, -1.0, -1.0])  # FRD <-> Gazebo's link axes: a half turn about x
P6 = np.diag([1.0, -1.0, -1.0, 1.0, -1.0, -1.0])
OPTIONS = HydroOptions(link="base_link", namespace="bluerov2")
HOSTILE = ["</plugin><evil/>", "\"'<>&", "]]>", "-->", "a\nb\r\nc\td", "\u00e9\u4e2d\U0001f600",
           "\u2028\u2029\x85", "<![CDATA[x]]>", "&amp;&#0;", "\x00\x01\x1b\x7f"]


def model_doc(v: VehicleParams) -> dict:
    """vehicle_model.json of a published parameter set (every derivative identified)."""
    def param(x: float) -> dict:
        return {"value": x, "ci95": [x - 0.1 * abs(x), x + 0.1 * abs(x)], "reason": None}
    sets = (v.added_mass, v.linear_damping, v.quadratic_damping)
    inertia = [[v.inertia_kg_m2[i] if i == j else 0.0 for j in range(3)] for i in range(3)]
    return {"format": "rigtool-vehicle-model", "schema_version": 1, "name": v.name,
            "frame": "FRD",
            "rigid_body": {"mass_kg": v.mass_kg, "inertia_kg_m2": inertia,
                           "cog_m": list(v.cog_m), "cob_m": list(v.cob_m),
                           "weight_n": v.weight_n, "buoyancy_n": v.buoyancy_n,
                           "water_density_kg_m3": 1000.0, "gravity_m_s2": 9.81},
            "hydrodynamics": {group: {n: param(x) for n, x in zip(names, vals, strict=True)}
                              for (group, names), vals in zip(GROUPS.items(), sets,
                                                              strict=True)}}


@pytest.fixture(params=[BLUEROV2, BLUEROV2_HEAVY], ids=["bluerov2", "heavy"])
def vehicle(request) -> tuple[VehicleParams, dict]:
    """A published parameter set and its checked model."""
    return request.param, validate_model(model_doc(request.param), "test.json")


# ----- Fossen in FRD, the truth ------------------------------------------------------------


def fossen_added(v: VehicleParams, nu: np.ndarray, nu_dot: np.ndarray) -> np.ndarray:
    """-M_A nu_dot - C_A(nu) nu (Fossen 2011, eq. 6.43, diagonal M_A = -diag(X_udot ...))."""
    ma = -np.array(v.added_mass)
    a1, a2 = ma[:3] * nu[:3], ma[3:] * nu[3:]
    coriolis = np.concatenate([np.cross(a1, nu[3:]), np.cross(a1, nu[:3]) + np.cross(a2, nu[3:])])
    return -ma * nu_dot + coriolis


def fossen_damping(v: VehicleParams, nu: np.ndarray) -> np.ndarray:
    """X = X_u u + X_u|u| u|u| on every axis."""
    return (np.array(v.linear_damping) + np.array(v.quadratic_damping) * np.abs(nu)) * nu


# ----- the consumers, from their source ----------------------------------------------------


def gz_parameters(root: ET.Element) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hydrodynamics::Configure: Ma(i, j) from <{f}Dot{V}>, linear from <{f}{V}>, |v|
    quadratic from <{f}{V}abs{V}> over "xyzkmn" x "UVWPQR"; an absent element is 0."""
    def get(tag: str) -> float:
        return float(root.findtext(tag) or 0.0)
    f, vel = "xyzkmn", "UVWPQR"
    ma = np.array([[get(f"{f[i]}Dot{vel[j]}") for j in range(6)] for i in range(6)])
    lin = np.array([[get(f"{f[i]}{vel[j]}") for j in range(6)] for i in range(6)])
    quad = np.array([[[get(f"{f[i]}{vel[j]}abs{vel[k]}") for k in range(6)] for j in range(6)]
                     for i in range(6)])
    return ma, lin, quad


def gz_wrench(root: ET.Element, state: np.ndarray, state_dot: np.ndarray) -> np.ndarray:
    """Hydrodynamics::PreUpdate's applied wrench (link frame) from added mass and damping:
    -(-Ma state_dot + D state), D(i, j) = -lin(i, j) - sum_k quad(i, j, k) |state(k)|."""
    ma, lin, quad = gz_parameters(root)
    d = -lin - np.einsum("ijk,k->ij", quad, np.abs(state))
    return -(-ma @ state_dot + d @ state)


def uuv_link(root: ET.Element) -> ET.Element:
    """The plugin's one <link>."""
    links = root.findall("link")
    assert len(links) == 1
    return links[0]


def uuv_matrices(root: ET.Element) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """HMFossen's constructor: Ma(row, col) = added_mass[6 row + col] (Str2Vector: split on
    whitespace, std::stod each), a diagonal DLin and DNonLin from 6 numbers."""
    hm = uuv_link(root).find("hydrodynamic_model")
    assert hm.findtext("type") == "fossen"
    def vec(tag: str) -> list[float]:
        return [float(t) for t in hm.findtext(tag).split()]
    added, lin, quad = vec("added_mass"), vec("linear_damping"), vec("quadratic_damping")
    assert len(added) == 36 and len(lin) == 6 and len(quad) == 6
    return np.array(added).reshape(6, 6), np.diag(lin), np.diag(quad)


def _skew(a: np.ndarray) -> np.ndarray:
    """CrossProductOperator."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def uuv_wrench(root: ET.Element, lin_vel: np.ndarray, ang_vel: np.ndarray,
               acc_ned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """HMFossen::ApplyHydrodynamicForces: velRel = ToNED(link velocities); damping -D velRel,
    added -Ma acc, Coriolis -Ca velRel; (added + Coriolis, damping) back FromNED, link frame."""
    ma, d_lin, d_quad = uuv_matrices(root)
    ned = np.concatenate([P @ lin_vel, P @ ang_vel])
    d = -d_lin - d_quad * np.abs(ned)  # nonlinear terms on the diagonal only
    ab = ma @ ned
    sa = -_skew(ab[:3])
    ca = np.block([[np.zeros((3, 3)), sa], [sa, -_skew(ab[3:])]])
    added = -ma @ acc_ned - ca @ ned
    damping = -d @ ned
    return P6 @ added, P6 @ damping


# ----- blocks read back --------------------------------------------------------------------


def block(fmt: str, model: dict, options: HydroOptions = OPTIONS) -> ET.Element:
    """A block's root element, as an XML parser reads its ASCII text."""
    text = HYDRO_FORMATS[fmt].render(model, options)
    text.encode("ascii")
    return ET.fromstring(text)


def test_gz_names_and_values_are_the_sname_derivatives(vehicle):
    """Every element the system reads for the diagonal, the SNAME value with its own sign,
    exactly (repr); the link name and namespace."""
    v, model = vehicle
    root = block("gz-hydrodynamics", model)
    assert root.get("filename") == "gz-sim-hydrodynamics-system"
    assert root.get("name") == "gz::sim::systems::Hydrodynamics"
    assert root.findtext("link_name") == "base_link" and root.findtext("namespace") == "bluerov2"
    want = dict(zip(["xDotU", "yDotV", "zDotW", "kDotP", "mDotQ", "nDotR",
                     "xU", "yV", "zW", "kP", "mQ", "nR",
                     "xUabsU", "yVabsV", "zWabsW", "kPabsP", "mQabsQ", "nRabsR"],
                    v.added_mass + v.linear_damping + v.quadratic_damping, strict=True))
    got = {el.tag: float(el.text) for el in root if el.tag in want}
    assert got == want
    assert root.findtext("rigtool_model_name") == v.name
    no_ns = block("gz-hydrodynamics", model, HydroOptions(link="base_link"))
    assert no_ns.find("namespace") is None


def test_gz_forces_are_fossens_in_the_link_frame(vehicle):
    """The system's added-mass and damping wrench for a motion seen in Gazebo's link axes is
    Fossen's (FRD) for the same motion: the derivatives carry over with their sign."""
    v, model = vehicle
    root = block("gz-hydrodynamics", model)
    rng = np.random.default_rng(48)
    for _ in range(50):
        nu, nu_dot = rng.normal(0, 0.7, 6), rng.normal(0, 2.0, 6)
        got = P6 @ gz_wrench(root, P6 @ nu, P6 @ nu_dot)
        m_a = -np.array(v.added_mass)  # M_A = -diag(X_udot ...)
        want = -m_a * nu_dot + fossen_damping(v, nu)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def gz_coriolis(ma: np.ndarray, s: np.ndarray) -> np.ndarray:
    """HydrodynamicsUtils.hh buildCoriolisMatrix (gz-sim 93bbf3e), from the diagonal of Ma."""
    c = np.zeros((6, 6))
    for (i, j), (sign, k) in {
            (0, 4): (-1, 2), (0, 5): (1, 1), (1, 3): (1, 2), (1, 5): (-1, 0), (2, 3): (-1, 1),
            (2, 4): (1, 0), (3, 1): (-1, 2), (3, 2): (1, 1), (3, 4): (-1, 5), (3, 5): (1, 4),
            (4, 0): (1, 2), (4, 2): (-1, 0), (4, 3): (1, 5), (4, 5): (-1, 3), (5, 0): (-1, 1),
            (5, 1): (1, 0), (5, 3): (-1, 4), (5, 4): (1, 3)}.items():
        c[i, j] = sign * ma[k, k] * s[k]
    return c


def test_gz_coriolis_is_the_opposite_of_fossens_as_the_docs_say(vehicle):
    """What docs/vehicle-formats.md reports: the system's added-mass Coriolis force
    (-(-Cmat state)) is +C_A(nu) nu, Fossen's with the sign turned; the block keeps the
    system's default and its comment says so."""
    v, model = vehicle
    root = block("gz-hydrodynamics", model)
    ma, _, _ = gz_parameters(root)
    nu = np.random.default_rng(3).normal(0, 0.7, 6)
    applied = P6 @ (gz_coriolis(ma, P6 @ nu) @ (P6 @ nu))
    np.testing.assert_allclose(applied, -fossen_added(v, nu, np.zeros(6)), rtol=1e-12,
                               atol=1e-12)
    assert root.find("disable_coriolis") is None
    assert "opposite of Fossen's" in HYDRO_FORMATS["gz-hydrodynamics"].render(model, OPTIONS)


def test_uuv_values_follow_hmfossen(vehicle):
    """added_mass is M_A = -diag(X_udot ...) (positive), row by row; the damping lists are
    the SNAME terms with their sign; volume gives the model's buoyancy; fluid density; link."""
    v, model = vehicle
    root = block("uuv-fossen", model)
    assert root.get("filename") == "libuuv_underwater_object_ros_plugin.so"
    link = uuv_link(root)
    assert link.get("name") == "base_link"
    ma, d_lin, d_quad = uuv_matrices(root)
    np.testing.assert_array_equal(ma, np.diag([-x for x in v.added_mass]))
    assert list(np.diag(d_lin)) == list(v.linear_damping)
    assert list(np.diag(d_quad)) == list(v.quadratic_damping)
    rho = float(root.findtext("fluid_density"))
    assert rho == 1000.0
    volume = float(link.findtext("volume"))
    assert volume * rho * 9.81 == pytest.approx(v.buoyancy_n, rel=1e-14)
    assert link.findtext("neutrally_buoyant") == "0"
    assert root.findtext("rigtool_model_name") == v.name


def test_uuv_forces_are_fossens_through_its_ned_conversion(vehicle):
    """HMFossen's added-mass, Coriolis and damping wrench for a motion seen in Gazebo's link
    axes, turned back to FRD, is Fossen's."""
    v, model = vehicle
    root = block("uuv-fossen", model)
    rng = np.random.default_rng(1948)
    for _ in range(50):
        nu, nu_dot = rng.normal(0, 0.7, 6), rng.normal(0, 2.0, 6)
        added, damping = uuv_wrench(root, P @ nu[:3], P @ nu[3:], nu_dot)
        np.testing.assert_allclose(P6 @ added, fossen_added(v, nu, nu_dot), rtol=1e-12,
                                   atol=1e-12)
        np.testing.assert_allclose(P6 @ damping, fossen_damping(v, nu), rtol=1e-12, atol=1e-12)


def test_uuv_centre_of_buoyancy_is_in_gazebo_link_axes(vehicle):
    """BuoyantObject applies the upward buoyancy at center_of_buoyancy in the link frame,
    unconverted: its moment, for any attitude, is Fossen's r_b x f_b in FRD, so a centre of
    buoyancy above the centre of gravity rights the vehicle."""
    v, model = vehicle
    root = block("uuv-fossen", model)
    link = uuv_link(root)
    cob = np.array([float(t) for t in link.findtext("center_of_buoyancy").split()])
    assert list(cob) == [v.cob_m[0], -v.cob_m[1], -v.cob_m[2]]
    b = float(link.findtext("volume")) * float(root.findtext("fluid_density")) * 9.81
    rng = np.random.default_rng(7)
    for _ in range(20):
        up_flu = rng.normal(size=3)
        up_flu /= np.linalg.norm(up_flu)
        moment_flu = np.cross(cob, b * up_flu)
        moment_frd = np.cross(np.array(v.cob_m), b * (P @ up_flu))
        np.testing.assert_allclose(P @ moment_flu, moment_frd, rtol=1e-12, atol=1e-12)
    roll = 0.3  # starboard down: up in FLU link axes is (0, sin, cos)
    moment = np.cross(cob, b * np.array([0.0, math.sin(roll), math.cos(roll)]))
    assert moment[0] < 0  # rights the roll


def test_numbers_are_exact_and_plain():
    """repr numbers: a value needing 17 digits reads back to the same double; no -0."""
    doc = model_doc(BLUEROV2)
    doc["hydrodynamics"]["linear_damping"]["X_u"]["value"] = -0.1 - 0.2
    doc["hydrodynamics"]["added_mass"]["Y_vdot"]["value"] = 0.0
    doc["rigid_body"]["cob_m"] = [0.0, 0.0, 1e-5 / 3]
    model = validate_model(doc, "exact.json")
    assert float(block("gz-hydrodynamics", model).findtext("xU")) == -0.1 - 0.2
    root = block("uuv-fossen", model)
    assert float(root.find("link/hydrodynamic_model/linear_damping").text.split()[0]) == (
        -0.1 - 0.2)
    assert float(uuv_link(root).findtext("center_of_buoyancy").split()[2]) == -1e-5 / 3
    for fmt in ("gz-hydrodynamics", "uuv-fossen"):
        assert not re.search(r"(?<![\w.])-0\.0(?![\d])", HYDRO_FORMATS[fmt].render(
            model, OPTIONS).split("-->", 1)[1])


# ----- the real parser -----------------------------------------------------------------------


def _numbers_of(root: ET.Element) -> dict[str, list[float]]:
    """Every element whose text is a list of numbers, by path."""
    out = {}
    for el in root.iter():
        try:
            out[el.tag] = [float(t) for t in (el.text or "").split()]
        except ValueError:
            continue
    return {k: v for k, v in out.items() if v}


def test_blocks_pass_the_sdformat_parser(sdf_checker):  # noqa: F811 (the imported fixture)
    """libsdformat loads a world holding each block and reads back every number."""
    model = validate_model(model_doc(BLUEROV2), "sdf.json")
    for fmt in ("gz-hydrodynamics", "uuv-fossen"):
        text = HYDRO_FORMATS[fmt].render(model, OPTIONS)
        back = ET.fromstring(sdf_check(sdf_checker, text))
        assert _numbers_of(back) == _numbers_of(ET.fromstring(text)), fmt


# ----- hostile text, null parameters, stonefish ----------------------------------------------


def shape(root: ET.Element) -> list[tuple[str, list[str]]]:
    """Every element's tag and attribute names, in document order."""
    return [(e.tag, sorted(e.attrib)) for e in root.iter()]


def kept(text: str) -> str:
    """What an XML 1.0 reader gets back of `text` (forbidden controls dropped, surrogates
    replaced; everything else exactly)."""
    return re.sub("[\x00-\x08\x0b\x0c\x0e-\x1f]", "", text)


def test_hostile_names_keep_every_block_the_same(request):
    """Comment and CDATA ends, quotes, markup, line breaks, controls and non-ASCII text as
    the model name, link and namespace: each block is ASCII, parses to the same elements and
    gives the text back; SDFormat still loads it (when built); comments hold no user text."""
    try:
        checker = request.getfixturevalue("sdf_checker")
    except pytest.skip.Exception:
        checker = None
    plain = validate_model(model_doc(BLUEROV2), "plain.json")
    want = {fmt: shape(block(fmt, plain)) for fmt in ("gz-hydrodynamics", "uuv-fossen")}
    first_lines = {fmt: HYDRO_FORMATS[fmt].render(plain, OPTIONS).splitlines()[0]
                   for fmt in want}
    for text in HOSTILE:
        doc = model_doc(BLUEROV2)
        doc["name"] = text
        model = validate_model(doc, "hostile.json")
        opts = HydroOptions(link=text, namespace=text)
        for fmt in ("gz-hydrodynamics", "uuv-fossen"):
            body = HYDRO_FORMATS[fmt].render(model, opts)
            root = ET.fromstring(body.encode("ascii"))
            assert shape(root) == want[fmt], (fmt, text)
            assert root.findtext("rigtool_model_name") == kept(text)
            link = (root.findtext("link_name") if fmt == "gz-hydrodynamics"
                    else uuv_link(root).get("name"))
            assert link == kept(text)
            assert all(line.startswith("<!--") == (i == 0)
                       for i, line in enumerate(body.splitlines()))
            assert body.splitlines()[0] == first_lines[fmt]  # the comment: no user text
            if checker is not None:
                sdf_check(checker, body)


def test_a_null_parameter_is_named(tmp_path):
    """needs() names a derivative that was not identified, with the model's reason; nothing
    is written for any format then."""
    doc = model_doc(BLUEROV2)
    doc["hydrodynamics"]["quadratic_damping"]["K_pp"] = {
        "value": None, "ci95": None, "reason": "roll was not excited"}
    model = validate_model(doc, "null.json")
    for fmt in ("gz-hydrodynamics", "uuv-fossen"):
        reasons = HYDRO_FORMATS[fmt].needs(model, OPTIONS)
        assert len(reasons) == 1 and "K_pp" in reasons[0] and "roll was not excited" in (
            reasons[0])
        assert HYDRO_FORMATS[fmt].needs(model, HydroOptions(link=" "))[-1].startswith(
            "no link")
    with pytest.raises(UsageError, match="K_pp"):
        write_hydro_formats(model, tmp_path, ["gz-hydrodynamics", "uuv-fossen"], OPTIONS)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(UsageError, match="unknown vehicle format"):
        check_hydro_formats(["gazebo"], model, OPTIONS)
    doc["hydrodynamics"]["added_mass"]["N_rdot"] = {
        "value": None, "ci95": None, "reason": "\x1b[31mred\nline\u202e" + "x" * 1000}
    reasons = gz_hydrodynamics.needs(validate_model(doc, "null.json"), OPTIONS)
    assert "N_rdot" in reasons[0] and "\\u001b[31mred line\\u202e" in reasons[0]
    assert all(c.isprintable() for c in reasons[0]) and len(reasons[0]) < 400


def test_blocks_are_written_all_or_none(tmp_path):
    """Both blocks land under their FILE names."""
    model = validate_model(model_doc(BLUEROV2), "w.json")
    paths = write_hydro_formats(model, tmp_path, ["gz-hydrodynamics", "uuv-fossen"], OPTIONS)
    assert sorted(p.name for p in paths) == sorted([gz_hydrodynamics.FILE, uuv_fossen.FILE])
    for p in paths:
        ET.fromstring(p.read_text(encoding="ascii"))


def test_stonefish_says_why_it_writes_nothing(tmp_path):
    """Stonefish takes no derivatives: needs() always says so, naming the source read."""
    model = validate_model(model_doc(BLUEROV2), "s.json")
    reasons = stonefish.needs(model, OPTIONS)
    assert stonefish.FILE is None and len(reasons) == 1
    assert "added mass is computed from the geometry" in reasons[0] and "b21eb8e" in reasons[0]
    with pytest.raises(UsageError, match="Stonefish takes no hydrodynamic derivatives"):
        write_hydro_formats(model, tmp_path, ["stonefish"], OPTIONS)
    with pytest.raises(UsageError):
        stonefish.render(model, OPTIONS)


def test_every_format_names_the_source_it_follows():
    """FOLLOWS names a file and a commit."""
    for mod in HYDRO_FORMATS.values():
        assert re.search(r"\b[0-9a-f]{7}\b", mod.FOLLOWS), mod.FOLLOWS
        assert re.search(r"\.(cc|cpp)\b", mod.FOLLOWS), mod.FOLLOWS


# ----- vehicle_model.json ----------------------------------------------------------------------


def _set(path: str, value: object) -> dict:
    """The BlueROV2 document with one field (dotted path) replaced."""
    doc = copy.deepcopy(model_doc(BLUEROV2))
    *head, last = path.split(".")
    obj = doc
    for key in head:
        obj = obj[int(key)] if isinstance(obj, list) else obj[key]
    if isinstance(obj, list):
        obj[int(last)] = value
    else:
        obj[last] = value
    return doc


AM = "hydrodynamics.added_mass.X_udot"
CRAFTED = [
    (f"{AM}.value", math.nan, f"{AM}.value"),
    (f"{AM}.value", math.inf, f"{AM}.value"),
    (f"{AM}.value", "-5.5", f"{AM}.value"),
    (f"{AM}.value", True, f"{AM}.value"),
    (f"{AM}.value", 1e300, f"{AM}.value"),
    (f"{AM}.value", 10**400, f"{AM}.value"),
    (f"{AM}.ci95", [1.0], f"{AM}.ci95"),
    (f"{AM}.ci95", [2.0, 1.0], f"{AM}.ci95"),
    (f"{AM}.reason", 3, f"{AM}.reason"),
    (f"{AM}.extra", [0.0] * 100_000, f"{AM}: unknown key"),
    ("hydrodynamics.added_mass.X_uu", {"value": 1.0, "ci95": None, "reason": None},
     "hydrodynamics.added_mass: unknown key"),
    ("hydrodynamics.linear_damping", [], "hydrodynamics.linear_damping: must be an object"),
    ("rigid_body.inertia_kg_m2", [[0.16, 0.01, 0], [0, 0.16, 0], [0, 0, 0.16]],
     "rigid_body.inertia_kg_m2: must be symmetric"),
    ("rigid_body.inertia_kg_m2", [[1.0, 2.0, 0], [2.0, 1.0, 0], [0, 0, 1.0]],
     "rigid_body.inertia_kg_m2: must be positive definite"),
    ("rigid_body.inertia_kg_m2", [[0.16, 0, 0], [0, 0.16, 0]], "rigid_body.inertia_kg_m2"),
    ("rigid_body.inertia_kg_m2", [0.16, 0.16, 0.16], "rigid_body.inertia_kg_m2[0]"),
    ("rigid_body.inertia_kg_m2.1.1", math.nan, "rigid_body.inertia_kg_m2[1][1]"),
    ("rigid_body.cob_m", [0.0, 0.0], "rigid_body.cob_m"),
    ("rigid_body.cob_m", [0.0] * 1_000_000, "rigid_body.cob_m"),
    ("rigid_body.cog_m.2", "0", "rigid_body.cog_m[2]"),
    ("rigid_body.mass_kg", -11.5, "rigid_body.mass_kg: must be positive"),
    ("rigid_body.water_density_kg_m3", 0.0, "rigid_body.water_density_kg_m3"),
    ("rigid_body.gravity_m_s2", math.nan, "rigid_body.gravity_m_s2"),
    ("rigid_body.buoyancy_n", None, "rigid_body.buoyancy_n"),
    ("name", "x" * 201, "name: is 201 characters"),
    ("name", ["a"], "name: must be text"),
    ("frame", "NED", "frame"),
    ("schema_version", 2, "schema_version"),
    ("schema_version", True, "schema_version"),
    ("format", "other", "format"),
    ("extra", [0] * 10_000, "(document): unknown key"),
]


@pytest.mark.parametrize(("path", "value", "field"), CRAFTED,
                         ids=[f"{p}={str(v)[:12]}" for p, v, _ in CRAFTED])
def test_validate_model_refuses_crafted_documents(path, value, field):
    """A ConfigError naming the file and the field; nothing passes through."""
    with pytest.raises(ConfigError) as info:
        validate_model(_set(path, value), "models/evil.json")
    msg = str(info.value)
    assert "models/evil.json: " + field.split(":")[0] in msg, msg
    assert field in msg, msg
    assert len(msg) < 2000


@pytest.mark.parametrize("doc", [None, [], "x", 1.0, {}])
def test_validate_model_refuses_what_is_no_document(doc):
    """Not an object, or an empty one."""
    with pytest.raises(ConfigError, match="bad.json: \\(document\\)"):
        validate_model(doc, "bad.json")


def test_validate_model_keeps_values_and_leaves_signs_alone():
    """Signs are not enforced (a positive damping term is reported, not hidden); ints become
    floats; the checked model equals the document otherwise."""
    doc = _set("hydrodynamics.linear_damping.Y_v.value", 2)
    model = validate_model(doc, "ok.json")
    assert model["hydrodynamics"]["linear_damping"]["Y_v"]["value"] == 2.0
    assert isinstance(model["hydrodynamics"]["linear_damping"]["Y_v"]["value"], float)
    assert json.loads(json.dumps(model)) == json.loads(json.dumps(doc))


def test_write_model_is_exact_and_atomic(tmp_path):
    """vehicle_model.json reads back to the checked model, numbers exact; a bad document
    writes nothing."""
    doc = _set("hydrodynamics.linear_damping.X_u.value", -0.1 - 0.2)
    path = write_model(doc, tmp_path)
    assert path.name == "vehicle_model.json"
    back = json.loads(path.read_text())
    assert validate_model(back, str(path)) == validate_model(doc, "doc")
    assert back["hydrodynamics"]["linear_damping"]["X_u"]["value"] == -0.1 - 0.2
    with pytest.raises(ConfigError, match="vehicle_model.json: rigid_body.mass_kg"):
        write_model(_set("rigid_body.mass_kg", math.nan), tmp_path / "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["vehicle_model.json"]


def test_the_docs_example_runs(tmp_path, monkeypatch):
    """docs/vehicle-formats.md's example, as written, beside a written vehicle_model.json."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "vehicle-formats.md").read_text()
    (code,) = re.findall(r"```python\n(.*?)```", text, re.S)
    write_model(model_doc(BLUEROV2), tmp_path)
    monkeypatch.chdir(tmp_path)
    scope: dict = {"__name__": "vehicle_formats_example"}
    exec(compile(code, "docs/vehicle-formats.md", "exec"), scope)
    assert sorted(p.name for p in scope["written"]) == sorted(
        [gz_hydrodynamics.FILE, uuv_fossen.FILE])
