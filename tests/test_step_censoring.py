"""Step runs say what they measured (issue: every output says what happened, after an
independent attack): a hold too short to settle shows no rise time, overshoot or end level as
measured, a step's direction follows its commanded levels, and a thrust that moves before its
command gives no dynamics (seeds and logs the fixes were not developed on)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rigtool.cli import main

PROTOCOLS = Path(__file__).resolve().parents[1] / "protocols"


def test_a_hold_too_short_to_settle_measures_no_rise_or_overshoot(tmp_path):
    text = (PROTOCOLS / "dynamics-steps.yaml").read_text()
    text = text.replace("seed: 1990", "seed: 7711").replace("seconds: 3.0", "seconds: 0.2")
    (tmp_path / "p.yaml").write_text(text)
    db, out = str(tmp_path / "db.sqlite"), str(tmp_path / "cal")
    assert main(["sweep", str(tmp_path / "p.yaml"), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", out, "--report"]) == 0
    folder = next(Path(out).iterdir())
    steps = json.loads((folder / "calibration.json").read_text())["dynamics"]["steps"]
    unsettled = [s for s in steps if not s["settled"]]
    assert unsettled, "a 0.2 s hold should leave steps unsettled"
    assert all(s["rise_s"] is None and s["overshoot_frac"] is None for s in unsettled)
    down = [s for s in steps if abs(s["command_to"]) < abs(s["command_from"])]
    assert down and all(s["direction"] == "down" for s in down)
    html = (folder / "report.html").read_text()
    assert html.count("not measured (not settled)") == 2 * len(unsettled)
    assert "(still moving)" in html


def test_thrust_before_its_command_gives_no_dynamics(tmp_path, capsys):
    """A step log whose thrust leads the command by 0.15 s (a clock offset) is refused."""
    t = np.arange(0, 18.0, 0.002)
    command = np.repeat([1500, 1700, 1500, 1850, 1500, 1300, 1500, 1150, 1500], 1000)
    target = np.where(command > 1500, (command - 1500) * 0.11, (command - 1500) * 0.085)
    thrust = np.zeros_like(t)
    for i in range(1, t.size):
        thrust[i] = thrust[i - 1] + (target[i] - thrust[i - 1]) * 0.002 / 0.12
    thrust = np.roll(thrust, -75) + np.random.default_rng(7712).normal(0, 0.05, t.size)
    rows = "\n".join(f"{a:.3f},{b},{c:.5f}" for a, b, c in zip(t, command, thrust, strict=True))
    (tmp_path / "log.csv").write_text("Time (s),ESC signal (us),Thrust (N)\n" + rows + "\n")
    db, out = str(tmp_path / "db.sqlite"), tmp_path / "cal"
    assert main(["import", str(tmp_path / "log.csv"), "--format", "steps", "--db", db]) == 0
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", db, "--out", str(out), "--export", "c-header"]) == 0
    assert "before its command" in capsys.readouterr().err
    header = next(out.iterdir()) / "thruster_calibration.h"
    assert "#define RIGTOOL_HAS_DYNAMICS 0" in header.read_text()
