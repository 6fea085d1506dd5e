"""Dynamics beyond the shipped protocols, through the CLI: steps straight through zero on a
propeller whose reverse coefficient differs, a thruster that follows Yoerger's model, one that
follows Healey's inflow law (identified, or refused), and a Tyto step log imported as a step
run. Seeds and twin settings here were not used while developing."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from rigtool.analysis.dynamics_response import quadratic_hop
from rigtool.artefacts.formats import FORMATS
from rigtool.cli import main
from rigtool.sim.physics import ThrusterTwin
from rigtool.thruster_profiles import profile_with_overrides

from .dynamics_helpers import dynamics_doc, import_steps, sweep_steps, tyto_rows, write_csv

CAN_CP = 1.926e-5
ESC_CP = 50.0 / 3800.0**2


def test_steps_through_zero_keep_the_first_order_model(tmp_path):
    """50 -> -50 % style steps with C_p_rev = 0.65 C_p_fwd: one-state, tau_n within 5 % and
    in its interval, the reverse ratio seen through zero."""
    truth = {"tau_s": 0.28, "cp_reverse": 0.65 * CAN_CP}
    steps = [0, 55, -55, 55, 0, -35, 35, -85, 85, 0]
    _, folder = sweep_steps(tmp_path, "zero", "can-bldc", steps, 3301, truth)
    doc = dynamics_doc(folder)
    assert doc["identified"] and doc["selected"] == "one-state"
    model = doc["models"]["one-state"]
    tau = model["tau_n"]
    assert tau["value"] == pytest.approx(0.28, rel=0.05) and tau["lo"] <= 0.28 <= tau["hi"]
    assert model["rho"]["value"] == pytest.approx(0.65, rel=0.05)


def test_steps_through_zero_with_inflow(tmp_path):
    """The two-state truth through zero (ESC twin, C_p_rev = 0.9 C_p_fwd): no spurious
    model, tau_n, tau_a and g within 5 %."""
    truth = {"tau_s": 0.16, "inflow_gain": 0.28, "inflow_tau_s": 0.5, "cp_reverse": 0.9 * ESC_CP}
    steps = [1500, 1720, 1280, 1720, 1500, 1350, 1650, 1500]
    _, folder = sweep_steps(tmp_path, "zero2", "esc-1100-1900", steps, 3302, truth)
    doc = dynamics_doc(folder)
    assert doc["identified"] and doc["selected"] == "two-state"
    model = doc["models"]["two-state"]
    for key, value in (("tau_n", 0.16), ("tau_a", 0.5), ("g", 0.28)):
        assert model[key]["value"] == pytest.approx(value, rel=0.05), key


def test_yoerger_thruster_is_identified_and_exported(tmp_path):
    """A twin following J n' = b u - a n|n| (tau_s at full speed): the yoerger model, alpha
    within 5 %, and alpha/beta in the ROS 2 parameters in r/min."""
    truth = {"speed_law": "quadratic", "tau_s": 0.22}
    steps = [0, 25, 0, 70, 25, 0, -45, 0, -90, -45, 0]
    db, folder = sweep_steps(tmp_path, "yoerger", "can-bldc", steps, 3303, truth)
    doc = dynamics_doc(folder)
    assert doc["identified"] and doc["selected"] == "yoerger", doc["reason"]
    alpha = 1 / (2 * 0.22 * math.sqrt(CAN_CP) * 1800.0)  # in sqrt(N) units
    assert doc["models"]["yoerger"]["alpha"]["value"] == pytest.approx(alpha, rel=0.05)
    assert doc["adequacy"]["model_error_frac"] < 0.01
    out = tmp_path / "export"
    assert main(["export-cal", "last", "--db", db, "--format", "ros2", "--format", "c-header",
                 "--out", str(out)]) == 0
    run_dir = next(out.iterdir())
    p = yaml.safe_load((run_dir / FORMATS["ros2"]).read_text())["/**"][
        "ros__parameters"]["rigtool"]
    assert p["dynamics_model"] == "yoerger" and p["yoerger_state_unit"] == "r/min"
    assert p["yoerger_alpha"] == pytest.approx(1 / (2 * 0.22 * 1800.0), rel=0.05)
    assert p["yoerger_beta_forward"] == pytest.approx(p["yoerger_alpha"] / CAN_CP, rel=0.05)
    assert "#define RIGTOOL_YOERGER_ALPHA" in (run_dir / FORMATS["c-header"]).read_text()


def test_healey_inflow_thruster_is_identified_or_refused(tmp_path):
    """Healey's quadratic inflow (not a candidate): tau_n within 5 %, or no dynamics and no
    time constant in the C header."""
    truth = {"tau_s": 0.2, "inflow_law": "healey", "inflow_gain": 0.4, "inflow_tau_s": 0.5}
    steps = [0, 30, 0, 90, 30, 0, -30, 0, -90, -30, 0]
    db, folder = sweep_steps(tmp_path, "healey", "can-bldc", steps, 3304, truth)
    doc = dynamics_doc(folder)
    tau = doc["models"][doc["selected"]]["tau_n"]["value"]
    assert (doc["identified"] and abs(tau - 0.2) < 0.05 * 0.2) or not doc["identified"]
    out = tmp_path / "export"
    assert main(["export-cal", "last", "--db", db, "--format", "c-header", "--out",
                 str(out)]) == 0
    header = (next(out.iterdir()) / FORMATS["c-header"]).read_text()
    assert f"RIGTOOL_HAS_DYNAMICS {int(doc['identified'])}" in header


def test_tyto_step_log_identifies_like_a_native_step_run(tmp_path):
    """A CSV step log (time, ESC, thrust, rpm, current; commands changing at known times)
    imported as a step run gives the twin's truth, as a native run does."""
    truth = {"tau_s": 0.14, "inflow_gain": 0.32, "inflow_tau_s": 0.42}
    steps = [1500, 1660, 1500, 1820, 1660, 1500, 1340, 1500, 1180, 1340, 1500]
    db = str(tmp_path / "tyto.sqlite")
    folder = import_steps(tmp_path, write_csv(tmp_path / "tyto.csv", tyto_rows(steps, truth,
                                                                              3305)), db)
    doc = dynamics_doc(folder)
    assert doc is not None and doc["identified"] and doc["selected"] == "two-state"
    model = doc["models"]["two-state"]
    for key, value in (("tau_n", 0.14), ("tau_a", 0.42), ("g", 0.32)):
        assert model[key]["value"] == pytest.approx(value, rel=0.05), key
        assert model[key]["lo"] <= value <= model[key]["hi"], key
    assert abs(model["delay"]["value"]) < 0.005


def test_twin_integrates_the_yoerger_law_as_its_closed_form():
    """The twin's numerical Yoerger speed against the analysis' closed form, through zero."""
    p = profile_with_overrides("can-bldc", {"speed_law": "quadratic", "tau_s": 0.3,
                                            "force_noise_n": 0.0, "vibration_noise_frac": 0.0})
    twin = ThrusterTwin(p, 1)
    t = np.arange(0.0, 4.0, 0.01)
    twin.set_command(0.0, 80.0)
    first = twin.sample(t[t < 2.0]).thrust_true_n
    twin.set_command(2.0, -60.0)
    second = twin.sample(t[t >= 2.0]).thrust_true_n
    alpha = 1 / (2 * 0.3 * 1800.0)  # r/min units
    n1 = quadratic_hop(np.zeros(first.size), np.full(first.size, 1440.0**2), alpha,
                       t[t < 2.0])
    n_switch = float(quadratic_hop(np.array(0.0), np.array(1440.0**2), alpha, np.array(2.0)))
    n2 = quadratic_hop(np.full(second.size, n_switch), np.full(second.size, -1080.0**2), alpha,
                       t[t >= 2.0] - 2.0)
    cp = np.where(np.concatenate([n1, n2]) >= 0, p.cp_forward, p.cp_reverse)
    expected = cp * np.concatenate([n1, n2]) * np.abs(np.concatenate([n1, n2]))
    np.testing.assert_allclose(np.concatenate([first, second]), expected, atol=1e-6)
