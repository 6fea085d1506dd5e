"""Vehicle artefacts: the C header compiles and agrees with cal.command(), ROS 2 parameters
load as YAML, and the Gazebo thrust coefficient reproduces C_p (issue: artefacts a vehicle
team drops in)."""

from __future__ import annotations

import math
import shutil
import subprocess

import numpy as np
import pytest
import yaml

import rigtool
from rigtool import cli
from rigtool.artefacts import vehicle
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
RIGS = {"esc": dict(profile="esc-1100-1900", unit="pulse_us", lo=1100, hi=1900, step=20),
        "can": dict(profile="can-bldc", unit="percent", lo=-100, hi=100, step=5)}


@pytest.fixture(scope="module", params=sorted(RIGS))
def exported(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(request.param)
    (tmp / "p.yaml").write_text(PROTOCOL.format(**RIGS[request.param]))
    db, out = str(tmp / "db.sqlite"), tmp / "cal"
    assert main(["sweep", str(tmp / "p.yaml"), "--sim", "--db", db]) == 0
    formats = [a for f in vehicle.FORMATS for a in ("--export", f)]
    assert main(["calibrate", "last", "--db", db, "--out", str(out), *formats]) == 0
    folder = next(out.iterdir())
    return tmp, db, folder, rigtool.load_calibration(folder)


def test_cli_and_module_agree_on_the_formats():
    assert tuple(cli.VEHICLE_FORMATS) == tuple(vehicle.FORMATS)


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_c_header_compiles_and_matches_cal_command(exported):
    tmp, _, folder, cal = exported
    header = folder / vehicle.FORMATS["c-header"]
    assert "units: thrust N" in header.read_text() and cal.run_id in header.read_text()
    probe = np.linspace(-60.0, 60.0, 2401)
    (tmp / "probe.txt").write_text("\n".join(repr(float(f)) for f in probe) + "\n")
    (tmp / "main.c").write_text(f'''#include <stdio.h>
#include "{header}"
int main(void) {{
    for (int i = 0; i < RIGTOOL_N_TEST; ++i) {{
        double c = rigtool_command_for_thrust(rigtool_test_thrust[i]);
        double want = rigtool_test_command[i];
        if (!(fabs(c - want) <= 1e-9 * (1.0 + fabs(want)) || (isnan(c) && isnan(want)))) {{
            printf("test %d\\n", i);
            return 1;
        }}
    }}
    double f;
    while (scanf("%lf", &f) == 1) printf("%.17g\\n", rigtool_command_for_thrust(f));
    return 0;
}}
''')
    exe = tmp / "probe"
    subprocess.run([CC, "-std=c99", "-Wall", "-Werror", "-O2", str(tmp / "main.c"), "-o",
                    str(exe), "-lm"], check=True)
    run = subprocess.run([str(exe)], input=(tmp / "probe.txt").read_text(), text=True,
                         capture_output=True, check=True)
    got = np.array([float(x) for x in run.stdout.split()])
    want = cal.command(probe)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    span = np.nanmax(want) - np.nanmin(want)
    ok = np.isfinite(want)
    assert ok.sum() > 1000 and np.max(np.abs(got[ok] - want[ok])) <= 1e-6 * span


def test_ros2_parameters_load_and_hold_the_map(exported):
    _, _, folder, cal = exported
    doc = yaml.safe_load((folder / vehicle.FORMATS["ros2"]).read_text())
    p = doc["/**"]["ros__parameters"]["rigtool"]
    assert p["source_run"] == cal.run_id and p["command_unit"] == cal.command_unit
    assert p["neutral_command"] == cal.neutral and p["thruster_id"] == "stern-1"
    f, c = np.array(p["map_forward_thrust_n"]), np.array(p["map_forward_command"])
    assert f.size > 3 and np.all(np.diff(f) > 0)
    np.testing.assert_allclose(cal.command(f), c, rtol=1e-7)
    assert p["thrust_coefficient_forward"] == pytest.approx(cal.coefficients["C_p_fwd"].value)
    assert len(p["dead_band"]) % 2 == 0


def test_gazebo_coefficient_reproduces_c_p(exported):
    _, _, folder, cal = exported
    text = (folder / vehicle.FORMATS["gazebo"]).read_text()
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
    assert (tmp / "again" / cal.run_id / vehicle.FORMATS["ros2"]).read_text().split("\n", 3)[3] \
        == (folder / vehicle.FORMATS["ros2"]).read_text().split("\n", 3)[3]
    (tmp / "bare.yaml").write_text((tmp / "p.yaml").read_text().replace(
        "metadata: {thruster_id: stern-1, propeller_diameter_m: 0.1, water_density_kg_m3: 1000}",
        "metadata: {thruster_id: stern-2}"))
    assert main(["sweep", str(tmp / "bare.yaml"), "--sim", "--db", db]) == 0
    capsys.readouterr()
    assert main(["export-cal", "last", "--format", "c-header", "--db", db]) == 2
    assert "has not been calibrated" in capsys.readouterr().err
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp / "bare")]) == 0
    capsys.readouterr()
    assert main(["export-cal", "last", "--format", "gazebo", "--db", db,
                 "--out", str(tmp / "bare")]) == 2
    assert "propeller diameter and water density" in capsys.readouterr().err
