"""Thruster dynamics from step responses, through the CLI on twins with a known truth: the
two-state model and its time constants when the twin has inflow dynamics, the one-state model
when it has none, and a held-out step sequence predicted from the identified model."""

from __future__ import annotations

import json

import numpy as np
import pytest

import rigtool
from rigtool.cli import main
from rigtool.protocol import Protocol

PROTOCOL = """\
rigtool_protocol: 1
name: steps
simulator: {{profile: {profile}, seed: {seed}, overrides: {overrides}}}
command: {{unit: {unit}, steps: {steps}}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {{seconds: 0}}
  acquire: {{seconds: 2.5, rate_hz: 500}}
  rest_s: 0
  tare: at_start
"""
CAN_STEPS = [0, 40, 0, 80, 40, 0, -40, 0, -80, -40, 0]
ESC_STEPS = [1500, 1650, 1500, 1800, 1650, 1500, 1350, 1500, 1200, 1350, 1500]
# (profile, unit, steps, seed, truth): two parameter sets with inflow, one without
CASES = [
    ("can-bldc", "percent", CAN_STEPS, 2201, {"tau_s": 0.25, "inflow_gain": 0.3,
                                              "inflow_tau_s": 0.7}),
    ("esc-1100-1900", "pulse_us", ESC_STEPS, 2202, {"tau_s": 0.12, "inflow_gain": 0.45,
                                                    "inflow_tau_s": 0.35,
                                                    "command_delay_s": 0.025}),
    ("can-bldc", "percent", CAN_STEPS, 2203, {"tau_s": 0.4, "inflow_gain": 0.0}),
]


def _run(tmp_path, profile, unit, steps, seed, truth, name="a"):
    over = "{" + ", ".join(f"{k}: {v}" for k, v in truth.items()) + "}"
    path = tmp_path / f"{name}.yaml"
    path.write_text(PROTOCOL.format(profile=profile, unit=unit, steps=steps, seed=seed,
                                    overrides=over))
    db, out = str(tmp_path / "db.sqlite"), tmp_path / f"cal-{name}"
    assert main(["sweep", str(path), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(out)]) == 0
    assert main(["report", "last", "--db", db, "--out", str(out)]) == 0
    return db, next(out.iterdir())


@pytest.mark.parametrize("case", CASES, ids=["can-inflow", "esc-inflow", "can-first-order"])
def test_models_are_recovered_and_selected(tmp_path, case):
    profile, unit, steps, seed, truth = case
    _, folder = _run(tmp_path, profile, unit, steps, seed, truth)
    doc = json.loads((folder / "calibration.json").read_text())["dynamics"]
    has_inflow = truth["inflow_gain"] > 0
    assert doc["selected"] == ("two-state" if has_inflow else "one-state")
    model = doc["models"][doc["selected"]]
    checks = [("tau_n", truth["tau_s"])]
    if has_inflow:
        checks += [("tau_a", truth["inflow_tau_s"]), ("g", truth["inflow_gain"])]
    for key, value in checks:
        c = model[key]
        assert c["value"] == pytest.approx(value, rel=0.05), key
        assert c["lo"] <= value <= c["hi"], key
    delay = model["delay"]
    assert delay["value"] == pytest.approx(truth.get("command_delay_s", 0.0), abs=1e-3)
    assert delay["lo"] <= truth.get("command_delay_s", 0.0) <= delay["hi"]
    settled = [s for s in doc["steps"] if s["settled"]]
    assert settled and all(s["rise_s"] > 0 for s in settled)
    assert all(s["rise_s"] is None for s in doc["steps"] if not s["settled"])
    html = (folder / "report.html").read_text()
    assert 'id="fig-dynamics"' in html and 'id="dynamics-steps"' in html


def test_twin_command_delay_shifts_the_response():
    """A delayed twin gives the undelayed twin's thrust, shifted by the delay, also when two
    commands are sent at the same instant (the last one holds)."""
    from rigtool.sim.physics import ThrusterTwin
    from rigtool.thruster_profiles import profile_with_overrides

    delay, t = 0.03, np.arange(0.0, 3.0, 0.002)
    over = {"inflow_gain": 0.3}
    late = ThrusterTwin(profile_with_overrides("can-bldc", {**over, "command_delay_s": delay}), 1)
    now = ThrusterTwin(profile_with_overrides("can-bldc", over), 1)

    def run(twin, shift):
        out, prev = [], 0.0
        for when, commands in [(1.0, [60]), (1.5, [20, -20]), (2.2, [0])]:
            out.append(twin.sample(t[(t >= prev + shift) & (t < when + shift)]).thrust_true_n)
            for c in commands:
                twin.set_command(when + shift, c)
            prev = when
        out.append(twin.sample(t[t >= prev + shift]).thrust_true_n)
        return np.concatenate(out)

    delayed, shifted = run(late, 0.0), run(now, delay)
    lead = delayed.size - shifted.size
    assert lead == round(delay / 0.002)
    assert np.all(delayed[:lead] == 0.0)
    np.testing.assert_allclose(delayed[lead:], shifted, atol=1e-9)
    assert late.command == 0.0 and np.min(delayed) < -1.0


def test_held_out_steps_are_predicted_within_two_percent(tmp_path):
    """Identify on one step sequence; predict another (other levels, other seed) from the
    command alone, with the steady map of a steady sweep of the same thruster."""
    truth = {"tau_s": 0.25, "inflow_gain": 0.3, "inflow_tau_s": 0.7}
    db, folder = _run(tmp_path, "can-bldc", "percent", CAN_STEPS, 2211, truth)
    dyn = rigtool.load_calibration(folder).dynamics
    steady_path = tmp_path / "steady.yaml"
    steady_path.write_text(PROTOCOL.format(
        profile="can-bldc", unit="percent", steps="[0]", seed=2212,
        overrides="{" + ", ".join(f"{k}: {v}" for k, v in truth.items()) + "}").replace(
        "steps: [0]", "range: {start: -100, stop: 100, step: 5}").replace(
        "settle: {seconds: 0}", "settle: {seconds: 3}"))
    assert main(["sweep", str(steady_path), "--sim", "--db", db]) == 0
    assert main(["calibrate", "last", "--db", db, "--out", str(tmp_path / "steady")]) == 0
    steady = rigtool.load_calibration(next((tmp_path / "steady").iterdir()))
    _, held = _run(tmp_path, "can-bldc", "percent", [0, 55, 20, 70, 0, -25, -65, 0], 2213,
                   truth, name="held")
    with rigtool.open(db) as lab:
        run = lab.run("last")
        points = run.points()
        samples = run.samples(columns=["t_s", "thrust_n", "command"])
    predicted = dyn.simulate(samples["t_s"], samples["command"], steady=steady.thrust)
    zero = json.loads((held / "calibration.json").read_text())["dynamics"]["zero_n"]
    full_scale = float(np.max(np.abs(points["thrust_all_mean_n"])))
    rms = float(np.sqrt(np.mean((predicted + zero - samples["thrust_n"]) ** 2)))
    assert rms < 0.02 * full_scale


def test_steps_need_no_settle_and_no_rest(tmp_path):
    import yaml

    text = PROTOCOL.format(profile="can-bldc", unit="percent", steps=CAN_STEPS, seed=1,
                           overrides="{}")
    protocol = Protocol.model_validate(yaml.safe_load(text))
    assert [s.command for s in __import__("rigtool.plan").plan.expand(protocol)] == CAN_STEPS
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("settle: {seconds: 0}", "settle: {seconds: 1}"))
    assert main(["sweep", str(bad), "--sim", "--db", str(tmp_path / "d.sqlite")]) == 2
