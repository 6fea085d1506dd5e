"""`calibrate --base` and `--train-with` refuse another thruster's run, as `--dynamics` does:
exit 2, one line naming both thruster ids, nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest

from rigtool.analysis.cavitation_runs import cavitation_stage, training_runs
from rigtool.cli import main
from rigtool.store import Store

RUN = """\
rigtool_protocol: 1
name: {name}
simulator: {{profile: can-bldc, seed: {seed}}}
metadata: {{thruster_id: {thruster}}}
command: {{unit: percent, values: {commands}, order: up}}
depth: {{unit: cm, values: [{depth_cm}], mode: manual}}
timing: {{settle: {{seconds: 1.0}}, acquire: {{seconds: 1, rate_hz: 250}}, rest_s: 0.0,
         tare: per_depth}}
limits: {{max_thrust_n: 90, max_current_a: 12, max_speed_rpm: 2000, slew_per_s: 200}}
"""


def _sweep(tmp: Path, name: str, thruster: str, depth_cm: int, seed: int) -> str:
    path = tmp / f"{name}.yaml"
    commands = "[60]" if depth_cm < 60 else "[30, 50, 70, 90]"
    path.write_text(RUN.format(name=name, seed=seed, thruster=thruster, commands=commands,
                               depth_cm=depth_cm))
    assert main(["sweep", str(path), "--sim", "--db", str(tmp / "db.sqlite")]) == 0
    return Store(tmp / "db.sqlite").resolve_run_id("last")


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """Deep and shallow runs of thrusters "port-7" and "stbd-2"."""
    tmp = tmp_path_factory.mktemp("thrusters")
    ids = {"deep port": _sweep(tmp, "deep-port", "port-7", 100, 11),
           "deep stbd": _sweep(tmp, "deep-stbd", "stbd-2", 100, 12),
           "shallow stbd": _sweep(tmp, "shallow-stbd", "stbd-2", 30, 13),
           "shallow port": _sweep(tmp, "shallow-port", "port-7", 30, 14),
           "shallow port b": _sweep(tmp, "shallow-port-b", "port-7", 30, 15)}
    return tmp, ids


def _calibrate(tmp: Path, *args: str) -> int:
    return main(["calibrate", *args, "--db", str(tmp / "db.sqlite"), "--out", str(tmp / "out")])


def test_base_run_of_another_thruster_is_refused(runs, capsys):
    tmp, ids = runs
    capsys.readouterr()
    shallow, other = ids["shallow port"], ids["deep stbd"]
    assert _calibrate(tmp, shallow, "--base", other) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"rigtool: error: --base {other}: ")
    assert "'stbd-2'" in err and "'port-7'" in err
    assert not (tmp / "out").exists()


def test_training_run_of_another_thruster_is_refused(runs, capsys):
    tmp, ids = runs
    capsys.readouterr()
    shallow = ids["shallow port"]
    other = ids["shallow stbd"]
    assert _calibrate(tmp, shallow, "--base", ids["deep port"], "--train-with", other) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"rigtool: error: --train-with {other}: ")
    assert "'stbd-2'" in err and "'port-7'" in err
    assert not (tmp / "out").exists()


def test_runs_of_the_same_thruster_are_accepted(runs):
    tmp, ids = runs
    with Store(tmp / "db.sqlite") as store:
        shallow = ids["shallow port"]
        assert cavitation_stage(store, shallow, ids["deep port"]).base_run_id == ids["deep port"]
        assert training_runs(store, shallow, [ids["shallow port b"]]) == [ids["shallow port b"]]


def test_a_run_without_a_thruster_id_joins_with_a_warning_naming_both(tmp_path, capsys):
    """After an attack: with an id missing on either side the check was skipped without a
    word. A base or training run without an id, or a run without one, is accepted with a
    warning that names both runs (seeds 16-19, not developed on)."""
    ids = {"deep anon": _sweep(tmp_path, "deep-anon", "''", 100, 16),
           "shallow anon": _sweep(tmp_path, "shallow-anon", "''", 30, 17),
           "shallow port": _sweep(tmp_path, "shallow-port", "port-7", 30, 18),
           "deep port": _sweep(tmp_path, "deep-port", "port-7", 100, 19)}
    cases = [(ids["shallow port"], ["--base", ids["deep anon"]], ids["deep anon"]),
             (ids["shallow port"], ["--base", ids["deep port"], "--train-with",
                                    ids["shallow anon"]], ids["shallow anon"]),
             (ids["shallow anon"], ["--base", ids["deep port"]], ids["deep port"])]
    for run, extra, other in cases:
        capsys.readouterr()
        assert _calibrate(tmp_path, run, *extra) == 0
        warned = [w for w in capsys.readouterr().err.splitlines() if "cannot check" in w]
        assert len(warned) == 1 and run in warned[0] and other in warned[0], warned
