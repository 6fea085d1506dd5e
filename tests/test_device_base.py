"""The shared device base (devices/base.py), the registry of driver names (the one list), and
the layer boundaries of devices and config: every driver over its real transport closes twice
harmlessly, closes at the end of a `with` (at neutral when the block raised), and refuses use
after close; the registry names what the rig schema accepts; protocol files are validated
without the simulator."""

from __future__ import annotations

import ast
import contextlib
import subprocess
import sys
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest

import rigtool
from rigtool.devices.ascii_gauge import AsciiGauge
from rigtool.devices.base import Device
from rigtool.devices.dbc_can import DbcCanConfig, DbcCanDriver
from rigtool.devices.depth import ManualDepth, PresetDepth
from rigtool.devices.manual_supply import ManualSupply
from rigtool.devices.netft import NetFTSensor
from rigtool.devices.registry import DRIVERS, driver_class
from rigtool.devices.scpi_supply import ScpiSupply, ScpiSupplyConfig
from rigtool.devices.serial_carriage import SerialCarriage, SerialCarriageConfig
from rigtool.devices.serial_stage import SerialStage, SerialStageConfig
from rigtool.devices.stm32_bridge import Stm32Bridge, Stm32BridgeConfig
from rigtool.devices.vesc_can import VescCanConfig, VescCanDriver
from rigtool.errors import DeviceError
from rigtool.protocol import SimulatorSpec
from rigtool.rig import Rig, open_rig, sim_rig
from rigtool.sim.carriage_twin import CarriageTwin
from rigtool.sim.dbc_twin import DbcServoTwin
from rigtool.sim.gauge_twin import GaugeTwin
from rigtool.sim.live import LiveTwin
from rigtool.sim.netft_twin import NetFTTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.scpi_supply_twin import ScpiSupplyTwin
from rigtool.sim.stage_twin import StageTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.sim.vesc_twin import VescTwin
from rigtool.thruster_profiles import PROFILES

from .helpers import wait_for

PACKAGE = Path(rigtool.__file__).parent


def _live(stack: contextlib.ExitStack, profile: str) -> LiveTwin:
    live = LiveTwin(ThrusterTwin(PROFILES[profile], seed=1)).start()
    stack.callback(live.stop)
    return live


def _started(stack: contextlib.ExitStack, twin):  # noqa: ANN001, ANN202 - any twin
    twin.start()
    stack.callback(twin.stop)
    return twin


# Each opener starts the driver's twin on its real transport and returns (open the driver,
# use it once: a call that must raise DeviceError after close, the live twin).
Opener = Callable[[contextlib.ExitStack], tuple[Callable[[], Device], Callable[[Device], object],
                                                LiveTwin | None]]


def _stm32(stack: contextlib.ExitStack):  # noqa: ANN202
    live = _live(stack, "stm32-pwm")
    fw = _started(stack, Stm32BridgeTwin(live, watchdog_ms=300, seed=7))
    config = Stm32BridgeConfig(driver="stm32-bridge", url=fw.pty_path, watchdog_ms=300)
    return lambda: Stm32Bridge(config), lambda d: d.set_command(400), live


def _vesc(stack: contextlib.ExitStack):  # noqa: ANN202
    live, channel = _live(stack, "can-bldc"), f"base-{uuid.uuid4().hex[:10]}"
    _started(stack, VescTwin(live, channel=channel, controller_id=5, pole_pairs=7))
    config = VescCanConfig(driver="vesc-can", interface="virtual", channel=channel,
                           controller_id=5, pole_pairs=7, timeout_s=0.5)
    return lambda: VescCanDriver(config), lambda d: d.set_command(30.0), live


def _dbc(stack: contextlib.ExitStack):  # noqa: ANN202
    live, channel = _live(stack, "can-bldc"), f"base-{uuid.uuid4().hex[:10]}"
    _started(stack, DbcServoTwin(live, channel=channel, node_id=3, watchdog_s=0.5))
    config = DbcCanConfig(driver="dbc-can", interface="virtual", channel=channel, node_id=3,
                          timeout_s=0.5)
    return lambda: DbcCanDriver(config), lambda d: d.set_command(30.0), live


def _netft(stack: contextlib.ExitStack):  # noqa: ANN202
    box = _started(stack, NetFTTwin(_live(stack, "can-bldc")))
    host, port = box.address
    config = {"driver": "ati-netft", "host": host, "port": port, "http_port": box.http_port}
    return lambda: NetFTSensor(config), lambda d: d.read(5, 100.0), None


def _gauge(stack: contextlib.ExitStack):  # noqa: ANN202
    twin = _started(stack, GaugeTwin(_live(stack, "can-bldc"), "mark10"))
    config = {"driver": "ascii-gauge", "url": twin.port, "preset": "mark10"}
    return lambda: AsciiGauge(config), lambda d: d.read(2, 50.0), None


def _stage(stack: contextlib.ExitStack):  # noqa: ANN202
    twin = _started(stack, StageTwin(_live(stack, "can-bldc"), speed_mm_s=250.0,
                                     position_mm=100.0, zero_offset_m=0.1, seed=3))
    config = SerialStageConfig(driver="serial-stage", url=twin.pty_path, zero_offset_m=0.1,
                               speed_mm_s=250.0, timeout_s=0.5)
    return lambda: SerialStage(config), lambda d: d.position_mm(), None


def _supply(stack: contextlib.ExitStack):  # noqa: ANN202
    twin = stack.enter_context(ScpiSupplyTwin(load_ohm=4.0, source_ohm=0.0, seed=1))
    config = ScpiSupplyConfig(driver="scpi-supply", url=twin.pty_path, timeout_s=0.5,
                              slew_v_per_s=40.0, current_limit_a=5.0, max_voltage_v=24.0)
    return lambda: ScpiSupply(config), lambda d: d.measure(), None


def _carriage(stack: contextlib.ExitStack):  # noqa: ANN202
    twin = stack.enter_context(CarriageTwin(accel_mps2=5.0, seed=2))
    config = SerialCarriageConfig(driver="serial-carriage", url=twin.pty_path, timeout_s=0.5,
                                  accel_mps2=5.0)
    return lambda: SerialCarriage(config), lambda d: d.state(), None


OPENERS: dict[str, Opener] = {"stm32-bridge": _stm32, "vesc-can": _vesc, "dbc-can": _dbc,
                              "ati-netft": _netft, "ascii-gauge": _gauge,
                              "serial-stage": _stage, "scpi-supply": _supply,
                              "serial-carriage": _carriage}


def test_every_registered_driver_is_opened_here():
    assert sorted(OPENERS) == sorted(name for table in DRIVERS.values() for name in table)


@pytest.mark.parametrize("name", sorted(OPENERS))
def test_close_twice_over_the_real_transport_is_harmless(name):
    with contextlib.ExitStack() as stack:
        make, use, _ = OPENERS[name](stack)
        device = make()
        use(device)  # works while open
        device.close()
        device.close()
        with pytest.raises(DeviceError):
            use(device)
        device.close()


@pytest.mark.parametrize("name", sorted(OPENERS))
def test_with_closes_the_driver(name):
    with contextlib.ExitStack() as stack:
        make, use, _ = OPENERS[name](stack)
        with make() as device:
            assert isinstance(device, Device)
            use(device)
        with pytest.raises(DeviceError):
            use(device)
        device.close()


@pytest.mark.parametrize("name", ["stm32-bridge", "vesc-can", "dbc-can"])
def test_with_leaves_the_actuator_at_neutral_when_the_block_raises(name):
    with contextlib.ExitStack() as stack:
        make, use, live = OPENERS[name](stack)
        with pytest.raises(RuntimeError, match="operator abort"), make() as device:
            neutral = device.info.neutral
            use(device)
            assert wait_for(lambda: live.command != neutral)
            raise RuntimeError("operator abort")
        assert wait_for(lambda: live.command == neutral)


def test_simulated_and_manual_devices_close_twice():
    rigset = open_rig(sim_rig(SimulatorSpec(profile="can-bldc")), 0.5, voltage_mode="preset")
    rigset.supply.set_voltage(12.0)
    devices = [rigset.actuator, rigset.sensor, rigset.depth_stage, rigset.supply,
               PresetDepth(), ManualDepth(interactive=False), ManualSupply(interactive=False)]
    for device in devices:
        assert isinstance(device, Device)
        with device:
            pass
        device.close()
    assert rigset.world.twin.supply_voltage_v == 0.0  # the simulated supply closed safe
    rigset.close()


class _Steps(Device):
    """A device whose safe state can fail, recording the hooks `close` runs."""

    def __init__(self, fail: bool) -> None:
        self.fail = fail
        self.steps: list[str] = []

    def _safe_state(self) -> None:
        self.steps.append("safe")
        if self.fail:
            raise DeviceError("neutral not acknowledged")

    def _release(self) -> None:
        self.steps.append("release")


def test_release_runs_once_and_a_failed_safe_state_is_raised_after_it():
    device = _Steps(fail=True)
    with pytest.raises(DeviceError, match="neutral not acknowledged"):
        device.close()
    device.close()
    assert device.steps == ["safe", "release"]
    healthy = _Steps(fail=False)
    with healthy:
        pass
    healthy.close()
    assert healthy.steps == ["safe", "release"]
    assert dict(healthy.stats) == {} and healthy.pop_warnings() == []


def test_registry_names_what_the_rig_schema_accepts_and_each_resolves_to_a_device_class():
    properties = Rig.model_json_schema()["properties"]
    for role, table in DRIVERS.items():
        union = next(s for s in properties[role]["anyOf"] if "discriminator" in s)
        assert sorted(union["discriminator"]["mapping"]) == sorted(table), role
        for name in table:
            cls = driver_class(role, name)
            assert isinstance(cls, type) and issubclass(cls, Device), name
            assert role != "actuator" or callable(cls.info_for), name
    with pytest.raises(KeyError, match="known: serial-stage"):
        driver_class("depth_stage", "stm32-bridge")


def _loaded_after(statement: str) -> str:
    """The rigtool.sim modules loaded in a fresh interpreter after `statement`."""
    code = (f"import sys\n{statement}\n"
            "print(' '.join(sorted(m for m in sys.modules if m.startswith('rigtool.sim'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_importing_the_protocol_or_the_rig_loads_no_simulator_module():
    assert _loaded_after("import rigtool.protocol") == ""
    assert _loaded_after("import rigtool.rig") == ""


def test_devices_import_no_store_engine_or_analysis():
    later = ("rigtool.store", "rigtool.engine", "rigtool.analysis", "rigtool.sweep")
    paths = [*sorted((PACKAGE / "devices").glob("*.py")), PACKAGE / "sim" / "devices.py"]
    bad = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom)
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            bad += [f"{path.name}: {n}" for n in names if n.startswith(later)]
    assert bad == []
