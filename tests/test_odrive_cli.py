"""An ODrive sweep through the real CLI: sweep -> calibrate -> report on the ODrive twin.

The shipped rig file protocols/rigs/odrive-example.yaml is used as it is, with only its
bus redirected to a python-can virtual channel and its Net F/T box to the Net F/T twin;
the dbc-can driver reads ODrive's own DBC. At the end the thruster is at zero velocity
and the axis IDLE, as the twin and the frames recorded on the bus both show.
"""

from __future__ import annotations

import uuid

import cantools
import pytest
import yaml

from rigtool.cli import main
from rigtool.sim.netft_twin import NetFTTwin
from rigtool.sim.odrive_twin import IDLE, ODRIVE_DBC, OdriveTwin
from rigtool.store import Store

from .conftest import ROOT
from .helpers import drain, wait_for

RIG = ROOT / "protocols/rigs/odrive-example.yaml"
NODE = 5
PROTOCOL = """\
rigtool_protocol: 1
name: odrive-velocity
metadata: {thruster_id: odrive-bldc, propeller_diameter_m: 0.2, water_density_kg_m3: 1000}
command: {unit: rpm, values: [-1500, -1000, -500, 0, 500, 1000, 1500]}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 1.0}
  acquire: {samples: 400, rate_hz: 1000}
  rest_s: 0.0
  tare: at_start
  tare_s: 0.2
limits: {max_thrust_n: 90, max_speed_rpm: 2000, slew_per_s: 3000}
"""


@pytest.fixture
def channel() -> str:
    return f"odrive-cli-{uuid.uuid4().hex[:10]}"


@pytest.fixture
def odrive(live, channel):
    twin = OdriveTwin(live, channel=channel, node_id=NODE).start()
    yield twin
    twin.stop()


@pytest.fixture
def box(live):
    twin = NetFTTwin(live).start()
    yield twin
    twin.stop()


@pytest.fixture
def rig(tmp_path, channel, box):
    """The shipped example rig, reaching the twins instead of can0 and 192.168.1.1."""
    data = yaml.safe_load(RIG.read_text())
    data["actuator"].update(interface="virtual", channel=channel, bitrate=None, node_id=NODE)
    host, port = box.address
    data["sensor"].update(host=host, port=port, http_port=box.http_port)
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.mark.slow
def test_odrive_sweep_calibrate_report(odrive, live, rig, recorder, tmp_path, capsys):
    protocol = tmp_path / "odrive.yaml"
    protocol.write_text(PROTOCOL)
    common = ["--db", str(tmp_path / "runs.sqlite")]
    assert main(["sweep", str(protocol), "--rig", str(rig), *common]) == 0, capsys.readouterr().err
    sent = [m for m in drain(recorder) if m.arbitration_id >> 5 == NODE]
    assert main(["calibrate", "last", *common, "--out", str(tmp_path / "out")]) == 0
    assert main(["report", "last", *common, "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "report.html" in out

    store = Store(tmp_path / "runs.sqlite")
    steps = store.steps(store.resolve_run_id("last"))
    assert len(steps) == 7 and all(s["n"] == 400 for s in steps)
    thrust = {s["command"]: s["thrust_all_mean_n"] for s in steps}
    assert thrust[1500] > thrust[1000] > thrust[500] > 1.0 > abs(thrust[0])
    assert thrust[-1500] < thrust[-1000] < thrust[-500] < -1.0

    # the axis was commanded in turns/s and left idle at zero velocity
    assert wait_for(lambda: odrive.axis_state == IDLE and live.command == 0.0, 1.0)
    assert odrive.input_vel_turns_s == 0.0
    turns_s = {round(v, 3) for v in odrive.input_vels}  # float32 on the wire
    assert turns_s >= {-25.0, -16.667, -8.333, 0.0, 8.333, 16.667, 25.0}
    vendor = cantools.database.load_file(str(ODRIVE_DBC))
    ours = [vendor.decode_message(m.arbitration_id, bytes(m.data), decode_choices=False)
            for m in sent if m.arbitration_id in (NODE << 5 | 7, NODE << 5 | 13)]  # fmt: skip
    assert ours[-2] == {"Input_Vel": 0.0, "Input_Torque_FF": 0.0}
    assert ours[-1] == {"Axis_Requested_State": IDLE}
