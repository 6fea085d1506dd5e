"""The `rigtool` command's own signal handling (rigtool.launch): a signal while Python still
imports the command, or after the run has ended, gives no traceback and keeps the status."""

from __future__ import annotations

import subprocess
import sys

import pytest

from rigtool.errors import EXIT_FAILED, EXIT_INTERRUPTED

pytestmark = pytest.mark.usefixtures("terminal_signals")  # every test here sends its child a signal

# A signal delivered to the process itself at a chosen moment, then the real entry point.
IMPORTING = """
import importlib.abc, os, signal, sys

class Interrupt(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "rigtool.cli":
            os.kill(os.getpid(), signal.{sig})
        return None

sys.meta_path.insert(0, Interrupt())
sys.argv = ["rigtool", "runs"]
from rigtool.launch import run
run()
"""

# What pydantic-core and matplotlib do when a signal's exception breaks their import: raise
# another error from it.
BROKEN_IMPORT = """
import importlib.abc, os, signal, sys

class Interrupt(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "rigtool.cli":
            try:
                os.kill(os.getpid(), signal.{sig})
                for _ in range(1000):
                    pass
            except KeyboardInterrupt as exc:
                raise RuntimeError("Error building validator") from exc
        return None

sys.meta_path.insert(0, Interrupt())
sys.argv = ["rigtool", "runs"]
from rigtool.launch import run
run()
"""

AFTER_THE_RUN = """
import os, signal, sys
import rigtool.cli
from rigtool.cli.signals import closing_signals

class Reporter:
    finished = False

def main(argv=None):
    reporter = Reporter()
    with closing_signals(reporter):
        reporter.finished = True  # the run has ended, actuator at neutral
    os.kill(os.getpid(), signal.{sig})  # after the sweep's own handlers are gone
    print("returned", flush=True)
    return 0

rigtool.cli.main = main
from rigtool.launch import run
run()
"""


def _python(code: str, tmp_path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=60, stdin=subprocess.DEVNULL)


def test_ctrl_c_while_the_command_imports_exits_130_without_a_traceback(tmp_path):
    proc = _python(IMPORTING.format(sig="SIGINT"), tmp_path)
    assert proc.returncode == EXIT_INTERRUPTED, proc.stderr
    assert "Traceback" not in proc.stderr and "rigtool: interrupted" in proc.stderr


def test_sigterm_while_the_command_imports_exits_1_naming_it(tmp_path):
    proc = _python(IMPORTING.format(sig="SIGTERM"), tmp_path)
    assert proc.returncode == EXIT_FAILED, proc.stderr
    assert "Traceback" not in proc.stderr and "stopped by SIGTERM" in proc.stderr


def test_a_signal_after_the_run_ended_keeps_the_runs_exit_status(tmp_path):
    for sig in ("SIGTERM", "SIGINT", "SIGHUP"):
        proc = _python(AFTER_THE_RUN.format(sig=sig), tmp_path)
        assert proc.returncode == 0, (sig, proc.returncode, proc.stderr)
        assert "returned" in proc.stdout and "Traceback" not in proc.stderr
        assert f"{sig} while closing: the run has ended" in proc.stderr


def test_a_stop_that_broke_an_import_ends_as_that_stop(tmp_path):
    for sig, status, words in (("SIGTERM", EXIT_FAILED, "stopped by SIGTERM"),
                               ("SIGINT", EXIT_INTERRUPTED, "rigtool: interrupted")):
        proc = _python(BROKEN_IMPORT.format(sig=sig), tmp_path)
        assert proc.returncode == status, (sig, proc.stderr)
        assert "Traceback" not in proc.stderr and words in proc.stderr
