"""End to end: a short sweep against `rigtool sim` running as a separate process, real drivers only.

The sweep talks to the STM32 bridge twin over TCP (socket://), the Net F/T twin over
loopback UDP (+ its HTTP calibration page) and the stage twin over a pty.
"""

from __future__ import annotations

import random

import pytest

from rigtool.cli import main
from rigtool.store import Store

from .helpers import sim_process

PROTOCOL = """\
rigtool_protocol: 1
name: e2e-stm32
command:
  unit: pwm_counts
  values: [0, 300, 415, 460]
depth:
  unit: cm
  values: [30, 35]
  mode: stage
timing:
  settle: {seconds: 1.0}
  acquire: {samples: 200, rate_hz: 1000}
  rest_s: 0.1
  tare: per_depth
  tare_s: 0.2
limits:
  max_thrust_n: 20
"""


@pytest.fixture
def sim_rig(tmp_path):
    """The rig file of a `rigtool sim` process (STM32 bridge, Net F/T, stage), which exits 0
    on SIGTERM after the test."""
    rig = tmp_path / "sim-rig.yaml"
    with sim_process(rig, "stm32-pwm", "--depth", "0.3") as proc:
        yield rig
    assert proc.returncode == 0


@pytest.mark.slow
def test_sweep_against_sim_process(sim_rig, tmp_path, capsys):
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL)
    db = tmp_path / "e2e.sqlite"
    assert main(["sweep", str(protocol), "--rig", str(sim_rig), "--db", str(db)]) == 0, capsys.readouterr()
    store = Store(db)
    run_id = store.resolve_run_id("last")
    steps = store.steps(run_id)
    assert len(steps) == 8 and all(s["n"] == 200 for s in steps)
    by = {(s["depth_m"], s["command"]): s["thrust_all_mean_n"] for s in steps}
    for depth in (0.3, 0.35):
        assert abs(by[(depth, 0)]) < 0.1  # dead zone, after the tare
        assert 4.5 < by[(depth, 300)] < 5.5  # forward saturated, 5 N
        assert 0.5 < by[(depth, 415)] < 4.5  # inverted forward branch
        assert -3.5 < by[(depth, 460)] < -1.0  # reverse after the break-away
    depths = [e["detail"] for e in store.events(run_id, "depth")]
    assert [d["reached_m"] for d in depths] == pytest.approx([0.3, 0.35], abs=0.002)
    assert [d["by"] for d in depths] == ["stage", "stage"]
    assert store.run(run_id)["rig"]["resolved"]["kind"] == "hardware"


CAN_PROTOCOL = """\
rigtool_protocol: 1
name: e2e-can
command:
  unit: percent
  values: [-60, 0, 60]
depth:
  unit: cm
  values: [30]
  mode: stage
timing:
  settle: {seconds: 1.5}
  acquire: {samples: 300, rate_hz: 1000}
  tare: per_depth
  tare_s: 0.2
limits:
  max_thrust_n: 80
  slew_per_s: 400
"""


@pytest.mark.slow
def test_can_sweep_against_sim_process_records_feedback(tmp_path, capsys):
    group = f"239.74.{random.randrange(1, 250)}.{random.randrange(1, 250)}"
    rig = tmp_path / "sim-rig.yaml"
    with sim_process(rig, "can-bldc", "--depth", "0.3", "--can-channel", group) as proc:
        protocol = tmp_path / "p.yaml"
        protocol.write_text(CAN_PROTOCOL)
        db = tmp_path / "can.sqlite"
        assert main(["sweep", str(protocol), "--rig", str(rig), "--db", str(db)]) == 0, capsys.readouterr()
    assert proc.returncode == 0
    store = Store(db)
    steps = store.steps(store.resolve_run_id("last"))
    speed = {s["command"]: s["speed_all_mean_rpm"] for s in steps}
    assert speed[60] == pytest.approx(1080, abs=60) and speed[-60] == pytest.approx(-1080, abs=60)
    assert abs(speed[0]) < 30
    thrust = {s["command"]: s["thrust_all_mean_n"] for s in steps}
    assert 18 < thrust[60] < 27 and -22 < thrust[-60] < -14
    assert all(s["current_all_mean_a"] is not None for s in steps)


def test_sim_fault_switches(tmp_path):
    from rigtool.errors import UsageError
    from rigtool.sim.server import start_sim

    server = start_sim("stm32-pwm", sensor="netft", netft="127.0.0.1:0")
    try:
        server.set_fault("netft.drop=0.25")
        server.set_fault("bridge.garbage=true")
        assert server.parts["netft"].faults.drop == 0.25 and server.parts["bridge"].garbage is True
        for bad in ("netft.nope=1", "warp.drive=1", "netft.drop=lots", "netft"):
            with pytest.raises(UsageError):
                server.set_fault(bad)
    finally:
        server.stop()


def test_sim_rejects_bad_endpoints():
    from rigtool.errors import UsageError
    from rigtool.sim.server import parse_host_port

    with pytest.raises(UsageError, match="out of range"):
        parse_host_port("127.0.0.1:99999")
    with pytest.raises(UsageError, match="HOST:PORT"):
        parse_host_port("localhost")
