"""The SCPI supply driver against its twin over a pty and over TCP: settings confirmed,
ramps at the slew limit, garbage counted and skipped, a silent supply a clear error, and the
output left safe on close."""

from __future__ import annotations

import time

import pytest

from rigtool.devices.scpi_supply import ScpiSupply, ScpiSupplyConfig
from rigtool.errors import DeviceError, UsageError
from rigtool.sim.scpi_supply_twin import ScpiSupplyTwin


@pytest.fixture(params=["pty", "tcp"])
def twin(request):
    with ScpiSupplyTwin(load_ohm=4.0, source_ohm=0.0, seed=1) as t:
        t.where = t.pty_path if request.param == "pty" else t.url
        yield t


def _open(twin, **kw) -> ScpiSupply:
    cfg = dict(driver="scpi-supply", url=twin.where, timeout_s=0.5, slew_v_per_s=40.0,
               current_limit_a=5.0, max_voltage_v=24.0)
    return ScpiSupply(ScpiSupplyConfig(**(cfg | kw)))


def test_identity_limit_voltage_and_measurement(twin):
    supply = _open(twin)
    assert supply.identity.startswith("RIGTOOL,SIM-PSU")
    assert twin.current_limit == 5.0 and not twin.output
    volts = supply.set_voltage(12.0)
    assert twin.output and twin.voltage_set == pytest.approx(12.0)
    assert volts == pytest.approx(12.0) and supply.measure()[1] == pytest.approx(3.0)
    supply.close()
    assert not twin.output  # on_exit: off
    supply.close()  # idempotent


def test_ramp_respects_the_slew_limit(twin):
    supply = _open(twin, slew_v_per_s=40.0)
    t0 = time.monotonic()
    supply.set_voltage(20.0)  # 0 -> 20 V at 40 V/s: half a second
    assert time.monotonic() - t0 >= 0.45
    volts = [v for what, v in twin.history if what == "VOLT"]
    assert volts[-1] == pytest.approx(20.0) and len(volts) >= 10
    assert max(b - a for a, b in zip([0.0, *volts], volts, strict=False)) <= 40.0 * 0.05 + 1e-6
    supply.close()


def test_current_limit_puts_the_supply_in_constant_current(twin):
    supply = _open(twin, current_limit_a=2.0)
    supply.set_voltage(20.0)  # 20 V into 4 ohm wants 5 A
    volts, amps = supply.measure()
    assert amps == pytest.approx(2.0) and volts == pytest.approx(8.0)
    supply.close()


def test_garbage_lines_are_counted_and_skipped(twin):
    twin.garbage = True
    supply = _open(twin)
    assert supply.set_voltage(6.0) == pytest.approx(6.0)
    assert supply.stats["garbage"] > 5
    supply.close()
    assert not twin.output


def test_refused_setting_is_an_error_naming_it(twin):
    supply = _open(twin, max_voltage_v=60.0)
    twin.max_voltage_v = 10.0  # the supply refuses what the rig file allows
    with pytest.raises(DeviceError, match=r"refused 'VOLT .*Data out of range"):
        supply.set_voltage(12.0)
    with pytest.raises(UsageError, match="outside 0..60 V"):
        supply.set_voltage(61.0)
    supply.close()


def test_silent_supply_is_a_clear_error_and_close_still_releases(twin):
    supply = _open(twin)
    supply.set_voltage(5.0)
    twin.no_replies = True
    t0 = time.monotonic()
    with pytest.raises(DeviceError, match=r"no reply from SCPI supply on .* within 0.5 s"):
        supply.measure()
    assert time.monotonic() - t0 < 2.0 and supply.stats["timeouts"] == 1
    with pytest.raises(DeviceError, match="no reply"):
        supply.close()  # the safe state could not be confirmed: said, and the port released
    supply.close()  # idempotent after a failed close
    twin.no_replies = False
    assert not twin.output  # the OUTP OFF itself reached the supply


def test_safe_voltage_mode_ramps_down_instead_of_switching_off(twin):
    supply = _open(twin, on_exit="safe_voltage", safe_voltage_v=2.0)
    supply.set_voltage(10.0)
    supply.close()
    assert twin.output and twin.voltage_set == pytest.approx(2.0)


def test_missing_port_names_it():
    with pytest.raises(DeviceError, match=r"cannot open /nonexistent/tty \(SCPI supply\)"):
        ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", url="/nonexistent/tty"))
