"""rigtool compare: corrections bring simulated mismatched thrusters within 2 % of each other."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigtool.analysis.compare import ThrusterCurve, compare_curves
from rigtool.cli import main
from rigtool.progress import SilentReporter
from rigtool.store import Store
from rigtool.sweep import resolve, run_sweep
from rigtool.workflows import compare

PROTOCOL = """\
rigtool_protocol: 1
name: esc-quick
simulator: {profile: esc-1100-1900, seed: 1}
command:
  unit: pulse_us
  range: {start: 1100, stop: 1900, step: 20}
  order: up
depth: {unit: m, values: [1.0], mode: preset}
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 300, rate_hz: 500}
  rest_s: 0.1
  tare: at_start
limits: {max_thrust_n: 80, slew_per_s: 4000}
"""
CP_F = 50.0 / 3800.0**2
CP_R = 0.8 * CP_F
# (thrust gain forward, thrust gain reverse, deadband in us): four mismatched stern thrusters
THRUSTERS = [(1.0, 1.0, 25.0), (0.88, 0.85, 35.0), (1.1, 1.12, 18.0), (0.95, 1.05, 30.0)]


@pytest.fixture(scope="module")
def sim_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    tmp = tmp_path_factory.mktemp("compare")
    protocol = tmp / "protocol.yaml"
    protocol.write_text(PROTOCOL)
    db = tmp / "runs.sqlite"
    store = Store(db)
    ids = []
    for k, (gf, gr, deadband) in enumerate(THRUSTERS):
        rig = tmp / f"rig{k}.yaml"
        rig.write_text(f"rigtool_rig: 1\nname: stern-{k}\nsimulator:\n  profile: esc-1100-1900\n"
                       f"  seed: {10 + k}\n  overrides: {{cp_forward: {gf * CP_F}, "
                       f"cp_reverse: {gr * CP_R}, deadband: {deadband}}}\n")
        ids.append(run_sweep(resolve(protocol, rig_path=str(rig)), store, SilentReporter()).run_id)
    store.close()
    return db, ids


@pytest.mark.parametrize("reference", [None, 0])
def test_corrections_bring_thrusters_within_two_percent(sim_runs, reference, tmp_path) -> None:
    db, ids = sim_runs
    store = Store(db, create=False)
    result, _ = compare(store, ids, None if reference is None else ids[reference],
                        tmp_path / "compare")
    assert result.spread_before > 0.15
    assert result.spread_after <= 0.02
    assert {m.branch for m in result.matches} == {"forward", "reverse"}
    for c in result.corrections:
        assert c.max_dev_after <= 0.02
    for m in result.matches:
        stack = np.vstack(list(m.after_n.values()))
        assert np.all(np.abs(stack) >= m.thrust_lo_n * 0.9)


def test_weaker_thruster_gets_a_wider_command(sim_runs, tmp_path) -> None:
    db, ids = sim_runs
    result, _ = compare(Store(db, create=False), ids, ids[0], tmp_path / "compare")
    weak = next(c for c in result.corrections if c.run_id == ids[1] and c.branch == "forward")
    ref = next(c for c in result.corrections if c.run_id == ids[0] and c.branch == "forward")
    assert weak.a > 1.0 and weak.apply(np.array([1700.0]))[0] > 1700.0
    assert ref.a == pytest.approx(1.0, abs=1e-3) and ref.b == pytest.approx(0.0, abs=1.0)


def test_cli_compare_writes_report_and_corrections(sim_runs, tmp_path: Path, capsys) -> None:
    db, ids = sim_runs
    out = tmp_path / "cmp"
    assert main(["compare", *ids, "--reference", ids[2], "--out", str(out), "--db", str(db)]) == 0
    doc = json.loads((out / "corrections.json").read_text())
    assert doc["reference"] == ids[2] and doc["spread_after"] <= 0.02
    assert len(doc["corrections"]) == 2 * len(ids)
    assert (out / "corrections.csv").read_text().startswith("run_id,label,branch,a,b,")
    html = (out / "compare.html").read_text()
    assert "data:image/svg+xml;base64," in html and "http://" not in html.replace(
        "http://www.w3.org", "")
    assert "spread between thrusters" in capsys.readouterr().out


def test_compare_curves_recovers_exact_affine_map() -> None:
    c = np.arange(1100.0, 1901.0, 20.0)

    def thrust(cmd: np.ndarray, gain: float, db: float) -> np.ndarray:
        x = np.maximum(np.abs(cmd - 1500) - db, 0)
        return np.where(cmd > 1500, gain, -0.8 * gain) * 1e-4 * x**2

    a = ThrusterCurve("a", "a", c, thrust(c, 1.0, 25), [(1480.0, 1520.0)])
    b = ThrusterCurve("b", "b", c, thrust(c, 0.81, 25), [(1480.0, 1520.0)])
    result = compare_curves([a, b], "a")
    fwd = next(x for x in result.corrections if x.run_id == "b" and x.branch == "forward")
    assert fwd.a == pytest.approx(1 / 0.9, rel=0.01)
    assert result.spread_after < 0.01


def test_compare_needs_two_runs() -> None:
    c = np.arange(1100.0, 1901.0, 100.0)
    with pytest.raises(Exception, match="at least two"):
        compare_curves([ThrusterCurve("a", "a", c, c - 1500)])
