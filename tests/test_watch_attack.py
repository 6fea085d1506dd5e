"""Issue 49: a hostile local client of `rigtool sweep --watch` changes nothing the sweep
stores. A real-transport sweep (STM32 bridge twin over TCP, Net F/T twin over UDP, in a
`rigtool sim` process) is run unwatched, then watched while a separate process attacks the
page (slowloris, a /data flood, malformed requests; seeded); the stored points must agree.

Before, the page was served by threads inside the sweep. Once, on a machine loaded to about
nine times its two cores, the same attack made the points read the previous command's
thrust (1.86 N for 4.90 N, 3.42 N for -1.77 N); the audit saw the rate probe read a 7 kHz
box at 4.3-5.7 kHz. On a lightly loaded machine the old code passes this test too: it guards
that the attack cannot reach the sweep, it does not reproduce the failure on demand
(test_sensor_rate.py reproduces the lost-record probe error deterministically).
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rigtool.store import Store

from .helpers import sim_process, stop_processes

PROTOCOL = """\
rigtool_protocol: 1
name: attacked
command:
  unit: pwm_counts
  values: [0, 300, 460]
depth:
  unit: cm
  values: [30]
  mode: stage
timing:
  settle: {seconds: 0.5}
  acquire: {samples: 3500, rate_hz: 7000}
  rest_s: 0.1
  tare: per_depth
  tare_s: 0.2
limits:
  max_thrust_n: 20
"""
ROOT = Path(__file__).resolve().parent.parent
ATTACK_NICE = 10  # the attacker runs at the watch server's priority, below the sweep's


def _sweep(protocol: Path, rig: Path, db: Path, watch: bool) -> list[dict]:
    """Run the sweep as its own process (attacked through its watch page when `watch`) and
    return its stored points."""
    cmd = [sys.executable, "-m", "rigtool.cli", "sweep", str(protocol), "--rig", str(rig),
           "--db", str(db)] + (["--watch", "0"] if watch else [])
    sweep = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    attack = None
    try:
        if watch:
            line = sweep.stderr.readline()
            port = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
            assert port, line
            attack = subprocess.Popen(
                ["nice", "-n", str(ATTACK_NICE), sys.executable, "-m", "tests.watch_attack",
                 port.group(1), "120", "49"], cwd=ROOT)
            time.sleep(1.0)  # the attack is under way before the rate probe
        assert sweep.wait(timeout=180) == 0, sweep.stderr.read()
    finally:
        stop_processes(attack, sweep)
    with Store(db, read_only=True) as store:
        run_id = store.resolve_run_id("last")
        assert not store.events(run_id, "sensor_rate")  # the box's 7 kHz was measured as such
        return store.steps(run_id)


@pytest.mark.slow
def test_an_attacked_watch_page_changes_nothing_the_sweep_stores(tmp_path):
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL)
    rig = tmp_path / "sim-rig.yaml"
    with sim_process(rig, "stm32-pwm", "--depth", "0.3", "--rate", "7000", "--seed", "49",
                     stdout=subprocess.DEVNULL):
        quiet = _sweep(protocol, rig, tmp_path / "quiet.sqlite", watch=False)
        attacked = _sweep(protocol, rig, tmp_path / "attacked.sqlite", watch=True)
    assert [(s["command"], s["n"], s["rate_hz"]) for s in attacked] == [
        (s["command"], s["n"], s["rate_hz"]) for s in quiet]
    for q, a in zip(quiet, attacked, strict=True):
        assert a["t_end_s"] - a["t_acquire_s"] == pytest.approx(q["t_end_s"] - q["t_acquire_s"],
                                                               abs=0.05)
        assert a["thrust_all_mean_n"] == pytest.approx(q["thrust_all_mean_n"], abs=0.3), (q, a)
