"""Shaft torque about the thrust axis from a six-axis sensor: C_q and K_Q with intervals,
mechanical power and overall efficiency per point, recovered through the CLI on twins the
analysis was not tuned on; no torque (and no invented one) where the sensor gives none."""

from __future__ import annotations

import csv
import json
import math

import pytest

from rigtool.cli import main
from rigtool.sim.physics import ThrusterTwin
from rigtool.thruster_profiles import profile_with_overrides

PROTOCOL = """\
rigtool_protocol: 1
name: torque
simulator: {{profile: can-bldc, seed: {seed}, overrides: {overrides}}}
metadata: {{propeller_diameter_m: 0.1, water_density_kg_m3: 998}}
command: {{unit: percent, range: {{start: -100, stop: 100, step: 10}}}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 1.0}}
  acquire: {{seconds: 1.5, rate_hz: 500}}
  tare: at_start
"""
# torque per newton of thrust about the thrust axis (tx) is crosstalk[3]
CASES = [
    (5201, {}),
    (5202, {"crosstalk": [0.0, 0.01, 0.0, -0.02, 0.0, 0.0], "cp_forward": 2.2e-5,
            "torque_noise_nm": 0.01}),
]


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


@pytest.fixture(params=CASES, ids=["stock", "left-hand-noisy"])
def calibrated(request, tmp_path):
    seed, overrides = request.param
    over = "{" + ", ".join(f"{k}: {v}" for k, v in overrides.items()) + "}"
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL.format(seed=seed, overrides=over))
    db, out = str(tmp_path / "db.sqlite"), tmp_path / "cal"
    assert main(["sweep", str(protocol), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    return db, next(out.iterdir()), profile_with_overrides("can-bldc", overrides)


def test_torque_coefficient_is_recovered_with_its_interval(calibrated):
    _, folder, profile = calibrated
    coefs = json.loads((folder / "calibration.json").read_text())["depths"][0]["coefficients"]
    per_thrust = profile.crosstalk[3]
    for key, cp in (("fwd", profile.cp_forward), ("rev", profile.cp_reverse)):
        truth = per_thrust * cp
        c = coefs[f"C_q_{key}"]
        assert c["value"] == pytest.approx(truth, rel=0.02)
        assert c["lo"] <= truth <= c["hi"]
        assert c["unit"] == "N m/(r/min)^2"
        kq = coefs[f"K_Q_{key}"]
        assert kq["value"] == pytest.approx(abs(c["value"]) * 3600 / (998 * 0.1**5), rel=1e-9)
        assert kq["lo"] <= abs(truth) * 3600 / (998 * 0.1**5) <= kq["hi"]


def test_mechanical_power_and_overall_efficiency_per_point(calibrated):
    _, folder, profile = calibrated
    rows = {float(r["command"]): r for r in _rows(folder / "points.csv")}
    twin = ThrusterTwin(profile, seed=0)
    for command in (50.0, -70.0, 100.0):
        n, f, i = twin.steady_state(command)
        mech = abs(profile.crosstalk[3] * f) * abs(n) * 2 * math.pi / 60
        bus = profile.supply_voltage_v - profile.supply_resistance_ohm * i
        row = rows[command]
        assert float(row["mech_power_w"]) == pytest.approx(mech, rel=0.02), command
        assert float(row["overall_efficiency"]) == pytest.approx(mech / (bus * i), rel=0.03)
        assert 0 < float(row["overall_efficiency_se"]) < 0.01
    doc = json.loads((folder / "calibration.json").read_text())
    overall = doc["depths"][0]["efficiency"]["overall"]
    assert 0 < overall["max"] < 1 and overall["mech_power_w"] > 0
    assert not any("overall efficiency" in w for w in doc["warnings"])


def test_no_torque_where_the_sensor_gives_none(calibrated, tmp_path):
    """A re-imported performance table has thrust only: no C_q, torque columns are nan."""
    db, folder, _ = calibrated
    assert main(["import", str(folder / "performance.csv"), "--db", db]) == 0
    out = tmp_path / "again"
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    again = next(out.iterdir())
    coefs = json.loads((again / "calibration.json").read_text())["depths"][0]["coefficients"]
    assert "C_q_fwd" not in coefs and "K_Q_fwd" not in coefs
    row = _rows(again / "points.csv")[0]
    assert row["torque_mean_nm"] == "nan" and row["overall_efficiency"] == "nan"


def test_an_impossible_efficiency_is_flagged(tmp_path):
    """Torque ten times too large for the power drawn: the calibration says so."""
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL.format(seed=5203,
                                        overrides="{crosstalk: [0, 0, 0, 0.2, 0, 0]}"))
    db, out = str(tmp_path / "db.sqlite"), tmp_path / "cal"
    assert main(["sweep", str(protocol), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    doc = json.loads(next(out.iterdir()).joinpath("calibration.json").read_text())
    assert any("overall efficiency > 1" in w for w in doc["warnings"])
