"""CAN rig sections honour python-can's own configuration (its config files under $HOME, the
CAN_* environment variables, named sections via `context:`) for what they leave out, and pass
`bus_args:` to python-can's Bus; all over python-can `virtual` buses with the real drivers."""

from __future__ import annotations

import os
import pwd
import subprocess
import sys
import uuid
from pathlib import Path

import can
import pytest

from rigtool.cli import main
from rigtool.devices.canbus import CanLink, bus_settings
from rigtool.devices.vesc_can import VescCanConfig, VescCanDriver
from rigtool.errors import ConfigError, UsageError
from rigtool.files import MAX_CONFIG_BYTES
from rigtool.rig import load_rig
from rigtool.sim.vesc_twin import VescTwin

from .helpers import wait_for

CTRL = 5


@pytest.fixture(autouse=True)
def can_home(tmp_path, monkeypatch):
    """A HOME of the test's own (python-can reads ~/can.conf, ~/.can, ~/.canrc) and no CAN_*
    variable from the machine; returns a function writing ~/can.conf."""
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    for name in [n for n in os.environ if n.startswith("CAN_")]:
        monkeypatch.delenv(name)
    monkeypatch.setattr(can, "rc", {})

    def _write(text: str, name: str = "can.conf") -> None:
        (home / name).write_text(text)

    return _write


@pytest.fixture
def channel() -> str:
    return f"cfg-{uuid.uuid4().hex[:10]}"


def _vesc(**fields) -> VescCanConfig:
    return VescCanConfig(driver="vesc-can", controller_id=CTRL, **fields)


def test_a_section_without_interface_or_channel_takes_them_from_can_conf(can_home, channel,
                                                                         live):
    can_home(f"[default]\ninterface = virtual\nchannel = {channel}\nbitrate = 250000\n")
    settings = bus_settings(_vesc())
    assert (settings.interface, settings.channel, settings.kwargs) == ("virtual", channel,
                                                                       {"bitrate": 250000})
    twin = VescTwin(live, channel=channel, controller_id=CTRL).start()
    try:
        driver = VescCanDriver(_vesc(timeout_s=0.5))  # opens the bus can.conf names
        try:
            assert driver._link.where == f"virtual:{channel}"
            assert wait_for(lambda: driver.stats["frames"] > 0, 2.0)
        finally:
            driver.close()
    finally:
        twin.stop()


def test_the_rig_file_wins_then_environment_then_file(can_home, monkeypatch):
    can_home("[default]\ninterface = pcan\nchannel = filebus\nbitrate = 125000\n", ".canrc")
    monkeypatch.setenv("CAN_CHANNEL", "envbus")
    settings = bus_settings(_vesc(interface="virtual"))
    assert (settings.interface, settings.channel) == ("virtual", "envbus")
    assert settings.kwargs == {"bitrate": 125000}  # left out of the rig: from ~/.canrc
    settings = bus_settings(_vesc(interface="virtual", bitrate=1000000))
    assert settings.kwargs == {"bitrate": 1000000}
    monkeypatch.setenv("CAN_BITRATE", "250000")
    assert bus_settings(_vesc(interface="virtual")).kwargs == {"bitrate": 250000}
    assert "bitrate" not in bus_settings(_vesc(interface="virtual", bitrate=None)).kwargs


def test_a_named_context_reads_its_section_and_suffixed_variables(can_home, monkeypatch):
    can_home("[default]\ninterface = virtual\nchannel = default-bus\n"
             "[bench2]\nchannel = bench2-bus\nreceive_own_messages = True\n")
    settings = bus_settings(_vesc(context="bench2"))
    assert (settings.interface, settings.channel) == ("virtual", "bench2-bus")
    assert settings.kwargs == {"bitrate": 500000, "receive_own_messages": True}
    monkeypatch.setenv("CAN_CHANNEL", "plain-env")
    monkeypatch.setenv("CAN_CHANNEL_bench2", "bench2-env")
    assert bus_settings(_vesc(context="bench2")).channel == "bench2-env"
    assert bus_settings(_vesc()).channel == "plain-env"


def test_a_section_naming_interface_and_channel_reads_no_python_can_config(can_home,
                                                                           monkeypatch):
    can_home("[default]\ninterface = pcan\nchannel = filebus\nfd = True\nbitrate = 1\n")
    monkeypatch.setenv("CAN_BITRATE", "125000")
    settings = bus_settings(_vesc(interface="virtual", channel="mine"))
    assert (settings.interface, settings.channel, settings.kwargs, settings.from_config) == (
        "virtual", "mine", {"bitrate": 500000}, False)


def test_with_no_configuration_the_interface_is_socketcan(can_home):
    assert bus_settings(_vesc(channel="can7")).interface == "socketcan"


def test_no_channel_anywhere_is_a_usage_error_through_the_cli(can_home, tmp_path, capsys):
    rig = tmp_path / "rig.yaml"
    rig.write_text("rigtool_rig: 1\nname: r\nactuator: {driver: vesc-can, interface: virtual, "
                   "context: lab}\nsensor: {driver: ati-netft, host: 127.0.0.1}\n")
    assert main(["check", str(rig)]) == 2
    err = capsys.readouterr().err
    assert "no CAN channel" in err and "CAN_CHANNEL_lab" in err and "Traceback" not in err


def test_a_configuration_python_can_refuses_is_a_usage_error(can_home):
    can_home("[default]\ninterface = no-such-can\nchannel = x\n")
    with pytest.raises(UsageError, match="python-can configuration.*no-such-can"):
        bus_settings(_vesc())


@pytest.mark.parametrize("text", ["interface = virtual\n", "[default]\ninterface\n  = x\n [\n",
                                  "[default]\nport = eighty\n"])
def test_a_damaged_can_conf_is_a_usage_error(can_home, text):
    can_home(text)
    with pytest.raises(UsageError, match="python-can configuration refused"):
        bus_settings(_vesc(channel="x"))


@pytest.mark.parametrize("value", ["[1]", '"s"', "3", "{not json"])
def test_a_can_config_variable_that_is_no_json_object_exits_2_naming_it(can_home, tmp_path,
                                                                        monkeypatch, capsys,
                                                                        value):
    monkeypatch.setenv("CAN_CONFIG", value)
    rig = tmp_path / "rig.yaml"
    rig.write_text("rigtool_rig: 1\nname: r\nactuator: {driver: vesc-can, interface: virtual}\n"
                   "sensor: {driver: ati-netft, host: 127.0.0.1}\n")
    assert main(["check", str(rig)]) == 2
    err = capsys.readouterr().err
    assert "environment variable CAN_CONFIG" in err and "Traceback" not in err


@pytest.mark.parametrize(("words", "expected"), [("no", False), ("off", False), ("0", False),
                                                 ("False", False), ("yes", True), ("on", True)])
def test_configured_flags_are_read_as_the_rig_file_reads_them(can_home, channel, words,
                                                              expected):
    can_home(f"[default]\ninterface = virtual\nchannel = {channel}\nfd = {words}\n"
             f"receive_own_messages = {words}\ndata_bitrate = 2000000\n")
    assert bus_settings(_vesc()).kwargs == {"bitrate": 500000, "fd": expected,
                                            "receive_own_messages": expected,
                                            "data_bitrate": 2000000}


@pytest.mark.parametrize("value", ["250k", "fast", "-3", "0", "1e6"])
def test_a_configured_bitrate_is_checked_naming_its_source(can_home, monkeypatch, value):
    monkeypatch.setenv("CAN_BITRATE_lab", value)
    with pytest.raises(UsageError, match=f"environment variable CAN_BITRATE_lab gives "
                                         f"bitrate = '{value}'"):
        bus_settings(_vesc(interface="virtual", channel="x", context="lab"))
    monkeypatch.delenv("CAN_BITRATE_lab")
    can_home(f"[lab]\nbitrate = {value}\n")
    with pytest.raises(UsageError, match=r"section \[lab\] of python-can's config files .*"
                                         f"bitrate = '{value}'"):
        bus_settings(_vesc(interface="virtual", channel="x", context="lab"))


@pytest.mark.parametrize(("config", "key"), [('{"fd": "maybe"}', "fd"),
                                             ('{"data_bitrate": -1}', "data_bitrate"),
                                             ('{"can_filters": [{"can_id": 1}]}', "can_filters"),
                                             ('{"poll_interval": [1]}', "poll_interval"),
                                             ('{"interface": 7}', "interface")])
def test_can_config_values_are_typed_as_bus_args(can_home, monkeypatch, config, key):
    monkeypatch.setenv("CAN_CONFIG", config)
    with pytest.raises(UsageError, match=f"environment variable CAN_CONFIG gives {key} ="):
        bus_settings(_vesc(channel="x"))


def _link(config: VescCanConfig) -> tuple[CanLink, list[int]]:
    seen: list[int] = []

    def _on_frame(msg: can.Message, t: float) -> str:
        seen.append(msg.arbitration_id)
        return "frames"

    link = CanLink(bus_settings(config), _on_frame, "test")
    link.start(0, can.Message(arbitration_id=0x7FF, is_extended_id=False))
    return link, seen


def test_can_filters_from_the_rig_file_filter_frames_on_the_bus(tmp_path, channel):
    rig = tmp_path / "rig.yaml"
    rig.write_text(
        "rigtool_rig: 1\nname: r\nsensor: {driver: ati-netft, host: 127.0.0.1}\n"
        f"actuator:\n  driver: vesc-can\n  interface: virtual\n  channel: {channel}\n"
        "  bus_args:\n    can_filters:\n"
        "      - {can_id: 0x100, can_mask: 0x7F0, extended: false}\n")
    link, seen = _link(load_rig(rig)[0].actuator)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        for frame_id, extended in ((0x105, False), (0x200, False), (0x101, True),
                                   (0x10A, False)):  # 0x10A last: all have been received
            sender.send(can.Message(arbitration_id=frame_id, is_extended_id=extended))
        assert wait_for(lambda: len(seen) >= 2, 1.0)
        link.stop_threads()
        assert seen == [0x105, 0x10A]
    finally:
        sender.shutdown()
        link.close()


@pytest.mark.parametrize("own", [True, False])
def test_receive_own_messages_reaches_the_bus(channel, own):
    link, seen = _link(_vesc(interface="virtual", channel=channel,
                             bus_args={"receive_own_messages": own}))
    try:
        link.send(can.Message(arbitration_id=0x123, is_extended_id=False))
        assert wait_for(lambda: seen == [0x123], 0.5) is own
    finally:
        link.close()


RIG = "rigtool_rig: 1\nname: r\nsensor: {{driver: ati-netft, host: 127.0.0.1}}\n" \
      "actuator:\n  driver: dbc-can\n  channel: can0\n{extra}"


@pytest.mark.parametrize(("extra", "line", "field", "message"), [
    ("  bus_args: {fd: 'yes please'}\n", 7, "actuator.bus_args.fd", "valid boolean"),
    ("  bus_args:\n    data_bitrate: -5\n", 8, "actuator.bus_args.data_bitrate",
     "greater than 0"),
    ("  bus_args:\n    can_filters: [{can_id: 0x100}]\n", 8,
     "actuator.bus_args.can_filters.0.can_mask", "missing"),
    ("  bus_args:\n    bitrate: 250000\n", 8, "actuator.bus_args.bitrate",
     "a field of the section itself"),
    ("  bus_args:\n    poll_interval: [1, 2]\n", 8, "actuator.bus_args.poll_interval",
     "valid"),
    ("  context: 'lab bench'\n", 7, "actuator.context", "pattern"),
    ("  bus_args:\n    can_filters: [{can_id: 0x800, can_mask: 0x7FF, extended: false}]\n", 8,
     "actuator.bus_args.can_filters.0.can_id", "11 bits"),
    ("  bus_args:\n    can_filters: [{can_id: 0x100, can_mask: 0xFFF, extended: false}]\n",
     8, "actuator.bus_args.can_filters.0.can_mask", "11 bits"),
])
def test_rig_file_bus_mistakes_name_file_line_and_field(tmp_path, extra, line, field, message):
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(extra=extra))
    with pytest.raises(ConfigError) as info:
        load_rig(path)
    problems = str(info.value)
    assert f"{path}:{line}: {field}" in problems and message in problems


def test_rig_file_bus_args_reach_the_settings(tmp_path, can_home):
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(extra="  interface: virtual\n  bus_args: {fd: true, "
                                     "data_bitrate: 2000000, poll_interval: 0.01}\n"))
    settings = bus_settings(load_rig(path)[0].actuator)
    assert settings.kwargs == {"bitrate": 500000, "fd": True, "data_bitrate": 2000000,
                               "poll_interval": 0.01}


def test_an_unknown_interface_in_the_rig_file_exits_2_at_check_with_file_and_line(tmp_path,
                                                                                   capsys):
    """Issue 49: it exited 1 when the bus was opened, though the same name in ~/.canrc
    exited 2; python-can's interface names (and rigtool's udp_loopback) are checked now."""
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(extra="  interface: no-such-can\n"))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:7: actuator.interface" in err and "unknown CAN interface" in err, err
    assert "Traceback" not in err


CANRC_TARGETS = {"/dev/zero": ("not a regular file",), "dir": ("not a regular file",),
                 # regular and of size 0 to stat, yet it reads on without end (attack report):
                 # refused at the cap, or where the kernel refuses a read of an odd size
                 "/proc/self/pagemap": ("file too large", "cannot read")}


@pytest.mark.parametrize("target", sorted(CANRC_TARGETS))
def test_a_canrc_that_is_no_regular_file_exits_2_naming_it(can_home, tmp_path, target):
    """Issue 49: a ~/.canrc linked to /dev/zero hung python-can's config reader; the config
    files are checked as rigtool's own (regular file, bounded size) before it reads them."""
    home = tmp_path / "home"
    canrc = home / ".canrc"
    if target == "dir":
        canrc.mkdir()
    else:
        canrc.symlink_to(target)
    rig = tmp_path / "rig.yaml"
    rig.write_text("rigtool_rig: 1\nname: r\nactuator: {driver: vesc-can, interface: virtual}\n"
                   "sensor: {driver: ati-netft, host: 127.0.0.1}\n")
    env = {**os.environ, "HOME": str(home), "MPLCONFIGDIR": str(_real_home() / ".cache" / "matplotlib")}
    proc = subprocess.run([sys.executable, "-m", "rigtool.cli", "check", str(rig)], env=env,
                          capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert proc.returncode == 2, proc.stderr
    assert any(f"{canrc}: {why}" in proc.stderr for why in CANRC_TARGETS[target]), proc.stderr
    assert "Traceback" not in proc.stderr


def _real_home() -> Path:
    """The account's home (HOME is the test's): its matplotlib cache spares the `rigtool`
    process a font scan."""
    return Path(pwd.getpwuid(os.getuid()).pw_dir)


def test_a_canrc_too_large_is_refused(can_home, tmp_path):
    (tmp_path / "home" / ".canrc").write_bytes(b"#" * (MAX_CONFIG_BYTES + 1))
    with pytest.raises(ConfigError, match="file too large"):
        bus_settings(_vesc())
