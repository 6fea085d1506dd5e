"""The SCPI supply over VISA (`resource:`, pyvisa): against pyvisa-sim, an independent
simulator driven by tests/visa/scpi-supply.yaml, and against rigtool's own supply twin on
TCP through pyvisa-py (`TCPIP::127.0.0.1::<port>::SOCKET`). The same voltage sweep (the
voltages of protocols/voltage-sweep.yaml) sends both instruments the same lines; the twin's
measured volts and amps come from its load model, pyvisa-sim's are fixed readings, so those
are not compared. One sweep and one check go through the CLI."""

from __future__ import annotations

import ast
import logging
import subprocess
import sys
from pathlib import Path

import pytest

from rigtool.cli import main
from rigtool.devices.scpi_supply import ScpiSupply, ScpiSupplyConfig
from rigtool.errors import ConfigError, DeviceError, UsageError
from rigtool.protocol import load_protocol
from rigtool.rig import load_rig
from rigtool.sim.live import LiveTwin
from rigtool.sim.netft_twin import NetFTTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.scpi_supply_twin import ScpiSupplyTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.store import Store
from rigtool.thruster_profiles import PROFILES

pytest.importorskip("pyvisa_py")
pytest.importorskip("pyvisa_sim")

ROOT = Path(__file__).resolve().parent.parent
SIM_LIBRARY = f"{Path(__file__).parent / 'visa' / 'scpi-supply.yaml'}@sim"
SIM_RESOURCES = ("TCPIP0::192.168.1.20::5025::SOCKET", "USB0::0x2A8D::0x1102::MY123::INSTR")
# the same limits on both instruments: the watchdog off, as pyvisa-sim's supply has none
LIMITS = {"max_voltage_v": 24.0, "slew_v_per_s": 200.0, "timeout_s": 0.3, "watchdog": "off"}


def _socket_resource(twin: ScpiSupplyTwin) -> str:
    return f"TCPIP::127.0.0.1::{twin.url.rsplit(':', 1)[1]}::SOCKET"


def _sweep_voltages() -> list[float]:
    protocol, _ = load_protocol(ROOT / "protocols" / "voltage-sweep.yaml")
    return [float(v) for v in protocol.voltage.values]


def _run_sweep(config: ScpiSupplyConfig) -> list[tuple[float, bool]]:
    """Each voltage of the sweep set and read back, then the supply made safe and closed:
    (setpoint read back, output on) after every point."""
    supply = ScpiSupply(config)
    states = []
    try:
        for volts in _sweep_voltages():
            supply.set_voltage(volts)
            states.append((supply._number("VOLT?"), supply.is_on()))
    finally:
        supply.close()
    assert supply.stats["garbage"] == 0 and supply.stats["errors"] == 0
    return states


def _sim_lines(records: list[logging.LogRecord]) -> list[str]:
    """The lines pyvisa-sim's instrument received, from its debug log."""
    prefix = "Writing into device input buffer: "
    return [ast.literal_eval(r.getMessage()[len(prefix):]).decode().rstrip("\n")
            for r in records if r.getMessage().startswith(prefix)]


def test_a_voltage_sweep_sends_pyvisa_sim_and_the_twin_the_same_lines(caplog):
    volts = _sweep_voltages()
    with ScpiSupplyTwin(setpoint_v=5.0, max_current_a=10.0, state_words=True) as twin:
        twin_states = _run_sweep(ScpiSupplyConfig(driver="scpi-supply",
                                                  resource=_socket_resource(twin), **LIMITS))
    caplog.set_level(logging.DEBUG, logger="pyvisa")
    sim_states = _run_sweep(ScpiSupplyConfig(driver="scpi-supply", resource=SIM_RESOURCES[0],
                                             visa_library=SIM_LIBRARY, **LIMITS))
    sim_lines = _sim_lines(caplog.records)
    assert sim_lines == twin.lines  # every query and setting, in order
    assert twin_states == sim_states == [(v, True) for v in volts]
    settings = [line for line in sim_lines if not line.endswith("?")]
    assert settings[:4] == ["CURR 10.0000", "VOLT 0.0000", "VOLT:PROT 24.0000", "OUTP ON"]
    assert settings[-2:] == ["OUTP OFF", "VOLT:PROT 30.0000"]  # off, protection as found
    assert max(float(s.split()[1]) for s in settings if s.startswith("VOLT ")) == max(volts)
    # what the twin accepted: the output went on once, at 0 V, and is off again
    assert twin.on_states == [(0.0, 10.0)] and not twin.output and twin.ovp_v == 30.0


def test_the_pyserial_url_and_the_visa_resource_send_the_twin_the_same_lines():
    lines = []
    for link in ("url", "resource"):
        with ScpiSupplyTwin(setpoint_v=5.0) as twin:
            where = twin.url if link == "url" else _socket_resource(twin)
            _run_sweep(ScpiSupplyConfig(driver="scpi-supply", **{link: where}, **LIMITS))
            lines.append(twin.lines)
    assert lines[0] == lines[1] and len(lines[0]) > 50


@pytest.mark.parametrize("resource", SIM_RESOURCES)
def test_opening_pyvisa_sim_only_asks(resource, caplog):
    caplog.set_level(logging.DEBUG, logger="pyvisa")
    supply = ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", resource=resource,
                                         visa_library=SIM_LIBRARY, timeout_s=0.3))
    supply.close()
    assert supply.identity == "PYVISA-SIM,SCPI-PSU,0001,1.0"
    assert (supply.found.setpoint_v, supply.found.output_on, supply.found.ovp_v) == (5.0, False,
                                                                                   30.0)
    assert supply.protection.over_voltage and not supply.protection.watchdog
    assert all(line.endswith("?") for line in _sim_lines(caplog.records))


def test_visa_errors_name_the_resource():
    with pytest.raises(DeviceError, match=r"cannot open VISA resource 'TCPIP::127\.0\.0\.9"):
        ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", resource="TCPIP::127.0.0.9::5025::SOCKET",
                                    visa_library=SIM_LIBRARY))  # not in the simulator's list
    with ScpiSupplyTwin() as twin:
        twin.no_replies = True
        resource = _socket_resource(twin)
        with pytest.raises(DeviceError, match=rf"no reply from SCPI supply on {resource} to "
                                              r"'\*IDN\?' within 0\.2 s"):
            ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", resource=resource, timeout_s=0.2))


def test_without_pyvisa_a_resource_is_a_usage_error_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyvisa", None)  # `import pyvisa` raises ImportError
    with pytest.raises(UsageError, match=r"pip install 'rigtool\[visa\]'") as info:
        ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", resource=SIM_RESOURCES[0]))
    assert info.value.exit_status == 2


RIG = "rigtool_rig: 1\nname: r\nactuator: {{driver: stm32-bridge, url: /dev/null}}\n" \
      "sensor: {{driver: ati-netft, host: 127.0.0.1}}\nsupply:\n  driver: scpi-supply\n{supply}"


@pytest.mark.parametrize(("supply", "line", "message"), [
    ("  resource: TCPIP::host::70000::SOCKET\n", 7, "port 70000"),
    ("  resource: 'TCPIP::host 5025'\n", 7, "is not a VISA resource string"),
    ("  url: TCPIP::192.168.1.20::5025::SOCKET\n", 7, "give it as `resource:`"),
    ("  max_voltage_v: 24\n", 5, "either `url:` (pyserial) or `resource:` (VISA)"),
    ("  url: /dev/ttyUSB0\n  resource: ASRL/dev/ttyUSB0::INSTR\n", 5, "exactly one"),
])
def test_rig_file_link_mistakes_name_file_and_line(tmp_path, supply, line, message):
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(supply=supply))
    with pytest.raises(ConfigError) as info:
        load_rig(path)
    assert f"{path}:{line}: supply" in str(info.value) and message in str(info.value)


@pytest.mark.parametrize("library", ["/tmp/libevil.so", "libc.so.6", "./visa.dll",
                                     "x.yaml@py", "@sim\n", "evil.so@sim", "@ni"])
def test_rig_file_visa_library_is_only_a_pyvisa_backend(tmp_path, library):
    """A rig file names no native library: pyvisa would load it with ctypes and run it."""
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(supply=f"  resource: '{SIM_RESOURCES[0]}'\n"
                                      f"  visa_library: {library!r}\n"))
    with pytest.raises(ConfigError) as info:
        load_rig(path)
    assert f"{path}:8: supply" in str(info.value) and "@py, @ivi, @sim" in str(info.value)


def test_a_native_library_with_a_constructor_is_never_loaded(tmp_path, capsys):
    """The attack: a shared object whose constructor writes a file, named by a rig file."""
    cc = pytest.importorskip("shutil").which("cc")
    if cc is None:
        pytest.skip("no C compiler")
    marker, source = tmp_path / "ran", tmp_path / "evil.c"
    source.write_text('#include <stdio.h>\n__attribute__((constructor)) static void f(void)'
                      f'{{ FILE *f = fopen("{marker}", "w"); if (f) fclose(f); }}\n')
    subprocess.run([cc, "-shared", "-fPIC", "-o", tmp_path / "evil.so", source], check=True)
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(supply=f"  resource: '{SIM_RESOURCES[0]}'\n"
                                      f"  visa_library: '{tmp_path / 'evil.so'}'\n"))
    assert main(["check", str(path), "--seconds", "0.1"]) == 2
    assert not marker.exists() and "Traceback" not in capsys.readouterr().err


def test_a_relative_sim_instrument_file_is_taken_relative_to_the_rig_file(tmp_path):
    (tmp_path / "instruments.yaml").write_text(Path(SIM_LIBRARY[:-4]).read_text())
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(supply=f"  resource: '{SIM_RESOURCES[0]}'\n"
                                      "  visa_library: instruments.yaml@sim\n"))
    config = load_rig(path)[0].supply
    assert config.visa_library == f"{tmp_path / 'instruments.yaml'}@sim"
    supply = ScpiSupply(config.model_copy(update=LIMITS))
    assert supply.identity.startswith("PYVISA-SIM")
    supply.close()


def test_a_backend_failing_to_load_is_a_device_error_naming_the_resource(tmp_path):
    broken = tmp_path / "broken.yaml@sim"  # no such instrument file: pyvisa-sim raises
    with pytest.raises(DeviceError, match=rf"cannot open VISA resource '{SIM_RESOURCES[0]}'"):
        ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", resource=SIM_RESOURCES[0],
                                    visa_library=str(broken), **LIMITS))


@pytest.mark.parametrize("resource", ["TCPIP::host::\u096b\u0966\u0968\u096b::SOCKET",
                                      "TCPIP::host::\u0665::SOCKET", "GPIB0::\u0665::INSTR",
                                      "ASRL\u0663::INSTR"])
def test_resource_digits_are_ascii_only(tmp_path, resource):
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(supply=f"  resource: '{resource}'\n"))
    with pytest.raises(ConfigError, match="is not a VISA resource string"):
        load_rig(path)


@pytest.mark.parametrize("resource", ["TCPIP::192.168.1.20::5025::SOCKET", "TCPIP::psu-3::INSTR",
                                      "TCPIP0::10.0.0.7::hislip0::INSTR",
                                      "USB0::0x2A8D::0x1102::MY123::INSTR",
                                      "ASRL/dev/ttyUSB0::INSTR", "ASRL3::INSTR", "GPIB0::5::INSTR"])
def test_rig_file_accepts_visa_resource_strings(tmp_path, resource):
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(supply=f"  resource: '{resource}'\n"))
    assert load_rig(path)[0].supply.resource == resource


def test_loading_a_visa_rig_imports_no_pyvisa(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(RIG.format(supply=f"  resource: {SIM_RESOURCES[1]}\n"))
    code = ("import sys, rigtool.rig, rigtool.cli, rigtool.sweep\n"
            f"rigtool.rig.load_rig({str(path)!r})\n"
            "print(sorted(m for m in ('pyvisa', 'pyvisa_py', 'pyvisa_sim') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


PROTOCOL = """\
rigtool_protocol: 1
name: visa-sweep
command: {unit: pwm_counts, values: [0, 300]}
depth: {unit: cm, values: [30]}
voltage: {unit: V, values: [12, 16], order: up, settle_s: 0.2}
timing:
  settle: {seconds: 0.3}
  acquire: {samples: 200, rate_hz: 1000}
  tare: at_start
  tare_s: 0.2
limits: {max_thrust_n: 20, max_current_a: 5}
"""


@pytest.fixture
def bench(tmp_path):
    """A rig file of the STM32 bridge twin and the Net F/T twin with the given supply section."""
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=5)).start()
    fw = Stm32BridgeTwin(live).start()
    box = NetFTTwin(live).start()

    def _make(supply: str) -> Path:
        host, port = box.address
        rig = tmp_path / "rig.yaml"
        rig.write_text(
            "rigtool_rig: 1\nname: visa-bench\nthrust: {channel: fz, sign: -1}\n"
            f"actuator: {{driver: stm32-bridge, url: '{fw.url}', timeout_s: 0.5}}\n"
            f"sensor: {{driver: ati-netft, host: {host}, port: {port}, "
            f"http_port: {box.http_port}}}\n"
            f"supply: {{driver: scpi-supply, {supply}, timeout_s: 0.5, slew_v_per_s: 200, "
            "max_voltage_v: 24}\n")
        return rig

    yield _make
    for part in (box, fw, live):
        part.stop()


@pytest.mark.slow
def test_cli_sweep_through_pyvisa_py_against_the_twin(bench, tmp_path):
    with ScpiSupplyTwin(load_ohm=4.0, source_ohm=0.0, setpoint_v=5.0) as twin:
        rig = bench(f"resource: '{_socket_resource(twin)}'")
        protocol = tmp_path / "p.yaml"
        protocol.write_text(PROTOCOL)
        db = tmp_path / "db.sqlite"
        assert main(["sweep", str(protocol), "--rig", str(rig), "--db", str(db)]) == 0
        assert twin.on_states == [(0.0, 5.0)] and not twin.output and not twin.watchdog
        assert max(v for what, v in twin.history if what == "VOLT") == 16.0
    store = Store(db)
    run_id = store.resolve_run_id("last")
    assert {s["voltage_set_v"] for s in store.steps(run_id)} == {12.0, 16.0}
    measured = [e["detail"]["measured_v"] for e in store.events(run_id, "voltage")]
    assert measured == pytest.approx([12.0, 16.0], abs=0.05)


@pytest.mark.slow
def test_cli_check_through_pyvisa_sim(bench, capsys):
    rig = bench(f"resource: '{SIM_RESOURCES[1]}', visa_library: '{SIM_LIBRARY}'")
    assert main(["check", str(rig), "--seconds", "0.3"]) == 0
    out = capsys.readouterr().out
    assert f"PYVISA-SIM,SCPI-PSU,0001,1.0 on {SIM_RESOURCES[1]}" in out
    assert "over-voltage protection: yes" in out and "output watchdog: NO" in out
