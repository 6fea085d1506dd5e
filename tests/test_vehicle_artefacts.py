"""Vehicle artefacts: the C header compiles and agrees with cal.command() (values and status),
ROS 2 parameters load as YAML, the Gazebo thrust coefficient reproduces C_p, and an export
writes every file or none (issues: artefacts a vehicle team drops in; calibrations that load
where vehicles run them)."""

from __future__ import annotations

import math
import shutil
import subprocess

import numpy as np
import pytest
import yaml

import rigtool
from rigtool.artefacts.formats import FORMATS
from rigtool.cli import main

CC = shutil.which("cc") or shutil.which("gcc")
PROTOCOL = """\
rigtool_protocol: 1
name: vehicle
simulator: {{profile: {profile}, seed: 41}}
metadata: {{thruster_id: stern-1, propeller_diameter_m: 0.1, water_density_kg_m3: 1000}}
command: {{unit: {unit}, range: {{start: {lo}, stop: {hi}, step: {step}}}, order: up}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 1.0}}
  acquire: {{samples: 300, rate_hz: 1000}}
  tare: at_start
"""
BASIC = ("c-header", "ros2", "gazebo", "csv-lut")
NAMES = ("--joint", "prop_joint", "--namespace", "thruster_1")
RIGS = {"esc": dict(profile="esc-1100-1900", unit="pulse_us", lo=1100, hi=1900, step=20),
        "can": dict(profile="can-bldc", unit="percent", lo=-100, hi=100, step=5)}


@pytest.fixture(scope="module", params=sorted(RIGS))
def exported(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(request.param)
    (tmp / "p.yaml").write_text(PROTOCOL.format(**RIGS[request.param]))
    db, out = str(tmp / "db.sqlite"), tmp / "cal"
    assert main(["sweep", str(tmp / "p.yaml"), "--sim", "--db", db]) == 0
    formats = [a for f in BASIC for a in ("--export", f)]
    assert main(["calibrate", "last", "--db", db, "--out", str(out), *formats, *NAMES]) == 0
    folder = next(out.iterdir())
    return tmp, db, folder, rigtool.load_calibration(folder)


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_c_header_compiles_and_matches_cal_command(exported):
    tmp, _, folder, cal = exported
    header = folder / FORMATS["c-header"]
    assert "units: thrust N" in header.read_text() and cal.run_id in header.read_text()
    probe = np.concatenate([np.linspace(-60.0, 60.0, 2401),
                            [np.inf, -np.inf, 1e308, -1e308, 1e19, -0.0, 5e-324, -5e-324]])
    (tmp / "probe.txt").write_text("\n".join(repr(float(f)) for f in probe) + "\n")
    (tmp / "main.c").write_text(f'''#include <stdio.h>
#include "{header}"
int main(void) {{
    int s;
    for (int i = 0; i < RIGTOOL_N_TEST; ++i) {{
        double c = rigtool_command_for_thrust_status(rigtool_test_thrust[i], &s);
        double want = rigtool_test_command[i];
        if (!(fabs(c - want) <= 1e-9 * (1.0 + fabs(want))) || s != rigtool_test_status[i]) {{
            printf("test %d\\n", i);
            return 1;
        }}
    }}
    double f;
    while (scanf("%lf", &f) == 1) {{
        double c = rigtool_command_for_thrust_status(f, &s);
        printf("%.17g %d %.17g\\n", c, s, rigtool_command_for_thrust_strict(f));
    }}
    return 0;
}}
''')
    exe = tmp / "probe"
    subprocess.run([CC, "-std=c99", "-Wall", "-Werror", "-O2", str(tmp / "main.c"), "-o",
                    str(exe), "-lm"], check=True)
    run = subprocess.run([str(exe)], input=(tmp / "probe.txt").read_text(), text=True,
                         capture_output=True, check=True)
    got, status, strict = np.array([[float(x) for x in line.split()]
                                    for line in run.stdout.splitlines()]).T
    want = cal.command(probe)
    assert np.isfinite(want).all() and np.isfinite(got).all()
    span = want.max() - want.min()
    assert np.max(np.abs(got - want)) <= 1e-6 * span
    names = {0: "ok", 1: "clamped", 2: "below_min", 3: "nan", 4: "gap"}
    assert [names[int(v)] for v in status] == list(cal.command_status(probe))
    want_strict = cal.command(probe, strict=True)
    assert np.array_equal(np.isnan(strict), np.isnan(want_strict))
    ok = np.isfinite(want_strict)
    assert ok.sum() > 1000 and np.max(np.abs(strict[ok] - want_strict[ok])) <= 1e-6 * span


def test_ros2_parameters_load_and_hold_the_map(exported):
    _, _, folder, cal = exported
    doc = yaml.safe_load((folder / FORMATS["ros2"]).read_text())
    p = doc["/**"]["ros__parameters"]["rigtool"]
    assert p["source_run"] == cal.run_id and p["command_unit"] == cal.command_unit
    assert p["neutral_command"] == cal.neutral and p["thruster_id"] == "stern-1"
    f, c = np.array(p["map_forward_thrust_n"]), np.array(p["map_forward_command"])
    assert f.size > 3 and np.all(np.diff(f) > 0)
    np.testing.assert_allclose(cal.command(f), c, rtol=1e-7)
    assert p["thrust_coefficient_forward"] == pytest.approx(cal.coefficients["C_p_fwd"].value)
    assert len(p.get("dead_band", [])) == 2 * p["n_dead_zones"]


def test_gazebo_coefficient_reproduces_c_p(exported):
    _, _, folder, cal = exported
    text = (folder / FORMATS["gazebo"]).read_text()
    c_t = float(text.split("<thrust_coefficient>")[1].split("<")[0])
    n_rpm = 1500.0
    omega = n_rpm * 2 * math.pi / 60
    thrust = c_t * 1000.0 * 0.1**4 * omega**2
    assert thrust == pytest.approx(cal.coefficients["C_p_fwd"].value * n_rpm**2, rel=1e-8)
    assert 'name="gz::sim::systems::Thruster"' in text and "rad/s" in text


def test_export_cal_from_the_stored_calibration_and_clear_errors(exported, capsys):
    tmp, db, folder, cal = exported
    assert main(["export-cal", "last", "--format", "ros2", "--db", db,
                 "--out", str(tmp / "again")]) == 0
    assert (tmp / "again" / cal.run_id / FORMATS["ros2"]).read_text().split("\n", 3)[3] \
        == (folder / FORMATS["ros2"]).read_text().split("\n", 3)[3]
    (tmp / "bare.yaml").write_text((tmp / "p.yaml").read_text().replace(
        "metadata: {thruster_id: stern-1, propeller_diameter_m: 0.1, water_density_kg_m3: 1000}",
        "metadata: {thruster_id: stern-2}"))
    assert main(["sweep", str(tmp / "bare.yaml"), "--sim", "--db", db]) == 0
    capsys.readouterr()
    assert main(["export-cal", "last", "--format", "c-header", "--db", db]) == 2
    assert "has not been calibrated" in capsys.readouterr().err
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "bare")]) == 0
    capsys.readouterr()
    before = sorted(p.name for p in (tmp / "bare").rglob("*"))
    assert main(["export-cal", "last", "--format", "c-header", "--format", "csv-lut",
                 "--format", "gazebo", "--db", db, "--out", str(tmp / "bare")]) == 2
    err = capsys.readouterr().err
    assert "nothing exported" in err and "propeller_diameter_m" in err and "--joint" in err
    assert sorted(p.name for p in (tmp / "bare").rglob("*")) == before


STEPS = {"esc": "[1500, 1700, 1500, 1300, 1500]", "can": "[0, 60, 0, -60, 0]"}


def test_time_constants_come_from_a_step_run_of_the_same_thruster(exported, capsys):
    """`--dynamics RUN` puts the identified time constants into every vehicle artefact; a run
    without dynamics or of another thruster is refused with exit 2."""
    tmp, db, steady, cal = exported
    rig = next(k for k, v in RIGS.items() if v["unit"] == cal.command_unit)
    text = (tmp / "p.yaml").read_text().replace("seed: 41}", "seed: 43, overrides: {tau_s: 0.2, "
                                                "inflow_gain: 0.3, inflow_tau_s: 0.6}}")
    text = text.split("command:")[0] + (
        f"command: {{unit: {RIGS[rig]['unit']}, steps: {STEPS[rig]}}}\n"
        "depth: {unit: m, values: [1.0]}\n"
        "timing: {settle: {seconds: 0}, acquire: {seconds: 2.0, rate_hz: 500}, rest_s: 0,"
        " tare: at_start}\n")
    (tmp / "steps.yaml").write_text(text)
    assert main(["sweep", str(tmp / "steps.yaml"), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "steps")]) == 0
    step_cal = rigtool.load_calibration(next((tmp / "steps").iterdir()))
    dyn = step_cal.dynamics.parameters
    out = tmp / "with-dynamics"
    args = ["export-cal", cal.run_id, "--dynamics", step_cal.run_id, "--db", db, "--out",
            str(out)]
    assert main([*args, *(a for f in BASIC for a in ("--format", f)), *NAMES]) == 0
    folder = out / cal.run_id
    p = yaml.safe_load((folder / FORMATS["ros2"]).read_text())["/**"][
        "ros__parameters"]["rigtool"]
    assert p["dynamics_source_run"] == step_cal.run_id
    assert p["dynamics_model"] == step_cal.dynamics.selected == "two-state"
    assert p["time_constant_s"] == pytest.approx(dyn["tau_n"].value, rel=1e-9)
    assert p["inflow_time_constant_s"] == pytest.approx(dyn["tau_a"].value, rel=1e-9)
    assert p["inflow_gain"] == pytest.approx(dyn["g"].value, rel=1e-9)
    assert p["command_delay_s"] == pytest.approx(dyn["delay"].value, rel=1e-9)
    assert p["time_constant_s"] == pytest.approx(0.2, rel=0.05)
    sdf = (folder / FORMATS["gazebo"]).read_text()
    tau = float(sdf.split("<rigtool_time_constant_s>")[1].split("<")[0])
    assert tau == pytest.approx(dyn["tau_n"].value, rel=1e-8)
    assert float(sdf.split("<max_thrust_cmd>")[1].split("<")[0]) > 0
    assert float(sdf.split("<min_thrust_cmd>")[1].split("<")[0]) < 0
    header = folder / FORMATS["c-header"]
    assert "_RIGTOOL_" not in header.read_text()
    assert "m follows s with RIGTOOL_TAU_A_S" in header.read_text()
    if CC is not None:
        (tmp / "dyn.c").write_text(f'''#include <stdio.h>
#include "{header}"
int main(void) {{
    printf("%d %.17g %.17g %.17g %.17g\\n", RIGTOOL_HAS_DYNAMICS, RIGTOOL_TAU_N_S,
           RIGTOOL_TAU_A_S, RIGTOOL_INFLOW_GAIN, RIGTOOL_DELAY_S);
    return 0;
}}
''')
        subprocess.run([CC, "-std=c99", "-Wall", "-Werror", str(tmp / "dyn.c"), "-o",
                        str(tmp / "dyn"), "-lm"], check=True)
        got = subprocess.run([str(tmp / "dyn")], capture_output=True, text=True,
                             check=True).stdout.split()
        assert got[0] == "1"
        np.testing.assert_allclose([float(x) for x in got[1:]],
                                   [dyn[k].value for k in ("tau_n", "tau_a", "g", "delay")],
                                   rtol=1e-9)
    no_dyn = yaml.safe_load((steady / FORMATS["ros2"]).read_text())["/**"][
        "ros__parameters"]["rigtool"]
    assert no_dyn["dynamics_model"] == "none" and "time_constant_s" not in no_dyn
    capsys.readouterr()
    assert main([*args[:3], cal.run_id, *args[4:], "--format", "ros2"]) == 2
    assert "no identified dynamics" in capsys.readouterr().err
    (tmp / "other.yaml").write_text(text.replace("thruster_id: stern-1", "thruster_id: bow-9"))
    assert main(["sweep", str(tmp / "other.yaml"), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "steps")]) == 0
    capsys.readouterr()
    assert main([*args[:3], "last", *args[4:], "--format", "ros2"]) == 2
    assert "would mix two thrusters" in capsys.readouterr().err
