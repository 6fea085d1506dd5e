"""Each shipped step-response protocol is the dynamics of a shipped steady protocol: the same
twin (profile) and the same thruster id, so the documented pairing (docs/artefacts.md, "Time
constants") runs through the CLI as a user types it: sweep both, calibrate the step run,
calibrate the steady run with `--export ros2 --dynamics STEP_RUN`, report; every step exit 0."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rigtool.cli import main
from rigtool.store import Store

from .conftest import PROTOCOLS, copy_db

PAIRS = {"dynamics-steps": "luo2020-baseline", "dynamics-steps-esc": "esc-1100-1900"}


def _protocol(name: str) -> dict:
    return yaml.safe_load((PROTOCOLS / f"{name}.yaml").read_text())


def _twin(name: str) -> tuple[str, str, str]:
    """(simulator profile, thruster id, command unit) of a shipped protocol."""
    doc = _protocol(name)
    return doc["simulator"]["profile"], doc["metadata"]["thruster_id"], doc["command"]["unit"]


def test_every_shipped_step_protocol_has_its_steady_pair():
    steps = sorted(p.stem for p in PROTOCOLS.glob("*.yaml")
                   if "steps" in _protocol(p.stem)["command"])
    assert steps == sorted(PAIRS)
    for step, steady in PAIRS.items():
        assert "steps" not in _protocol(steady)["command"]
        assert _twin(step) == _twin(steady), (step, steady)


@pytest.mark.slow
@pytest.mark.parametrize("steps", sorted(PAIRS))
def test_documented_dynamics_pairing(steps, tmp_path, shipped_sweep, capsys):
    db = str(copy_db(shipped_sweep(PAIRS[steps]), tmp_path / "lab.sqlite"))
    out = tmp_path / "calibrations"
    assert main(["sweep", str(PROTOCOLS / f"{steps}.yaml"), "--sim", "--db", db]) == 0
    with Store(Path(db), read_only=True) as store:
        step_run, steady_run = (r["id"] for r in store.runs(limit=2))
    assert main(["calibrate", step_run, "--db", db, "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["calibrate", steady_run, "--db", db, "--out", str(out), "--export", "ros2",
                 "--dynamics", step_run]) == 0, capsys.readouterr().err
    params = yaml.safe_load((out / steady_run / "thruster_params.yaml").read_text())
    values = params["/**"]["ros__parameters"]["rigtool"]
    assert values["dynamics_source_run"] == step_run
    assert values["dynamics_model"] != "none" and values["time_constant_s"] > 0
    assert main(["report", steady_run, "--db", db, "--out", str(out)]) == 0
    assert (out / steady_run / "report.html").is_file()
