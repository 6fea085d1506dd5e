"""Controller exports (ArduSub .param, PX4 parameter file, thruster_manager and auv_controllers
YAML): each file is read the way its consumer reads it, the consumer's own model is evaluated
on it over the whole command range and compared with cal.thrust (issue: controller formats;
docs/formats-controllers.md)."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

import rigtool
from rigtool.artefacts.formats import FORMATS, write_vehicle_artefacts
from rigtool.artefacts.vehicle import RAD_S_PER_RPM, ExportOptions
from rigtool.cli import main
from rigtool.store import Store
from rigtool.workflows import stored_results

from .conftest import copy_db

ROOT = Path(__file__).resolve().parents[1]
FORWARD_ONLY = """\
rigtool_protocol: 1
name: forward-only
simulator: {profile: esc-1100-1900, seed: 5}
metadata: {thruster_id: fwd-1, propeller_diameter_m: 0.1, water_density_kg_m3: 1000}
command: {unit: pulse_us, range: {start: 1500, stop: 1900, step: 20}, order: up}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 200, rate_hz: 1000}
  tare: at_start
"""
CONTROLLERS = ("ardupilot", "px4", "thruster-manager", "auv-controllers")
HOSTILE = 'q"\'x\n# PWNED,1\r\n1\t1\tPWNED\t1\t9\n*/ --> \u2028\u2029, a,b\x85\\ #: [] {}'
# Bounds the twins stay well inside (the files state their own, smaller, figures)
ARDUPILOT_BOUND_PCT = 2.0  # ArduSub expo linearisation vs a straight line, % of full thrust
PX4_BOUND_PCT = 15.0  # PX4's one symmetric curve on a thruster 20 % weaker in reverse
POLY_BOUND_PCT = 8.0  # one polynomial thrust -> PWM through a dead band and a sqrt shape
COMMAND_RANGE = {"esc": (1100, 1900), "demo": (-100, 100), "fwd": (1500, 1900)}
TABLE_PCT = 0.5  # limits and tables, % of full-scale thrust


def _cli(*args: str | Path) -> int:
    return main([str(a) for a in args])


@pytest.fixture(scope="module")
def runs(tmp_path_factory, shipped_sweep):
    """Three twins swept and calibrated once through the CLI, with their exports: the shipped
    ESC (the session's sweep of it, copied) and quick-demo protocols, and a forward-only ESC
    sweep."""
    tmp = tmp_path_factory.mktemp("controllers")
    db, out = tmp / "db.sqlite", tmp / "cal"
    (tmp / "fwd.yaml").write_text(FORWARD_ONLY)
    joint = ("--joint", "thruster_1_joint")
    result = {}
    for name, protocol, formats in (
            ("esc", ROOT / "protocols" / "esc-1100-1900.yaml", CONTROLLERS),
            ("demo", ROOT / "protocols" / "quick-demo.yaml",
             ("px4", "thruster-manager", "auv-controllers")),
            ("fwd", tmp / "fwd.yaml", ("ardupilot", "px4", "auv-controllers"))):
        if name == "esc":
            copy_db(shipped_sweep("esc-1100-1900"), db)
        else:
            assert _cli("sweep", protocol, "--sim", "--db", db) == 0
        store = Store(db)
        run_id = store.resolve_run_id("last")
        store.close()
        exports = [a for f in formats for a in ("--export", f)]
        assert _cli("calibrate", run_id, "--db", db, "--out", out, *exports, *joint) == 0
        folder = out / run_id
        assert all((folder / FORMATS[f]).is_file() for f in formats)
        result[name] = (tmp, db, folder, rigtool.load_calibration(folder))
    return result


def parse_param(text: str) -> dict[str, float]:
    """A .param file as AP_Param::parse_param_line reads it: a line starting with `#` is
    skipped, the name and value are the first two tokens split at any of `, =\\t\\r\\n`, a name
    is at most 16 characters, the value goes through atof."""
    out = {}
    for line in text.split("\n"):
        if line.startswith("#"):
            continue
        tokens = [t for t in re.split(r"[, =\t\r\n]+", line) if t]
        if len(tokens) < 2 or len(tokens[0]) > 16:
            continue
        out[tokens[0]] = float(tokens[1])
    return out


def parse_qgc(text: str) -> dict[str, float]:
    """A parameter file as QGroundControl's readParametersFromStream reads it: lines not
    starting with `#`, split at tabs, with 5 fields (system id, component id, name, value,
    MAV_PARAM_TYPE); system 1, component 1, REAL32 (9) here."""
    out = {}
    for line in text.splitlines():
        if line.startswith("#"):
            continue
        fields = line.split("\t")
        if len(fields) == 5:
            assert fields[0] == "1" and fields[1] == "1" and fields[4] == "9"
            out[fields[2]] = float(fields[3])
    return out


def stated(text: str, pattern: str) -> float:
    """A figure the file states in its comments."""
    return float(re.search(pattern, text).group(1))


def ardupilot_expo(thrust: np.ndarray, expo: float) -> np.ndarray:
    """ArduPilot's apply_thrust_curve_and_volt_scaling, battery scale 1, lift_max 1."""
    if expo == 0:
        return thrust
    root = np.sqrt(np.maximum((1 - expo) ** 2 + 4 * expo * thrust, 0))
    return np.clip((expo - 1 + root) / (2 * expo), 0, 1)


def no_empty_list(doc: object) -> bool:
    """True when no list in `doc` is empty."""
    if isinstance(doc, dict):
        return all(no_empty_list(v) for v in doc.values())
    if isinstance(doc, list):
        return bool(doc) and all(no_empty_list(v) for v in doc)
    return True


def ardusub_pwm(sign: float, act: np.ndarray, half: float) -> np.ndarray:
    """AP_Motors6DOF::calc_thrust_to_pwm: 1500 + thrust x range in single precision, returned
    as int16_t (truncated toward zero: whole microseconds)."""
    f32 = np.float32
    return np.trunc(f32(1500) + f32(sign) * act.astype(f32) * f32(half)).astype(float)


@pytest.mark.parametrize("name", ["esc", "fwd"])
def test_ardupilot_expo_linearises_thrust(runs, name):
    """The .param as AP_Param loads it: MOT_SPIN_ARM within its metadata and not above
    MOT_SPIN_MIN (AP_MotorsMulticopter's arming check, which refuses MOT_SPIN_ARM >
    MOT_SPIN_MIN, and its default 0.1 would be above 0.07 here); the stated error is the
    linearised thrust's largest deviation with the pulse truncated to whole us as ArduSub
    writes it, and the curve-alone figure beside it is without that."""
    _, _, folder, cal = runs[name]
    text = (folder / FORMATS["ardupilot"]).read_text()
    p = parse_param(text)
    assert set(p) == {"MOT_PWM_MIN", "MOT_PWM_MAX", "MOT_SPIN_ARM", "MOT_SPIN_MIN",
                      "MOT_SPIN_MAX", "MOT_THST_EXPO"}
    assert p["MOT_PWM_MAX"] == 1900 and p["MOT_PWM_MIN"] == (1100 if name == "esc" else 1500)
    assert 0.0 <= p["MOT_SPIN_ARM"] <= p["MOT_SPIN_MIN"] <= 0.3  # arming_checks
    err_stated = stated(text, r"by at most ([0-9.]+) %")
    curve_stated = stated(text, r"the curve alone\n# ([0-9.]+) %")
    assert err_stated <= ARDUPILOT_BOUND_PCT
    demand = np.linspace(0, 1, 1001)
    act = p["MOT_SPIN_MIN"] + (p["MOT_SPIN_MAX"] - p["MOT_SPIN_MIN"]) * ardupilot_expo(
        demand, p["MOT_THST_EXPO"])
    halves = [(1.0, p["MOT_PWM_MAX"] - 1500)]
    if p["MOT_PWM_MIN"] < 1500:
        halves.append((-1.0, 1500 - p["MOT_PWM_MIN"]))
    errors, curve = [], []
    for sign, half in halves:
        full = sign * cal.thrust(1500 + sign * half)
        f = sign * cal.thrust(ardusub_pwm(sign, act, half))
        assert np.all(np.isfinite(f))
        errors.append(np.max(np.abs(f - demand * full)) / full)
        f = sign * cal.thrust(1500 + sign * act * half)
        curve.append(np.max(np.abs(f - demand * full)) / full)
    assert 100 * max(errors) == pytest.approx(err_stated, abs=0.01)
    assert 100 * max(curve) == pytest.approx(curve_stated, abs=0.01)
    if name == "esc":
        assert err_stated >= 0.45  # whole us alone cost about 0.5 % near full reverse
        ratio = stated(text, r"reverse_ratio ([0-9.]+)")
        assert ratio == pytest.approx(-cal.thrust(1100.0) / cal.thrust(1900.0), abs=1e-3)
    else:
        assert "reverse_ratio" not in text


def px4_limits(text: str) -> tuple[int, int]:
    """The PWM_MAIN_MIN/MAX values the file tells the user to type (whole us)."""
    m = re.search(r"PWM_MAIN_MIN<ch> (\S+), PWM_MAIN_MAX<ch> (\S+?)[ .]", text)
    return int(m.group(1)), int(m.group(2))


def px4_range(text: str) -> tuple[float, float]:
    """The run's command range the advised output limits stand for: the limits themselves for
    a pulse-width run, else the stated fractions of the driver's -100..100 % span."""
    m = re.search(r"Those are (\S+) and (\S+) of the way", text)
    if m is None:
        return px4_limits(text)
    return -100.0 + 200.0 * float(m.group(1)), -100.0 + 200.0 * float(m.group(2))


def px4_output(u: float, lo: int, hi: int) -> int:
    """MixingOutput::output_limit_calc_single: -1..1 interpolated onto minimum..maximum,
    lroundf, constrained to 0..65535 (uint16)."""
    value = lo + (min(max(u, -1.0), 1.0) + 1.0) / 2.0 * (hi - lo)
    return min(max(int(math.floor(value + 0.5)), 0), 65535)


@pytest.mark.parametrize("name", ["esc", "demo", "fwd"])
def test_px4_output_range_is_typed_in_driver_units(runs, name):
    """The output limits advised are what PX4 takes: whole, non-negative driver values (us
    here); through output_limit_calc_single they command the run's range, its neutral at the
    middle of a reversible motor's -1..1 (a percent run via a PWM-input ESC taking 1100..1900
    us for -100..100 %, as the file says)."""
    _, _, folder, cal = runs[name]
    text = (folder / FORMATS["px4"]).read_text()
    lo_us, hi_us = px4_limits(text)
    assert 0 <= lo_us < hi_us <= 65535
    assert not re.search(r"(MIN|MAX)<ch> -", text)
    lo, hi = px4_range(text)
    assert (lo, hi) == pytest.approx(COMMAND_RANGE[name])
    to_run = (lambda us: us) if name != "demo" else (lambda us: (us - 1500.0) / 4.0)
    if name == "fwd":  # non-reversible: 0..1 remapped to -1..1 first
        assert to_run(px4_output(-1.0, lo_us, hi_us)) == lo == cal.neutral
    else:
        assert to_run(px4_output(0.0, lo_us, hi_us)) == cal.neutral
        assert to_run(px4_output(-1.0, lo_us, hi_us)) == pytest.approx(lo)
    assert to_run(px4_output(1.0, lo_us, hi_us)) == pytest.approx(hi)
    if name == "demo":
        assert "cannot be typed" in text and "UAVCAN_EC_MIN" in text


@pytest.mark.parametrize("name", ["esc", "demo", "fwd"])
def test_px4_thrust_model_matches_cal(runs, name):
    _, _, folder, cal = runs[name]
    text = (folder / FORMATS["px4"]).read_text()
    p = parse_qgc(text)
    f, ct = p["THR_MDL_FAC"], p["CA_ROTOR0_CT"]
    assert 0 <= f <= 1 and ct > 0
    lo, hi = px4_range(text)
    err_stated = stated(text, r"range\n# ([0-9.]+) %")
    assert err_stated <= PX4_BOUND_PCT
    u = np.linspace(0, 1, 1001)
    model = ct * (f * u ** 2 + (1 - f) * u)
    if name == "fwd":
        measured = [cal.thrust(lo + u * (hi - lo))]
    else:
        mid = (lo + hi) / 2
        assert mid == cal.neutral
        measured = [cal.thrust(mid + u * (hi - mid)), -cal.thrust(mid - u * (mid - lo))]
    scale = max(np.max(np.abs(m)) for m in measured)
    err = max(np.max(np.abs(model - m)) for m in measured) / scale
    assert 100 * err <= err_stated + 0.05
    coef = cal.coefficients
    km = coef["C_q_fwd"].value / coef["C_p_fwd"].value
    assert p["CA_ROTOR0_KM"] == pytest.approx(km, abs=1e-5)


def test_px4_index_and_missing_torque(runs, tmp_path):
    """--index 3 writes CA_ROTOR2; without torque the KM line is left out and says so."""
    _, db, _, api_cal = runs["esc"]
    store = Store(db)
    cal = stored_results(store, api_cal.run_id).calibration
    store.close()
    sec = cal.sections[-1]
    no_torque = replace(cal, sections=[replace(sec, fits={k: v for k, v in sec.fits.items()
                                                          if not k.startswith("C_q")})])
    path, = write_vehicle_artefacts(no_torque, tmp_path, ["px4"], "2024-01-01T00:00:00Z",
                                    options=ExportOptions(index=3))
    text = path.read_text()
    assert set(parse_qgc(text)) == {"THR_MDL_FAC", "CA_ROTOR2_CT"}
    assert "CA_ROTOR2_KM is not set" in text


@pytest.mark.parametrize("name", ["esc", "demo"])
def test_thruster_manager_limits(runs, name):
    _, _, folder, cal = runs[name]
    doc = yaml.safe_load((folder / FORMATS["thruster-manager"]).read_text())
    tam = doc["/**"]["ros__parameters"]["tam"]
    assert all(isinstance(v, float) for v in tam.values())  # declared as doubles
    grid = np.linspace(*COMMAND_RANGE[name], 4001)
    thrust = cal.thrust(grid)
    full = np.nanmax(np.abs(thrust))
    assert abs(tam["max_thrust"] - np.nanmax(thrust)) <= TABLE_PCT / 100 * full
    assert abs(tam["min_thrust"] - np.nanmin(thrust)) <= TABLE_PCT / 100 * full
    smallest = max(cal.thrust_map().limits(d)[0] for d in ("forward", "reverse"))
    assert abs(tam["deadzone"] - smallest) <= TABLE_PCT / 100 * full
    assert doc["/**"]["ros__parameters"]["rigtool"]["source_run"] == cal.run_id


@pytest.mark.parametrize("name", ["esc", "fwd"])
def test_auv_polynomial_controller(runs, name):
    _, _, folder, cal = runs[name]
    text = (folder / FORMATS["auv-controllers"]).read_text()
    doc = yaml.safe_load(text)
    manager = doc["controller_manager"]["ros__parameters"]
    assert manager["thruster_1_controller"]["type"] == (
        "thruster_controllers/PolynomialThrustCurveController")
    p = doc["thruster_1_controller"]["ros__parameters"]
    assert p["thruster"] == "thruster_1_joint"
    for key in ("min_deadband_pwm", "max_deadband_pwm", "neutral_pwm"):
        assert type(p[key]) is int
    assert all(isinstance(p[k], float) for k in ("min_thrust", "max_thrust"))
    assert p["thrust_curve_coefficients"] and all(
        isinstance(c, float) for c in p["thrust_curve_coefficients"])
    err_stated = stated(text, r"over the range ([0-9.]+) %")
    assert err_stated <= POLY_BOUND_PCT
    full = cal.thrust(np.array(COMMAND_RANGE[name], dtype=float))  # measured extremes
    scale = np.max(np.abs(full))
    force = np.linspace(min(full[0], 0.0), full[1], 4001)
    clamped = np.clip(force, p["min_thrust"], p["max_thrust"])  # as the controller does
    pwm = np.round(sum(c * clamped ** i for i, c in enumerate(p["thrust_curve_coefficients"])))
    pwm = np.where((pwm > p["min_deadband_pwm"]) & (pwm < p["max_deadband_pwm"]),
                   p["neutral_pwm"], pwm)
    assert np.all((pwm >= COMMAND_RANGE[name][0]) & (pwm <= COMMAND_RANGE[name][1]))
    err = np.max(np.abs(cal.thrust(pwm) - force)) / scale
    assert 100 * err <= err_stated + 0.01
    assert full[1] - err_stated / 100 * scale <= p["max_thrust"] <= full[1] + 1e-9
    if name == "fwd":
        assert p["min_thrust"] == 0.0
        assert "thruster_1_rotation_rate_controller" in doc
    else:
        assert full[0] - 1e-9 <= p["min_thrust"] <= full[0] + err_stated / 100 * scale
        assert "No rotation_rate_controller: needs the propeller diameter" in text


def test_auv_rotation_rate_controller(runs):
    _, _, folder, cal = runs["demo"]
    doc = yaml.safe_load((folder / FORMATS["auv-controllers"]).read_text())
    assert "thruster_1_controller" not in doc
    p = doc["thruster_1_rotation_rate_controller"]["ros__parameters"]
    assert p["propeller_diameter"] == 0.2 and p["fluid_density"] == 1000.0
    force = np.linspace(0, p["max_thrust"], 1001)[1:]
    omega = np.sqrt(force / (p["fluid_density"] * p["thrust_coefficient"]
                             * p["propeller_diameter"] ** 4))
    got = cal.thrust_from_speed(omega / RAD_S_PER_RPM)
    assert np.max(np.abs(got - force)) <= 1e-6 * p["max_thrust"]
    assert p["min_deadband"] < 0 < p["max_deadband"]


def test_every_yaml_loads_without_empty_lists(runs):
    for name, (_, _, folder, _) in runs.items():
        for fmt in ("thruster-manager", "auv-controllers"):
            path = folder / FORMATS[fmt]
            if path.exists():
                text = path.read_text()
                assert "[]" not in text, (name, fmt)
                assert no_empty_list(yaml.safe_load(text)), (name, fmt)


def test_missing_prerequisite_exits_2_and_writes_nothing(runs):
    tmp, db, folder, cal = runs["demo"]
    out = tmp / "refused"
    assert _cli("calibrate", cal.run_id, "--db", db, "--out", out, "--export", "ardupilot",
                "--export", "px4") == 2
    assert not out.exists() or not any(out.rglob("*"))
    assert _cli("export-cal", cal.run_id, "--db", db, "--out", out, "--format", "px4",
                "--format", "ardupilot") == 2
    assert not out.exists() or not any(out.rglob("*"))
    _, db, folder, cal = runs["fwd"]
    assert _cli("export-cal", cal.run_id, "--db", db, "--out", out, "--format",
                "thruster-manager") == 2
    assert _cli("export-cal", cal.run_id, "--db", db, "--out", out, "--format",
                "auv-controllers") == 2  # no --joint
    assert not out.exists() or not any(out.rglob("*"))


def test_hostile_texts_do_not_change_any_parse(runs, tmp_path):
    _, db, _, api_cal = runs["esc"]
    store = Store(db)
    cal = stored_results(store, api_cal.run_id).calibration
    store.close()
    options = ExportOptions(joint="thruster_1_joint")
    plain = write_vehicle_artefacts(cal, tmp_path / "plain", CONTROLLERS, "2024-01-01", None,
                                    options)
    hostile_cal = replace(cal, run_name=HOSTILE, thruster_id=HOSTILE)
    hostile = write_vehicle_artefacts(hostile_cal, tmp_path / "hostile", CONTROLLERS, HOSTILE,
                                      None, replace(options, joint=HOSTILE))
    for fmt, a, b in zip(CONTROLLERS, plain, hostile, strict=True):
        ta, tb = a.read_text(), b.read_text()
        if fmt == "ardupilot":
            assert parse_param(ta) == parse_param(tb) and ta == tb
        elif fmt == "px4":
            assert parse_qgc(ta) == parse_qgc(tb) and ta == tb
        else:
            da, db_ = yaml.safe_load(ta), yaml.safe_load(tb)
            assert da.keys() == db_.keys()
            assert [line for line in ta.splitlines() if line.startswith("#")] == [
                line for line in tb.splitlines() if line.startswith("#")]
            for node, body in db_.items():
                params = body["ros__parameters"]
                if "rigtool" in params:
                    assert params["rigtool"]["run_name"] == HOSTILE
                    assert params["rigtool"]["thruster_id"] == HOSTILE
                    assert params["rigtool"]["created_utc"] == HOSTILE
                if "thruster" in params:
                    assert params["thruster"] == HOSTILE
                assert set(params) == set(da[node]["ros__parameters"])
            assert len(ta.splitlines()) == len(tb.splitlines())
    assert math.isfinite(parse_param(plain[0].read_text())["MOT_THST_EXPO"])


def test_ardupilot_expo_is_the_webtools_optimum(runs):
    """On a one-direction run the criterion is exactly WebTools ThrustExpo's: the standard
    deviation of the slope of thrust over demand 0..1 (step 0.001); the written expo has the
    least of it among its neighbours on WebTools' 0.005 grid."""
    _, _, folder, cal = runs["fwd"]
    p = parse_param((folder / FORMATS["ardupilot"]).read_text())
    demand = np.linspace(0, 1, 1001)

    def spread(expo: float) -> float:
        act = p["MOT_SPIN_MIN"] + (p["MOT_SPIN_MAX"] - p["MOT_SPIN_MIN"]) * ardupilot_expo(
            demand, expo)
        f = cal.thrust(p["MOT_PWM_MIN"] + act * (p["MOT_PWM_MAX"] - p["MOT_PWM_MIN"]))
        return float(np.std(np.diff(f) / 0.001))

    best = spread(p["MOT_THST_EXPO"])
    for step in (-0.05, -0.005, 0.005, 0.05):
        if -1 <= p["MOT_THST_EXPO"] + step <= 1:
            assert best <= spread(p["MOT_THST_EXPO"] + step) + 1e-9
