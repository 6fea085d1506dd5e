"""Electrical power and efficiency per point against the twin's truth, the manufacturer-style
performance table and its round trip through `rigtool import` (issue: power and efficiency)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from rigtool.analysis.dataset import Samples
from rigtool.analysis.steady import steady_windows
from rigtool.cli import main
from rigtool.sim.physics import ThrusterTwin
from rigtool.thruster_profiles import profile_with_overrides

PROTOCOL = """\
rigtool_protocol: 1
name: efficiency
simulator: {{profile: can-bldc, seed: {seed}, overrides: {overrides}}}
command: {{unit: percent, range: {{start: -100, stop: 100, step: 25}}, order: up}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 1.5}}
  acquire: {{samples: 1000, rate_hz: 1000}}
  tare: at_start
"""
# The default twin, and one with a sagging 24 V supply and a hungrier motor.
CASES = [(21, {}), (22, {"supply_voltage_v": 24.0, "supply_resistance_ohm": 0.4,
                         "cn": 1.6e-9})]


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


@pytest.fixture(params=CASES, ids=["default", "sagging-24V"])
def calibrated(request, tmp_path):
    seed, overrides = request.param
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL.format(seed=seed, overrides=overrides or "{}"))
    db, out = str(tmp_path / "db.sqlite"), tmp_path / "cal"
    assert main(["sweep", str(protocol), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    folder = next(out.iterdir())
    return db, folder, profile_with_overrides("can-bldc", overrides)


def test_thrust_per_watt_matches_the_twin(calibrated):
    """At every live command, N/W is within 2 % of the twin's noise-free truth (at 50 % too),
    and the truth lies inside the point's 95 % interval for most points."""
    _, folder, profile = calibrated
    twin = ThrusterTwin(profile, seed=0)
    inside = checked = 0
    for row in _rows(folder / "points.csv"):
        command = float(row["command"])
        if abs(command) < 25:
            continue
        _, thrust, current = twin.steady_state(command)
        volts = profile.supply_voltage_v - profile.supply_resistance_ohm * current
        truth = abs(thrust) / (volts * current)
        got, se = float(row["efficiency_n_per_w"]), float(row["efficiency_se_n_per_w"])
        assert got == pytest.approx(truth, rel=0.02), command
        assert float(row["efficiency_g_per_w"]) == pytest.approx(got * 1000 / 9.80665)
        inside += abs(got - truth) <= 1.96 * se
        checked += 1
    assert checked == 8 and inside >= 6


def test_power_is_the_mean_of_the_product():
    """V and I that move against each other: mean(V I) differs from mean(V) mean(I)."""
    n = 400
    i = 5.0 + np.where(np.arange(n) % 2, 2.0, -2.0)
    v = 48.0 - 0.5 * (i - 5.0)
    samples = Samples(t_s=np.arange(n) / 1000.0, thrust_n=np.full(n, 10.0),
                      speed_rpm=np.full(n, 1000.0), current_a=i, voltage_v=v,
                      point=np.zeros(n, dtype=np.int64), offsets=np.array([0, n]))
    power = steady_windows(samples).channels["power_w"].mean[0]
    assert power == pytest.approx(np.mean(v * i)) and power != pytest.approx(48.0 * 5.0)


def test_performance_table_round_trips_through_import(calibrated, capsys):
    db, folder, _ = calibrated
    table = _rows(folder / "performance.csv")
    assert list(table[0]) == ["Depth (m)", "ESC (percent)", "Motor Optical Speed (RPM)",
                              "Current (A)", "Voltage (V)", "Electrical Power (W)",
                              "Thrust (N)", "Force (kgf)", "Efficiency (g/W)"]
    assert main(["import", str(folder / "performance.csv"), "--db", db]) == 0
    import rigtool

    with rigtool.open(db) as lab:
        points = lab.run("last").points()
        volts = lab.run("last").samples(columns=["voltage_v"])["voltage_v"]
    for key, column in (("command", "ESC (percent)"), ("depth_m", "Depth (m)"),
                        ("thrust_all_mean_n", "Thrust (N)"),
                        ("speed_all_mean_rpm", "Motor Optical Speed (RPM)"),
                        ("current_all_mean_a", "Current (A)")):
        np.testing.assert_allclose(points[key], [float(r[column]) for r in table], rtol=1e-8)
    np.testing.assert_allclose(volts, [float(r["Voltage (V)"]) for r in table], rtol=1e-8)


def test_report_has_the_efficiency_figure_or_says_why_not(calibrated, tmp_path):
    db, folder, _ = calibrated
    assert main(["report", "last", "--db", db, "--out", str(folder.parent)]) == 0
    assert 'data-figure="efficiency"' in (folder / "report.html").read_text()
    esc = tmp_path / "esc.yaml"  # the ESC twin reports speed and current, but no voltage
    esc.write_text(PROTOCOL.format(seed=3, overrides="{}").replace("can-bldc", "esc-1100-1900")
                   .replace("unit: percent, range: {start: -100, stop: 100, step: 25}",
                            "unit: pulse_us, range: {start: 1100, stop: 1900, step: 100}"))
    assert main(["sweep", str(esc), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "c2"), "--report"]) == 0
    html = next((tmp_path / "c2").glob("*/report.html")).read_text()
    assert 'data-omitted="efficiency"' in html and "needs both" in html
