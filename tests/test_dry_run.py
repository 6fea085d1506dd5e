"""`rigtool sweep --dry-run` reads files and prints the plan: it opens, commands and changes no
device. Every shipped rig file is pointed at local endpoints this test serves (TCP listeners,
a UDP socket, a python-can virtual bus, pseudo-terminals), and the dry run must reach none."""

from __future__ import annotations

import os
import socket
import uuid

import can
import pytest
import yaml

from rigtool.cli import main
from rigtool.sim.line_server import open_pty

from .conftest import ROOT

RIGS = sorted((ROOT / "protocols/rigs").glob("*.yaml"))
PROTOCOL = """\
rigtool_protocol: 1
name: dry
command: {{unit: {unit}, values: {values}}}
depth: {{unit: m, values: [1.0]}}
voltage: {{unit: V, values: [12, 16]}}
timing: {{settle: {{seconds: 0.5}}, acquire: {{samples: 100, rate_hz: 500}}}}
"""
VALUES = {"percent": [0, 50], "rpm": [0, 900], "pwm_counts": [0, 300], "pulse_us": [1500, 1700],
          "current_a": [0, 5]}


class Endpoints:
    """Local stand-ins for every address a rig file may name; `touched()` counts contacts."""

    def __init__(self) -> None:
        self.tcp = socket.create_server(("127.0.0.1", 0))
        self.tcp.setblocking(False)
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.bind(("127.0.0.1", 0))
        self.udp.setblocking(False)
        self.ptys = [open_pty() for _ in range(3)]
        self.channel = f"dry-{uuid.uuid4().hex[:8]}"
        self.bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)

    def url(self) -> str:
        return f"socket://127.0.0.1:{self.tcp.getsockname()[1]}"

    def touched(self) -> list[str]:
        seen = []
        try:
            self.tcp.accept()
            seen.append("tcp connection")
        except BlockingIOError:
            pass
        try:
            self.udp.recv(2048)
            seen.append("udp datagram")
        except BlockingIOError:
            pass
        for master, _, path in self.ptys:
            try:
                if os.read(master, 4096):
                    seen.append(f"bytes on {path}")
            except (BlockingIOError, OSError):
                pass
        if self.bus.recv(timeout=0.05) is not None:
            seen.append("CAN frame")
        return seen

    def close(self) -> None:
        self.bus.shutdown()
        for sock in (self.tcp, self.udp):
            sock.close()
        for master, slave, _ in self.ptys:
            os.close(master)
            os.close(slave)


def _redirect(section: dict, ends: Endpoints, pty: int) -> dict:
    """The device section with every address replaced by a local endpoint."""
    out = dict(section)
    if "url" in out:
        out["url"] = ends.url() if pty == 0 else ends.ptys[pty][2]
    if "host" in out:
        out["host"], out["port"] = "127.0.0.1", ends.udp.getsockname()[1]
        out["http_port"] = ends.tcp.getsockname()[1]
    if "interface" in out:
        out.update(interface="virtual", channel=ends.channel, bitrate=None)
    return out


@pytest.mark.parametrize("rig_file", RIGS, ids=lambda p: p.stem)
def test_dry_run_on_every_shipped_rig_opens_nothing(rig_file, tmp_path, capsys):
    rig = yaml.safe_load(rig_file.read_text())
    ends = Endpoints()
    try:
        for i, role in enumerate(("actuator", "sensor", "depth_stage")):
            if rig.get(role):
                rig[role] = _redirect(rig[role], ends, i)
        rig["supply"] = {"driver": "scpi-supply", "url": ends.ptys[2][2], "max_voltage_v": 24}
        if rig.get("simulator"):
            rig.pop("supply")
        (tmp_path / "rig.yaml").write_text(yaml.safe_dump(rig))
        unit = _actuator_unit(rig)
        (tmp_path / "p.yaml").write_text(PROTOCOL.format(unit=unit, values=VALUES[unit]))
        code = main(["sweep", str(tmp_path / "p.yaml"), "--rig", str(tmp_path / "rig.yaml"),
                     "--db", str(tmp_path / "db.sqlite"), "--dry-run"])
        captured = capsys.readouterr()
        assert code == 0, captured.err
        assert "4 points" in captured.out and "12 V, 16 V" in captured.out
        assert ends.touched() == []
        assert not (tmp_path / "db.sqlite").exists()
    finally:
        ends.close()


def _actuator_unit(rig: dict) -> str:
    if rig.get("simulator"):
        from rigtool.thruster_profiles import PROFILES

        return PROFILES[rig["simulator"]["profile"]].command_unit
    act = rig["actuator"]
    command = act.get("command") or {}  # dbc-can: the unit is in its command section
    return act.get("command_unit") or act.get("unit") or command.get("unit") or "percent"

