"""`rigtool sim` is reachable from this host only, and two simulators never hear each other."""

from __future__ import annotations

import socket
import struct
import time

import can
import numpy as np
import pytest
import yaml
from can.interfaces.udp_multicast.utils import pack_message

from rigtool.cli import main
from rigtool.devices.canbus import open_bus

from .helpers import drain, sim_process

SET_DUTY, STATUS_1 = 0, 9


def _socket_address(fd: int) -> tuple:
    sock = socket.fromfd(fd, socket.AF_INET, socket.SOCK_DGRAM)
    try:
        return sock.getsockname()
    finally:
        sock.close()


@pytest.mark.slow
def test_check_aimed_at_one_sim_never_reaches_another(tmp_path, capsys) -> None:
    rig1, rig2 = tmp_path / "first.yaml", tmp_path / "second.yaml"
    with sim_process(rig1, "can-bldc"), sim_process(rig2, "can-bldc"):
        act1 = yaml.safe_load(rig1.read_text())["actuator"]
        act2 = yaml.safe_load(rig2.read_text())["actuator"]
        assert act1["channel"] != act2["channel"]
        listener = open_bus(act2["interface"], act2["channel"])
        try:
            drain(listener)
            assert main(["check", str(rig1), "--seconds", "1.5", "--rate", "200",
                         "--command", "40"]) == 0, capsys.readouterr()
            frames = drain(listener, 0.3)
        finally:
            listener.shutdown()
        packets = {m.arbitration_id >> 8 for m in frames if m.is_extended_id}
        assert STATUS_1 in packets  # the listener does hear the second simulator ...
        assert SET_DUTY not in packets  # ... but never a command meant for the first
        erpm = [struct.unpack_from(">i", bytes(m.data))[0] for m in frames
                if m.arbitration_id >> 8 == STATUS_1 and len(m.data) >= 4]
        # the second motor never turned: idle noise only (40 % would be about 5000 ERPM)
        assert erpm and max(abs(e) for e in erpm) < 1000


def test_can_sim_ignores_datagrams_not_sent_to_its_group_on_loopback() -> None:
    from rigtool.sim.server import start_sim

    server = start_sim("can-bldc", netft="127.0.0.1:0")
    try:
        vesc = server.parts["vesc"]
        host, port = _socket_address(vesc._bus.fileno())
        assert host != "0.0.0.0"  # bound to its own multicast group, not every interface
        frame = pack_message(can.Message(arbitration_id=(SET_DUTY << 8) | vesc.controller_id,
                                         data=struct.pack(">i", 50_000), is_extended_id=True))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for target in ("127.0.0.1", socket.gethostbyname(socket.gethostname())):
                sender.sendto(frame, (target, port))
        time.sleep(0.3)
        assert vesc.commands == []
    finally:
        server.stop()


@pytest.mark.parametrize("profile", ["stm32-pwm", "can-bldc"])
def test_every_sim_socket_is_bound_to_loopback_by_default(profile: str) -> None:
    from rigtool.sim.server import start_sim

    server = start_sim(profile, netft="127.0.0.1:0")
    try:
        rig = yaml.safe_load(server.rig_yaml())
        ft = server.parts["netft"]
        assert ft.address[0] == "127.0.0.1" and ft._http.server_address[0] == "127.0.0.1"
        if profile == "stm32-pwm":
            assert server.parts["bridge"].address[0] == "127.0.0.1"
            assert rig["actuator"]["url"].startswith("socket://127.0.0.1:")
        else:
            group = _socket_address(server.parts["vesc"]._bus.fileno())[0]
            assert group.startswith("239.") and rig["actuator"]["channel"].startswith(group + ":")
    finally:
        server.stop()


def test_bind_opts_in_to_other_addresses(capsys) -> None:
    from rigtool.sim.server import start_sim

    server = start_sim("stm32-pwm", bind="0.0.0.0", netft="0")
    try:
        assert server.parts["bridge"].address[0] == "0.0.0.0"
        assert server.parts["netft"].address[0] == "0.0.0.0"
    finally:
        server.stop()
    server = start_sim("can-bldc", bind="0.0.0.0", netft="0")
    try:
        assert yaml.safe_load(server.rig_yaml())["actuator"]["interface"] == "udp_multicast"
    finally:
        server.stop()


def test_bad_can_channel_and_bind_are_usage_errors(capsys) -> None:
    assert main(["sim", "--profile", "can-bldc", "--can-channel", "10.0.0.1:5"]) == 2
    assert "239." in capsys.readouterr().err
    assert main(["sim", "--profile", "stm32-pwm", "--bind", "no.such.host.invalid"]) == 2


def test_sim_rate_sets_the_net_ft_rdt_rate(capsys) -> None:
    """`--rate` runs the twin and the Net F/T's RDT stream at that rate; the box's XML says so
    (the driver reads it), and a rate out of range is a usage error."""
    from rigtool.devices.netft import NetFTConfig, NetFTSensor
    from rigtool.sim.server import start_sim

    server = start_sim("stm32-pwm", netft="127.0.0.1:0", rate_hz=7000.0)
    try:
        host, port = server.parts["netft"].address
        sensor = NetFTSensor(NetFTConfig(driver="ati-netft", host=host, port=port,
                                         http_port=server.parts["netft"].http_port))
        try:
            block = sensor.read(1400, 7000.0)
        finally:
            sensor.close()
        assert sensor.calibration.rate_hz == 7000.0
        assert len(block) == 1400 and np.all(np.diff(block.seq) >= 1)
    finally:
        server.stop()
    assert main(["sim", "--profile", "stm32-pwm", "--rate", "0"]) == 2
    assert "1 to 10000" in capsys.readouterr().err
