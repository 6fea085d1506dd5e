"""The CLI package (docs/cli.md): every command parses and answers --help; --db, the run and
--out come from one shared parent parser each; a sweep exits with the status its outcome
carries; `calibrate` renders its own table."""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys

import pytest

import rigtool
from rigtool.cli import build_parser, main
from rigtool.cli.calibration_table import summary_rows
from rigtool.cli.options import CALIBRATIONS_OUT, DB, RUN
from rigtool.engine import Outcome
from rigtool.errors import (
    EXIT_COMPLETED,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_NOT_AT_NEUTRAL,
    EXIT_USAGE,
)
from rigtool.store import Store
from rigtool.workflows import stored_results

from .conftest import ROOT, SMALL_PROTOCOL

# Every command, with the fewest arguments it parses.
MINIMAL = {"sweep": [], "watch": [], "runs": [], "show": ["last"], "calibrate": ["last"],
           "export-cal": ["last", "--format", "ros2"], "report": ["last"],
           "check": ["rig.yaml"], "sim": [], "export": [], "merge": ["a.sqlite", "-o", "b.sqlite"],
           "import": ["log.csv"], "compare": ["a", "b"],
           "identify": ["vehicle.yaml", "log.csv"], "sim-vehicle": ["--calibration", "cal"]}
WITHOUT_DB = {"check", "sim", "merge", "identify", "sim-vehicle"}  # no run database (merge
# names its own; the vehicle commands read files)
TWO_DEPTHS = """\
rigtool_protocol: 1
name: two-depths
simulator: {profile: can-bldc, seed: 7}
command: {unit: percent, range: {start: -100, stop: 100, step: 20}, order: up}
depth: {unit: m, values: [0.5, 1.0], mode: preset}
timing: {settle: {seconds: 0.3}, acquire: {samples: 100, rate_hz: 500}, rest_s: 0.0,
         tare: per_depth}
limits: {max_thrust_n: 90, slew_per_s: 400}
"""


def _commands() -> dict[str, argparse.ArgumentParser]:
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices


def _actions(parser: argparse.ArgumentParser, dest: str) -> list[argparse.Action]:
    return [a for a in parser._actions if a.dest == dest]


def test_every_command_parses_its_minimal_arguments():
    assert set(_commands()) == set(MINIMAL)
    for name, args in MINIMAL.items():
        assert callable(build_parser().parse_args([name, *args]).func)


@pytest.mark.parametrize("name", sorted(MINIMAL))
def test_each_command_takes_db_from_the_shared_parent(name):
    (db,) = DB._actions
    parser = _commands()[name]
    if name in WITHOUT_DB:
        assert "--db" not in parser._option_string_actions
        return
    assert _actions(parser, "db") == [db]  # parents= shares the parent's action itself
    args = build_parser().parse_args([name, *MINIMAL[name], "--db", "elsewhere.sqlite"])
    assert args.db == "elsewhere.sqlite"


def test_the_run_and_the_calibrations_folder_come_from_their_parents():
    (run,), (out,) = RUN._actions, CALIBRATIONS_OUT._actions
    commands = _commands()
    for name in ("show", "calibrate", "export-cal", "report"):
        assert _actions(commands[name], "run") == [run]
    for name in ("calibrate", "export-cal", "report"):
        assert _actions(commands[name], "out") == [out]
    defaults = {name: build_parser().parse_args([name, *MINIMAL[name]]).out
                for name in ("calibrate", "export", "compare")}
    assert defaults == {"calibrate": "calibrations", "export": "exports",
                        "compare": "calibrations/compare"}


@pytest.mark.parametrize("name", sorted(MINIMAL))
def test_each_command_answers_help(name, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([name, "--help"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: rigtool {name} ")


@pytest.mark.parametrize("module", ["rigtool", "rigtool.cli"])
def test_python_m_runs_the_cli(module):
    proc = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True,
                          text=True, timeout=60)
    assert (proc.returncode, proc.stdout.strip()) == (0, f"rigtool {rigtool.__version__}")


@pytest.mark.parametrize("outcome, code", [
    (Outcome("r", "completed", None, 4), EXIT_COMPLETED),
    (Outcome("r", "aborted", "thrust 25 N above 20 N", 1), EXIT_FAILED),
    (Outcome("r", "aborted", "stopped by SIGTERM", 1), EXIT_FAILED),
    (Outcome("r", "aborted", "stopped by the operator (Ctrl-C)", 1, interrupted=True),
     EXIT_INTERRUPTED),
    (Outcome("r", "aborted", "limit", 1, neutral_ok=False), EXIT_NOT_AT_NEUTRAL),
    (Outcome("r", "aborted", "Ctrl-C", 1, neutral_ok=False, interrupted=True),
     EXIT_NOT_AT_NEUTRAL),
    (Outcome("r", "completed", None, 4, neutral_ok=False), EXIT_NOT_AT_NEUTRAL),
])
def test_the_outcome_carries_its_exit_status(outcome, code):
    assert outcome.exit_status == code


def test_a_sweep_exits_with_the_status_its_outcome_carries(write_yaml, db_path, monkeypatch):
    """The CLI returns the outcome's status as it is, whatever the run's reason says."""
    from rigtool import sweep

    outcomes = []
    run_sweep = sweep.run_sweep

    def recorded(*args, **kwargs):
        outcomes.append(run_sweep(*args, **kwargs))
        return outcomes[-1]

    monkeypatch.setattr(sweep, "run_sweep", recorded)
    tripping = write_yaml(SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 20"))
    assert main(["sweep", str(tripping), "--sim", "--db", str(db_path)]) == EXIT_FAILED
    assert outcomes[-1].exit_status == EXIT_FAILED and outcomes[-1].status == "aborted"
    monkeypatch.setattr(Outcome, "exit_status", property(lambda self: 42))
    assert main(["sweep", str(tripping), "--sim", "--db", str(db_path)]) == 42


def test_sigterm_during_check_exits_1_not_ctrl_c_s_130(monkeypatch, capsys):
    """SIGTERM stops `check` (devices closed) with 1 and says so, as it does a sweep."""
    from rigtool import check

    measure = check.run_check

    def terminated(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        return measure(*args, **kwargs)

    monkeypatch.setattr(check, "run_check", terminated)
    assert main(["check", str(ROOT / "protocols/rigs/sim-can-bldc.yaml"), "--seconds", "0.5"]) == 1
    assert "rigtool: stopped by SIGTERM" in capsys.readouterr().err


def test_docs_list_every_command_and_exit_status():
    text = (ROOT / "docs" / "cli.md").read_text()
    assert [n for n in MINIMAL if f"| `rigtool {n}" not in text] == []
    codes = {int(c) for c in re.findall(r"^\| (\d+) \|", text, flags=re.M)}
    assert codes == {EXIT_COMPLETED, EXIT_FAILED, EXIT_USAGE, EXIT_NOT_AT_NEUTRAL,
                     EXIT_INTERRUPTED}
    assert "(docs/cli.md)" in (ROOT / "README.md").read_text()


def test_calibrate_prints_the_calibration_table(write_yaml, db_path, tmp_path, capsys):
    protocol = write_yaml(TWO_DEPTHS)
    assert main(["sweep", str(protocol), "--sim", "--db", str(db_path)]) == 0
    capsys.readouterr()
    assert main(["calibrate", "last", "--db", str(db_path), "--out", str(tmp_path / "cal")]) == 0
    printed = capsys.readouterr().out
    assert "calibration of run" in printed and "95 % interval" in printed
    with Store(db_path, read_only=True) as store:
        cal = stored_results(store, store.resolve_run_id("last")).calibration
    rows = summary_rows(cal)
    names = [r[0] for r in rows]
    assert "C_p_fwd @ 0.5 m" in names and "tare_drift" in names
    assert all(len(r) == 6 and isinstance(r[4], str) for r in rows)
    assert all(name in printed for name in names)
    cp = rows[names.index("C_p_fwd @ 1 m")]
    assert cp[2] < cp[1] < cp[3] and cp[4] == "N/(r/min)^2"
