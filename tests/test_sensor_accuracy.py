"""Issue 47 item 6: a rig file states the force sensor's datasheet accuracy; calibrate adds
it as a bound to the systematic part of the thrust coefficients' intervals (not C_n's),
through the CLI on the twin; a wrong value names the file, line and field."""

from __future__ import annotations

import json
import math

import pytest

from rigtool.cli import main
from rigtool.store import Store

from .conftest import PROTOCOLS

RIG = """\
rigtool_rig: 1
name: sim-accuracy
simulator: {{profile: can-bldc, seed: 3}}
sensor_accuracy: {{nonlinearity_pct_fs: 0.5, hysteresis_pct_fs: 0.5, crosstalk_pct_fs: {xt},
                  full_scale_n: 100}}
"""


def test_declared_accuracy_reaches_the_thrust_intervals(tmp_path):
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG.format(xt=1.5))
    db, out = tmp_path / "r.sqlite", tmp_path / "cal"
    assert main(["sweep", str(PROTOCOLS / "quick-demo.yaml"), "--rig", str(rig),
                 "--db", str(db)]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(out)]) == 0
    run_id = Store(db).resolve_run_id("last")
    (depth,) = json.loads((out / run_id / "calibration.json").read_text())["depths"]
    acc, coef = depth["sensor_accuracy"], depth["coefficients"]
    top = max(abs(p) for p in (depth["thrust_law"]["fwd"]["full_scale_n"],
                               depth["thrust_law"]["rev"]["full_scale_n"]))
    want = math.sqrt(0.5**2 + 0.5**2 + 1.5**2) / 100 * 100 / top
    assert acc["thrust_share"] == pytest.approx(want, rel=0.05)
    for name in ("C_p_fwd", "C_p_rev", "C_i_fwd"):
        c = coef[name]
        share = 1e-3 + acc["thrust_share"]  # the scale allowance, then the declared bound
        assert c["systematic"] / abs(c["value"]) == pytest.approx(share, rel=1e-6), name
    assert coef["C_n"]["systematic"] / coef["C_n"]["value"] == pytest.approx(1e-3)


def test_a_negative_accuracy_names_its_line(tmp_path, capsys):
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG.format(xt=-1))
    code = main(["sweep", str(PROTOCOLS / "quick-demo.yaml"), "--rig", str(rig),
                 "--db", str(tmp_path / "r.sqlite"), "--dry-run"])
    assert code == 2
    err = capsys.readouterr().err
    assert f"{rig}:4" in err and "crosstalk_pct_fs" in err, err


def test_import_states_the_accuracy_and_calibrate_carries_it(tmp_path, capsys):
    """`rigtool import --sensor-accuracy`: with no full scale the run's largest thrust stands
    for it, so the share is the declared accuracy itself; a negative value exits 2."""
    from .standlogs import Stand, step_table

    log, db, out = tmp_path / "t.csv", tmp_path / "t.sqlite", tmp_path / "cal"
    log.write_text(step_table(Stand(), 4720)[0], encoding="utf-8")
    assert main(["import", str(log), "--db", str(db), "--sensor-accuracy",
                 "nonlinearity=0.2,crosstalk=1.5"]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(out)]) == 0
    run_id = Store(db).resolve_run_id("last")
    (depth,) = json.loads((out / run_id / "calibration.json").read_text())["depths"]
    share = math.hypot(0.2, 1.5) / 100
    assert depth["sensor_accuracy"]["thrust_share"] == pytest.approx(share)
    c = depth["coefficients"]["C_p_fwd"]
    assert c["systematic"] / c["value"] == pytest.approx(1e-3 + share)
    capsys.readouterr()
    assert main(["import", str(log), "--db", str(db), "--sensor-accuracy", "crosstalk=-1"]) == 2
    assert "--sensor-accuracy" in capsys.readouterr().err
