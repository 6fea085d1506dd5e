"""Acceptance: calibrating twin runs recovers the profile's physics (issue: calibrate and report).

These run the shipped protocols on the simulator and check the fitted coefficients,
dead zones and break-aways against the values the twin was built with.
"""

from __future__ import annotations

import json

import pytest

from rigtool.analysis.calibrate import calibrate_run
from rigtool.cli import main
from rigtool.store import Store
from rigtool.thruster_profiles import PROFILES

from .conftest import PROTOCOLS, copy_db

CAN = PROFILES["can-bldc"]


@pytest.fixture(scope="module")
def baseline(tmp_path_factory, shipped_sweep):
    """One full luo2020-baseline run (401 points, 1.2 M samples): the session's sweep
    (conftest.shipped_sweep), copied for the tests here."""
    db = copy_db(shipped_sweep("luo2020-baseline"),
                 tmp_path_factory.mktemp("baseline") / "runs.sqlite")
    store = Store(db)
    return store, store.resolve_run_id("last")


def _within(coef, true_value: float, rel: float) -> None:
    assert abs(coef.value - true_value) <= rel * true_value, (coef, true_value)
    assert coef.lo <= true_value <= coef.hi, (coef, true_value)


def test_baseline_stores_401_points_and_1203000_samples(baseline):
    store, run_id = baseline
    assert len(store.steps(run_id)) == 401
    assert store.conn.execute("SELECT sum(n) FROM sample_blocks").fetchone()[0] == 1_203_000
    assert store.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"


def test_baseline_recovers_cp_and_cn(baseline):
    store, run_id = baseline
    (sec,) = calibrate_run(store, run_id).sections
    _within(sec.fits["C_p_fwd"], CAN.cp_forward, 0.01)
    _within(sec.fits["C_p_rev"], CAN.cp_reverse, 0.01)
    assert abs(sec.fits["C_n"].value - CAN.cn) <= 0.03 * CAN.cn
    for key, cp in (("fwd", CAN.cp_forward), ("rev", CAN.cp_reverse)):
        c_i = cp / CAN.cn ** (2 / 3)  # f = C_i I^(2/3) with the idle current taken off
        _within(sec.fits[f"C_i_{key}"], c_i, 0.01)
        _within(sec.fits[f"C_i_{key}_direct"], c_i, 0.01)


@pytest.mark.parametrize("cp, cn", [(2.6e-5, 0.9e-9), (1.4e-5, 1.8e-9)])
def test_overridden_thruster_is_recovered(write_yaml, tmp_path, cp, cn):
    rig = write_yaml(f"""\
name: other-thruster
simulator:
  profile: can-bldc
  seed: 11
  overrides: {{cp_forward: {cp}, cp_reverse: {0.75 * cp}, cn: {cn}}}
""", "rig.yaml")
    protocol = (PROTOCOLS / "luo2020-baseline.yaml").read_text().replace(
        "step: 0.5}", "step: 4}").replace("samples: 3000", "samples: 1500")
    db = tmp_path / "o.sqlite"
    assert main(["sweep", str(write_yaml(protocol)), "--rig", str(rig), "--db", str(db)]) == 0
    store = Store(db)
    (sec,) = calibrate_run(store, store.resolve_run_id("last")).sections
    _within(sec.fits["C_p_fwd"], cp, 0.01)
    _within(sec.fits["C_p_rev"], 0.75 * cp, 0.01)
    assert abs(sec.fits["C_n"].value - cn) <= 0.03 * cn


def _zones(cal):
    (sec,) = cal.sections
    return sec.curve


def test_stm32_dead_zones_and_break_away(shipped_sweep):
    store = Store(shipped_sweep("stm32-pwm"), read_only=True)
    curve = _zones(calibrate_run(store, store.resolve_run_id("last")))
    zones = sorted(curve.dead_zones)
    assert len(zones) == 2
    (lo1, hi1), (lo2, hi2) = zones
    assert abs(lo1 - 0) <= 2 and abs(hi1 - 206) <= 2
    assert abs(lo2 - 428) <= 2 and abs(hi2 - 445) <= 2
    assert any(abs(b - 451) <= 1 for b in curve.break_aways)


def test_esc_deadband(tmp_path, capsys, shipped_sweep):
    db = copy_db(shipped_sweep("esc-1100-1900"), tmp_path / "e.sqlite")
    out = tmp_path / "cal"
    assert main(["calibrate", "last", "--out", str(out), "--db", str(db)]) == 0
    run_id = Store(db).resolve_run_id("last")
    doc = json.loads((out / run_id / "calibration.json").read_text())
    text = json.dumps(doc)
    assert "dead_zones" in text
    curve = _zones(calibrate_run(Store(db), run_id))
    ((lo, hi),) = curve.dead_zones
    assert abs(lo - 1475) <= 4 and abs(hi - 1525) <= 4
