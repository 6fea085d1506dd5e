"""Exit statuses of `rigtool sweep` come from how the run ended (docs/cli.md, "Exit status"):
0 completed, 1 failed or tripped, 2 usage, 3 the actuator may not be at neutral, 130 Ctrl-C."""

from __future__ import annotations

import os
import signal

import pytest

from rigtool.cli import main
from rigtool.engine import Engine
from rigtool.errors import DeviceError
from rigtool.progress import SilentReporter
from rigtool.sim.devices import SimActuator
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve

from .conftest import SMALL_PROTOCOL

pytestmark = pytest.mark.usefixtures("terminal_signals")  # the tests press Ctrl-C or send SIGTERM

TRIPPING = SMALL_PROTOCOL.replace("max_thrust_n: 90", "max_thrust_n: 20")


class CtrlCAfterFirstPoint(SilentReporter):
    """Presses Ctrl-C (SIGINT to this process) once the first point is stored."""

    def step_done(self, step, thrust_n) -> None:
        if step.idx == 0:
            os.kill(os.getpid(), signal.SIGINT)


@pytest.fixture
def deaf_neutral(monkeypatch):
    """The twin's driver acknowledges the first neutral (start of run) and no later one."""
    calls = []

    def neutral(self):
        calls.append(1)
        if len(calls) > 1:
            raise DeviceError("driver did not acknowledge neutral")
        self.set_command(self.info.neutral)

    monkeypatch.setattr(SimActuator, "neutral", neutral)


def _sweep(write_yaml, db_path, text: str) -> int:
    return main(["sweep", str(write_yaml(text)), "--sim", "--db", str(db_path)])


def test_completed_run_exits_0(write_yaml, db_path):
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 0


def test_limit_trip_exits_1(write_yaml, db_path, capsys):
    assert _sweep(write_yaml, db_path, TRIPPING) == 1
    assert "actuator at neutral" in capsys.readouterr().err


def test_bad_protocol_exits_2(write_yaml, db_path):
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL.replace("values: [1.0]", "values: []")) == 2


def test_ctrl_c_exits_130_from_the_outcome(write_yaml, db_path, monkeypatch, capsys):
    monkeypatch.setattr("rigtool.cli.sweep.default_reporter", CtrlCAfterFirstPoint)
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 130
    assert "--resume" in capsys.readouterr().err
    store = Store(db_path)
    assert store.run(store.resolve_run_id("last"))["status"] == "aborted"


class CtrlCThenTerm(SilentReporter):
    """Ctrl-C once the first point is stored, then SIGTERM during the next point."""

    def step_done(self, step, thrust_n) -> None:
        if step.idx == 0:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGTERM)


@pytest.mark.parametrize("reporter, code, reason", [
    (CtrlCAfterFirstPoint, 130, "Ctrl-C"), (CtrlCThenTerm, 1, "SIGTERM")])
def test_the_signal_that_stopped_the_run_sets_the_exit_status(write_yaml, db_path, monkeypatch,
                                                               reporter, code, reason):
    """A SIGTERM after a Ctrl-C stops the run at once: the run says SIGTERM, and so does the
    exit status (1, as for SIGTERM alone), not the Ctrl-C's 130."""
    monkeypatch.setattr("rigtool.cli.sweep.default_reporter", reporter)
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == code
    store = Store(db_path)
    run = store.run(store.resolve_run_id("last"))
    assert run["status"] == "aborted" and reason in (run["stop_reason"] or "")


def test_outcome_says_whether_ctrl_c_stopped_the_run(write_yaml, db_path):
    outcomes = []
    for reporter, text in ((CtrlCAfterFirstPoint(), SMALL_PROTOCOL), (None, TRIPPING)):
        setup = resolve(write_yaml(text), sim=True)
        rigset = open_checked(setup)
        store = Store(db_path)
        run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                                  metadata={}, seed=1, command_unit="percent",
                                  tool_version="test")
        try:
            outcomes.append(Engine(setup.protocol, setup.plan, rigset, store, run_id,
                                   reporter).run())
        finally:
            rigset.close()
            store.close()
    (stopped, tripped) = outcomes
    assert stopped.status == "aborted" and stopped.interrupted
    assert tripped.status == "aborted" and not tripped.interrupted


@pytest.mark.usefixtures("deaf_neutral")
def test_unconfirmed_neutral_at_the_end_exits_3(write_yaml, db_path, capsys):
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 3
    err = capsys.readouterr().err
    assert "THE NEUTRAL COMMAND FAILED" in err and "actuator at neutral" not in err


@pytest.mark.usefixtures("deaf_neutral")
def test_unconfirmed_neutral_after_a_trip_or_ctrl_c_exits_3(write_yaml, db_path, monkeypatch):
    assert _sweep(write_yaml, db_path, TRIPPING) == 3
    monkeypatch.setattr("rigtool.cli.sweep.default_reporter", CtrlCAfterFirstPoint)
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 3


@pytest.mark.usefixtures("deaf_neutral")
def test_unconfirmed_neutral_after_an_error_exits_3(write_yaml, db_path, monkeypatch, capsys):
    def broken_read(self, n, rate_hz):
        raise OSError("sensor cable pulled")

    monkeypatch.setattr("rigtool.sim.devices.SimForceSensor.read", broken_read)
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 3
    err = capsys.readouterr().err
    last = err.splitlines()[-1]
    assert "sensor cable pulled" in last and "THE NEUTRAL COMMAND FAILED" in last
    assert "Traceback" not in err


def _signal_on_call(monkeypatch, module, name: str, sig: int) -> None:
    """Make `module.name` send `sig` to this process before it does its work."""
    original = getattr(module, name)

    def signalled(*args, **kwargs):
        os.kill(os.getpid(), sig)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, signalled)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_after_the_run_ended_leaves_the_exit_status_the_runs(write_yaml, db_path,
                                                                     monkeypatch, capfd, sig):
    """After an attack: a second signal while the rig closed and the outcome printed killed
    the process (-15, -2). It is noted (on file descriptor 2: a handler must not print
    through the console it may have interrupted), and the status stays the run's (0 here)."""
    from rigtool.cli import sweep

    _signal_on_call(monkeypatch, sweep, "_report_outcome", sig)
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 0
    assert "while closing" in capfd.readouterr().err


def test_sigterm_before_the_run_starts_exits_1(write_yaml, db_path, monkeypatch, capsys):
    """A SIGTERM while the devices open (before any run) stops the command with 1, as a
    SIGTERM during a run does (it was killed by the signal: -15)."""
    from rigtool import sweep

    _signal_on_call(monkeypatch, sweep, "open_checked", signal.SIGTERM)
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 1
    assert "stopped by SIGTERM" in capsys.readouterr().err


def test_sigterm_just_after_the_run_was_created_closes_it(write_yaml, db_path, monkeypatch,
                                                          capsys):
    """A SIGTERM between the run's creation and the engine's own handling left the run
    `running` with no reason (an attack's timed signal): it is stored `aborted`, saying why."""
    from rigtool import sweep

    _signal_on_call(monkeypatch, sweep, "Engine", signal.SIGTERM)
    assert _sweep(write_yaml, db_path, SMALL_PROTOCOL) == 1
    assert "stopped by SIGTERM" in capsys.readouterr().err
    with Store(db_path, read_only=True) as store:
        (listed,) = store.runs()
        run = store.run(listed["id"])
        assert (run["status"], run["stop_reason"]) == (
            "aborted", "stopped by SIGTERM before the first point")
