"""The SCPI supply driver against its twin over a pty and over TCP: settings confirmed,
ramps at the slew limit, garbage counted and skipped, a silent supply a clear error, the
output left safe on close, never switched on outside the rig's limits, and the supply's own
protections (over-voltage, output watchdog) armed where it has them."""

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
    cfg = dict(driver="scpi-supply", url=getattr(twin, "where", twin.pty_path), timeout_s=0.5, slew_v_per_s=40.0,
               current_limit_a=5.0, max_voltage_v=24.0)
    return ScpiSupply(ScpiSupplyConfig(**(cfg | kw)))


def test_identity_limit_voltage_and_measurement(twin):
    supply = _open(twin)
    assert supply.identity.startswith("RIGTOOL,SIM-PSU")
    assert twin.current_limit == 10.0 and not twin.output  # opening commands nothing
    volts = supply.set_voltage(12.0)
    assert twin.current_limit == 5.0 and twin.on_states == [(0.0, 5.0)]
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
    with pytest.raises(DeviceError, match=r"refused 'VOLT(:PROT)? .*Data out of range"):
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


def test_safe_voltage_mode_keeps_a_supply_found_on_at_its_safe_voltage():
    """Something else relied on the supply being on: the exit ramps it down, never up."""
    for safe_v, last_v in ((2.0, 10.0), (20.0, 12.0)):
        with ScpiSupplyTwin(setpoint_v=6.0, output=True) as twin:
            supply = _open(twin, on_exit="safe_voltage", safe_voltage_v=safe_v)
            supply.set_voltage(last_v)
            supply.close()
            assert twin.output and twin.voltage_set == pytest.approx(min(safe_v, last_v))
            assert max(v for what, v in twin.history if what == "VOLT") == last_v


def test_safe_voltage_mode_switches_off_a_supply_it_found_off(twin):
    supply = _open(twin, on_exit="safe_voltage", safe_voltage_v=2.0)
    supply.set_voltage(10.0)
    supply.close()
    assert not twin.output


def test_missing_port_names_it():
    with pytest.raises(DeviceError, match=r"cannot open /nonexistent/tty \(SCPI supply\)"):
        ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", url="/nonexistent/tty"))


def _on_outside_limits(twin, max_voltage_v: float, current_limit_a: float) -> list:
    """Every moment the output was switched on at a setpoint or current limit outside the rig's."""
    return [(v, a) for v, a in twin.on_states if v > max_voltage_v or a > current_limit_a + 1e-9]


@pytest.mark.parametrize("leftover_v", [48.0, 24.5, 12.0])
def test_leftover_setpoint_is_never_switched_on(leftover_v):
    """A shared bench supply left off at a high setpoint: the limit and a 0 V setpoint are
    programmed and read back with the output off, then it is switched on and ramped up."""
    for where in ("pty_path", "url"):
        with ScpiSupplyTwin(max_voltage_v=60.0, setpoint_v=leftover_v, load_ohm=4.0) as twin:
            supply = _open(twin, url=getattr(twin, where), max_voltage_v=24.0,
                           current_limit_a=2.0, slew_v_per_s=400.0)
            assert twin.lines[:1] == ["*IDN?"] and not twin.history  # opening sets nothing
            supply.set_voltage(12.0)
            assert twin.on_states == [(0.0, 2.0)]
            sent = [line for line in twin.lines if not line.endswith("?")]
            assert sent.index("OUTP ON") > max(sent.index("CURR 2.0000"), sent.index("VOLT 0.0000"))
            assert twin.ovp_v == 24.0 and twin.voltage_set == pytest.approx(12.0)
            supply.close()
            assert not twin.output and _on_outside_limits(twin, 24.0, 2.0) == []


def test_output_found_on_above_the_limit_is_switched_off_and_refused():
    with ScpiSupplyTwin(max_voltage_v=60.0, setpoint_v=48.0, output=True) as twin:
        with pytest.raises(DeviceError, match=r"output was on at a 48 V setpoint, above "
                                              r"max_voltage_v \(24 V\).*switched it off"):
            _open(twin, url=twin.pty_path, max_voltage_v=24.0)
        assert not twin.output and twin.history == [("OUTP", 0.0)]


def test_output_found_on_within_limits_is_switched_off_before_it_is_programmed():
    with ScpiSupplyTwin(setpoint_v=20.0, output=True) as twin:
        supply = _open(twin, url=twin.url, max_voltage_v=24.0, slew_v_per_s=1000.0)
        supply.set_voltage(12.0)
        assert twin.history[0] == ("OUTP", 0.0) and twin.on_states == [(0.0, 5.0)]
        on_at = twin.history.index(("OUTP", 1.0))
        assert {what for what, _ in twin.history[1:on_at]} == {"CURR", "VOLT", "VOLT:PROT",
                                                                "OUTP:PROT:WDOG:DEL", "WDOG_ARM"}
        assert twin.voltage_set == 12.0
        supply.close()
        assert not twin.output


def test_supplies_that_round_answer_in_words_or_guard_their_protection():
    """A 10 mV setpoint resolution (Korad), `OUTP?` answered ON/OFF (Rigol), and a protection
    level that may not go below the leftover setpoint: all arm and ramp."""
    with ScpiSupplyTwin(setpoint_v=48.0, max_voltage_v=60.0, resolution_v=0.01,
                        state_words=True) as twin:
        supply = _open(twin, slew_v_per_s=7.0, max_voltage_v=24.0)
        assert supply.found.output_on is False and supply.found.ovp_v == 60.0
        supply.set_voltage(1.0)
        assert twin.output and twin.voltage_set == pytest.approx(1.0) and twin.ovp_v == 24.0
        supply.close()
        assert not twin.output and twin.ovp_v == 60.0  # the level found, restored


def test_untouched_supply_is_left_as_found():
    """A supply opened but never set (a dry run, a run that stopped before its first voltage)
    is sent no setting on close, whatever `on_exit` says."""
    for on_exit in ("off", "safe_voltage"):
        with ScpiSupplyTwin(setpoint_v=12.0) as twin:
            supply = _open(twin, url=twin.pty_path, on_exit=on_exit, safe_voltage_v=12.0)
            supply.close()
            assert not twin.output and twin.history == []
            assert all(line.endswith("?") for line in twin.lines)


def test_safe_voltage_exit_never_switches_an_off_output_on(twin):
    supply = _open(twin, on_exit="safe_voltage", safe_voltage_v=5.0)
    supply.set_voltage(10.0)
    supply.output(False)  # e.g. the operator, or a protection, switched it off
    supply.safe()
    supply.close()
    assert not twin.output and twin.on_states == [(0.0, 5.0)]


def test_watchdog_and_over_voltage_protection_are_armed_and_disarmed(twin):
    supply = _open(twin, watchdog_s=2.0)
    assert supply.protection.over_voltage and supply.protection.watchdog
    supply.set_voltage(6.0)
    assert twin.watchdog and twin.watchdog_s == 2.0 and twin.ovp_v == 24.0
    time.sleep(3.0)  # the keep-alive talks while the host is alive
    assert twin.output
    supply.close()
    assert not twin.output and not twin.watchdog  # left to the next user without a watchdog


def test_watchdog_switches_the_output_off_when_the_host_goes_silent(twin):
    supply = _open(twin, watchdog_s=1.0)
    supply.set_voltage(6.0)
    supply._keepalive_stop.set()  # what kill -9 does to the host's keep-alive thread
    twin.no_replies = True
    deadline = time.monotonic() + 5.0
    while twin.output and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not twin.output and ("WDOG", 0.0) in twin.history


def test_supply_without_protections_is_reported_and_required_refuses():
    with ScpiSupplyTwin(protection=False) as twin:
        supply = _open(twin, url=twin.pty_path, timeout_s=0.2)
        assert not supply.protection.over_voltage and not supply.protection.watchdog
        assert supply.stats["timeouts"] == 0  # probing is not a link fault
        supply.set_voltage(6.0)
        assert twin.output
        supply.close()
        with pytest.raises(DeviceError, match="has no watchdog"):
            _open(twin, url=twin.pty_path, timeout_s=0.2, watchdog="required")


def test_safe_voltage_above_the_limit_is_a_config_error():
    with pytest.raises(ValueError, match="safe_voltage_v"):
        ScpiSupplyConfig(driver="scpi-supply", url="x", max_voltage_v=24, on_exit="safe_voltage",
                         safe_voltage_v=30)
