"""The live progress line shows the thrust read with the command it names, to the very end."""

from __future__ import annotations

import io
import re
import types

import pytest
from rich.console import Console

from rigtool import progress
from rigtool.engine import Engine
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve

PROTOCOL = """\
rigtool_protocol: 1
name: live-line
simulator: {profile: esc-1100-1900, seed: 5}
command: {unit: pulse_us, values: [1700, 1900]}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 250, rate_hz: 500}
  rest_s: 1.0
  tare: at_start
limits: {max_thrust_n: 90, slew_per_s: 2000}
"""
LINE = re.compile(r"cmd\s+(\S+) µs\s+depth\s+\S+ m\s+thrust\s+(\S+) N")


class TickingClock:
    """Stands in for the `time` module of rigtool.progress: every call is 1 s later, so the
    live line is redrawn on every reading instead of at most ten times a second."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        self.t += 1.0
        return self.t


def test_last_live_line_pairs_the_command_with_its_own_reading(write_yaml, db_path,
                                                               monkeypatch):
    monkeypatch.setattr(progress, "time", types.SimpleNamespace(monotonic=TickingClock().monotonic))
    screen = io.StringIO()
    reporter = progress.RichReporter(Console(file=screen, width=200, markup=False))
    setup = resolve(write_yaml(PROTOCOL), sim=True)
    rigset = open_checked(setup)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=5, command_unit="pulse_us", tool_version="test")
    try:
        assert Engine(setup.protocol, setup.plan, rigset, store, run_id,
                      reporter).run().status == "completed"
    finally:
        rigset.close()
    command, thrust = (float(x) for x in LINE.findall(screen.getvalue())[-1])
    means = {s["command"]: s["thrust_all_mean_n"] for s in store.steps(run_id)}
    assert means[1900] > 20
    if command == 1500:  # the rest after the last point, at neutral
        assert abs(thrust) < 1.0
    else:
        assert thrust == pytest.approx(means[command], rel=0.1)
