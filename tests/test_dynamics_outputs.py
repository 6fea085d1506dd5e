"""Every dynamics output says what happened, through the CLI: garbage gives no dynamics and
no export carries any; valid step protocols give a result or a one-line reason; a settling
time cut off by the end of its window is shown as such; a step run reports no hysteresis."""

from __future__ import annotations

import json
import random

import pytest

from rigtool.artefacts.formats import FORMATS
from rigtool.cli import main

from .dynamics_helpers import (
    dynamics_doc,
    import_steps,
    sweep_steady,
    sweep_steps,
    tyto_rows,
    write_csv,
)

ESC_STEPS = [1500, 1680, 1500, 1840, 1680, 1500, 1320, 1500, 1160, 1320, 1500]
ESC_TRUTH = {"tau_s": 0.17, "inflow_gain": 0.2, "inflow_tau_s": 0.55}


def _headers(tmp_path, db: str, dynamics_run: str) -> list[str]:
    """The C headers of the last run exported with `dynamics_run`'s dynamics: none when the
    export refuses that run (exit 2), which carries no dynamics either."""
    out = tmp_path / "export"
    assert main(["export-cal", "last", "--db", db, "--format", "c-header", "--dynamics",
                 dynamics_run, "--out", str(out)]) in (0, 2)
    return [p.read_text() for p in out.rglob(FORMATS["c-header"])]


def test_pure_noise_gives_no_dynamics_and_no_export_carries_it(tmp_path, capsys):
    """sigma 50 N on a thruster giving no thrust: no dynamics identified, said in a warning,
    and a header exported with this run's dynamics has RIGTOOL_HAS_DYNAMICS 0."""
    truth = {"cp_forward": 1e-12, "cp_reverse": 1e-12, "force_noise_n": 50}
    db, folder = sweep_steps(tmp_path, "noise", "can-bldc", [0, 45, 0, 85, 0, -45, 0], 3401,
                             truth, hold=1.5, rate=200)
    doc = dynamics_doc(folder)
    assert doc is None or not doc.get("identified", True)
    assert "no dynamics identified" in capsys.readouterr().err
    run_id = folder.name
    sweep_steady(tmp_path, db, "can-bldc", 3402)
    for header in _headers(tmp_path, db, run_id):
        assert "#define RIGTOOL_HAS_DYNAMICS 0" in header and "RIGTOOL_TAU_N_S" not in header


def test_reversed_timestamps_give_no_dynamics(tmp_path, capsys):
    """A step log whose time column runs backwards: the step run gets no dynamics, with the
    reason in one line, and no export takes them."""
    rows = tyto_rows(ESC_STEPS, ESC_TRUTH, 3403)
    times = [r[0] for r in rows][::-1]
    rows = [[t, *r[1:]] for t, r in zip(times, rows, strict=True)]
    db = str(tmp_path / "rev.sqlite")
    folder = import_steps(tmp_path, write_csv(tmp_path / "rev.csv", rows), db)
    doc = dynamics_doc(folder)
    warnings = [w for w in json.loads((folder / "calibration.json").read_text())["warnings"]
                if "dynamics" in w]
    assert doc is None or not doc["identified"]
    assert len(warnings) == 1 and "backwards" in warnings[0] and "\n" not in warnings[0]
    assert "no dynamics identified" in capsys.readouterr().err
    for header in _headers(tmp_path, db, folder.name):
        assert "#define RIGTOOL_HAS_DYNAMICS 0" in header


@pytest.mark.parametrize("steps", [[50, 50, 50, 50], [0, 0]], ids=["same-level", "zeros"])
def test_steps_without_a_step_give_a_reason(tmp_path, capsys, steps):
    db, folder = sweep_steps(tmp_path, "flat", "can-bldc", steps, 3404, {}, hold=1.0, rate=200)
    assert dynamics_doc(folder) is None
    err = capsys.readouterr().err
    assert "no dynamics identified: every level commands" in err


def test_many_short_alternating_steps_give_a_result(tmp_path):
    """400 alternating steps of 20 samples each (full forward to full reverse)."""
    _, folder = sweep_steps(tmp_path, "alt", "esc-1100-1900", [1100, 1900] * 200, 3405,
                            {"tau_s": 0.05}, hold=0.2, rate=100)
    doc = dynamics_doc(folder)
    assert doc is not None and doc["identified"]
    assert doc["models"][doc["selected"]]["tau_n"]["value"] == pytest.approx(0.05, rel=0.05)


def test_missing_non_finite_thrust_and_equal_timestamps_give_a_result(tmp_path):
    """A step log with nan, inf and empty thrust cells and 10 ms time stamps at 200 Hz
    (pairs of equal times) still identifies the thruster."""
    rng = random.Random(3406)
    rows = tyto_rows(ESC_STEPS, ESC_TRUTH, 3406)
    for r in rows:
        r[0] = f"{round(float(r[0]) / 0.01) * 0.01:.2f}"
        if rng.random() < 0.03:
            r[2] = rng.choice(["nan", "inf", ""])
    db = str(tmp_path / "bad.sqlite")
    doc = dynamics_doc(import_steps(tmp_path, write_csv(tmp_path / "bad.csv", rows), db))
    assert doc is not None and doc["identified"] and doc["selected"] == "two-state"
    assert doc["models"]["two-state"]["tau_n"]["value"] == pytest.approx(0.17, rel=0.05)


def test_censored_settling_and_no_hysteresis_from_steps(tmp_path, capsys):
    """A slow thruster in 1.2 s holds: the step table says the steps did not settle in the
    window instead of printing the window's end; the step run reports no hysteresis."""
    db, folder = sweep_steps(tmp_path, "slow", "can-bldc", [0, 60, 20, 0, -60, 0], 3407,
                             {"tau_s": 0.9}, hold=1.2, rate=200)
    doc = json.loads((folder / "calibration.json").read_text())
    steps = doc["dynamics"]["steps"]
    assert steps and all(not s.get("settled", True) and s["settling_s"] is None for s in steps)
    assert all(d.get("hysteresis") is None for d in doc["depths"])
    assert "hysteresis" not in capsys.readouterr().out
    assert main(["report", "last", "--db", db, "--out", str(tmp_path / "report")]) == 0
    html = next((tmp_path / "report").rglob("report.html")).read_text()
    table = html.split('id="dynamics-steps"')[1].split("</table>")[0]
    assert table.count("&gt; 1.2 s (not settled in the window)") == len(steps)
