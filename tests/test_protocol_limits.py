"""The limits commercial stands trip on: bus voltage, power, torque and temperature.

Each is driven through on the twin (a twin parameter makes it exceed: supply sag, a supply
that floats above its setpoint, the sensor's reaction torque, motor heating), trips to
neutral with an event naming limit, value and threshold, and leaves the supply off. A limit
with no data source on the rig is refused before the run; hostile values are file errors.
"""

from __future__ import annotations

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.devices.thermistor import Thermistor
from rigtool.engine import Engine
from rigtool.errors import ConfigError, SafetyTrip
from rigtool.protocol import Limits, load_protocol
from rigtool.safety import LimitMonitor
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve

from .test_engine import RecordingActuator

SWEEP = """\
rigtool_protocol: 1
name: limits
simulator:
  profile: can-bldc
  seed: 4
  overrides: {overrides}
command: {{unit: percent, values: [0, 20, 40, 60, 80, 100], order: {order}}}
depth: {{unit: m, values: [1.0]}}
voltage: {{unit: V, values: {volts}, settle_s: 0.2}}
timing:
  settle: {{seconds: 0.5}}
  acquire: {{samples: 200, rate_hz: 500}}
  rest_s: 0.2
  tare: at_start
limits:
  slew_per_s: 400
  debounce_samples: 5
{limits}
"""

# limit field, its protocol lines, twin overrides, command order, voltages, what trips
CASES = {
    # 2 ohm leads: the bus sags to 44 V at 60 % and 40 V at 80 %
    "min_bus_v": ("  min_bus_v: 42", "{supply_resistance_ohm: 2.0}", "up", "[48]"),
    # a supply floating 4 V above its setpoint at light load: 46 V set is a 50 V bus (the
    # twin starts at 40 V, 44 V on the bus)
    "max_bus_v": ("  max_bus_v: 48", "{supply_rise_v: 4.0, supply_resistance_ohm: 1.0, "
                  "supply_voltage_v: 40}", "up", "[40, 46]"),
    # 185 W at 80 %
    "max_power_w": ("  max_power_w: 150", "{}", "up", "[48]"),
    # the reaction torque about the thrust axis (tx for fx): 0.05 N m per N of thrust
    "max_torque_nm": ("  max_torque_nm: 1.5", "{crosstalk: [0, 0, 0, 0.05, 0, 0]}", "up", "[48]"),
    # the motor heats with I^2 and the twin reports its temperature
    "max_temperature_c": ("  max_temperature_c: 40",
                          "{feedback: [speed_rpm, current_a, voltage_v, temperature_c], "
                          "heating_c_per_a2_s: 1.0, thermal_tau_s: 60}", "up", "[48]"),
}


def _protocol(name: str) -> str:
    limits, overrides, order, volts = CASES[name]
    return SWEEP.format(limits=limits, overrides=overrides, order=order, volts=volts)


@pytest.mark.parametrize("name", sorted(CASES))
def test_each_limit_trips_on_the_twin_to_neutral_with_the_supply_off(name, write_yaml, db_path):
    setup = resolve(write_yaml(_protocol(name)), sim=True)
    rigset = open_checked(setup)
    rigset.actuator = RecordingActuator(rigset.actuator)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=4, command_unit="percent", tool_version="test")
    twin = rigset.world.twin
    try:
        outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
    finally:
        rigset.close()
    assert outcome.status == "aborted" and name in outcome.reason, outcome.reason
    assert outcome.exit_status == 1  # as every limit trip
    trips = store.events(run_id, "limit_trip")
    assert len(trips) == 1
    detail = trips[0]["detail"]
    threshold = getattr(setup.protocol.limits, name)
    assert detail["limit"] == name and detail["threshold"] == threshold
    beyond = detail["value"] < threshold if name == "min_bus_v" else detail["value"] > threshold
    assert beyond and detail["readings"] >= 5
    assert f"{detail['value']:.4g}" in detail["message"] and f"{threshold:g}" in detail["message"]
    assert rigset.actuator.sent[-1] == 0.0  # neutral
    assert twin.supply_voltage_v == 0.0  # the supply made safe: output off
    # not at the start: the sweep went through points before the limit was reached
    assert 0 < len(store.steps(run_id)) < len(setup.plan)


def test_a_trip_through_the_cli_exits_1_and_names_the_limit(write_yaml, db_path, capsys):
    path = write_yaml(_protocol("max_power_w"))
    assert main(["sweep", str(path), "--sim", "--db", str(db_path)]) == 1
    assert "max_power_w" in capsys.readouterr().err
    store = Store(db_path)
    trip = store.events(store.resolve_run_id("last"), "limit_trip")[0]["detail"]
    assert trip["limit"] == "max_power_w" and trip["source"] == "actuator"


@pytest.mark.parametrize("quantity, field, values, source", [
    ("bus_v", "min_bus_v", [30, 10, 10, 30, 10, 10], "actuator"),
    ("bus_v", "max_bus_v", [30, 60, 60, 30, 60, 30], "actuator"),
    ("power_w", "max_power_w", [0, 900, -900, 0, 900, 0], "actuator"),
    ("torque_nm", "max_torque_nm", [0, 9, -9, 0, 9, 0], ""),
    ("temperature_c", "max_temperature_c", [20, 99, 99, 20, 99, 20], "sensor"),
])
def test_every_new_limit_is_debounced_in_its_own_readings(quantity, field, values, source):
    limits = Limits(min_bus_v=20, max_bus_v=50, max_power_w=500, max_torque_nm=5,
                    max_temperature_c=80, debounce_samples=3)
    mon = LimitMonitor(limits)
    mon.check({quantity: np.array(values, dtype=float)}, source)  # runs of 2 and 1: no trip
    mon.check({quantity: np.array([np.nan] * 8)}, source)  # missing readings never trip
    mon.check({quantity: np.array(values[:1], dtype=float)}, source)  # one within: count restarts
    mon.check({quantity: np.array(values[:2], dtype=float)}, "supply")  # counted apart
    with pytest.raises(SafetyTrip) as trip:  # 2 at the end of one block + 1: 3 in a row
        mon.check({quantity: np.array(values[1:3], dtype=float)}, source)
        mon.check({quantity: np.array(values[1:2], dtype=float)}, source)
    assert trip.value.detail["limit"] == field and trip.value.detail["readings"] == 3


def test_blocks_without_valid_readings_keep_the_count():
    """A slow source (blocks with no reading) or NaN readings do not restart the count."""
    mon = LimitMonitor(Limits(max_temperature_c=35, debounce_samples=3))
    mon.check({"temperature_c": np.array([80.0])}, "actuator")
    mon.check({"temperature_c": np.array([])}, "actuator")
    mon.check({"temperature_c": np.array([80.0, np.nan])}, "actuator")
    mon.check({"temperature_c": np.array([np.nan])}, "actuator")
    with pytest.raises(SafetyTrip) as trip:
        mon.check({"temperature_c": np.array([80.0])}, "actuator")
    assert trip.value.detail["readings"] == 3


def test_a_source_without_valid_readings_trips_after_the_bound():
    """Blocks with no valid reading for NO_READING_S trip, naming the limit; one valid
    reading restarts that time."""
    from rigtool.safety import NO_READING_S

    clock = [0.0]
    mon = LimitMonitor(Limits(max_temperature_c=35), lambda: clock[0])
    for t in np.arange(0.0, NO_READING_S, 0.1):
        clock[0] = float(t)
        mon.check({"temperature_c": np.array([np.nan, np.nan])}, "actuator")
    mon.check({"temperature_c": np.array([20.0])}, "actuator")  # back: the time restarts
    for t in np.arange(NO_READING_S, 2 * NO_READING_S - 0.05, 0.1):
        clock[0] = float(t)
        mon.check({"temperature_c": np.array([])}, "actuator")
    clock[0] = 2 * NO_READING_S + 0.01
    with pytest.raises(SafetyTrip, match="max_temperature_c: no valid reading") as trip:
        mon.check({"temperature_c": np.array([])}, "actuator")
    assert trip.value.detail["reason"] == "no valid reading"


NO_FEEDBACK = """\
rigtool_protocol: 1
name: no-source
simulator: {{profile: stm32-pwm}}
command: {{unit: pwm_counts, values: [0, 300]}}
depth: {{unit: cm, values: [30]}}
timing:
  settle: {{seconds: 0.2}}
  acquire: {{samples: 100, rate_hz: 500}}
limits:
  max_thrust_n: 20
{limit}
"""


@pytest.mark.parametrize("limit, missing", [
    ("  min_bus_v: 10", "no bus voltage"), ("  max_bus_v: 30", "no bus voltage"),
    ("  max_power_w: 100", "no power"), ("  max_temperature_c: 60", "no temperature channel"),
])
@pytest.mark.parametrize("dry", [False, True])
def test_a_limit_without_data_on_the_rig_is_refused_before_the_run(limit, missing, dry,
                                                                   write_yaml, db_path, capsys):
    """The stm32-pwm twin reports no feedback and the protocol programs no supply."""
    path = write_yaml(NO_FEEDBACK.format(limit=limit))
    args = ["sweep", str(path), "--sim", "--db", str(db_path)] + (["--dry-run"] if dry else [])
    assert main(args) == 2
    err = capsys.readouterr().err
    field = limit.split(":")[0].strip()
    assert f"{path}:11" in err and f"limits.{field}" in err and missing in err
    assert not db_path.exists() or Store(db_path).runs() == []


def test_torque_on_a_single_axis_gauge_is_refused(write_yaml, tmp_path, capsys):
    rig = write_yaml("rigtool_rig: 1\nname: gauge-bench\n"
                     "actuator: {driver: stm32-bridge, url: 'socket://127.0.0.1:9'}\n"
                     "sensor: {driver: ascii-gauge, url: /dev/null, preset: hx711-csv}\n",
                     "rig.yaml")
    path = write_yaml(NO_FEEDBACK.format(limit="  max_torque_nm: 2"))
    assert main(["sweep", str(path), "--rig", str(rig), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert f"{path}:11" in err and "max_torque_nm" in err and "force only" in err


def test_a_gauge_temperature_field_is_a_source(write_yaml, capsys):
    rig = write_yaml("rigtool_rig: 1\nname: gauge-bench\n"
                     "actuator: {driver: stm32-bridge, url: 'socket://127.0.0.1:9'}\n"
                     "sensor: {driver: ascii-gauge, url: /dev/null, mode: stream, unit: N,\n"
                     "  pattern: '(?P<value>[-0-9.]+),(?P<temperature_c>[-0-9.]+)'}\n",
                     "rig.yaml")
    path = write_yaml(NO_FEEDBACK.format(limit="  max_temperature_c: 60"))
    assert main(["sweep", str(path), "--rig", str(rig), "--dry-run"]) == 0


HOSTILE = [
    ("min_bus_v: .nan", "min_bus_v"),
    ("max_bus_v: '48 V'", "max_bus_v"),
    ("max_power_w: -5", "max_power_w"),
    ("max_torque_nm: .inf", "max_torque_nm"),
    ("max_temperature_c: -300", "max_temperature_c"),
    ("debounce_samples: -2", "debounce_samples"),
    ("debounce_samples: true", "debounce_samples"),
    ("max_temperature_c: '70'", "max_temperature_c"),
    ("max_thrust_n: '20'", "max_thrust_n"),
    ("torque_channel: fx", "torque_channel"),
    ("min_bus_v: 50\n  max_bus_v: 40", "min_bus_v"),
]


@pytest.mark.parametrize("line, field", HOSTILE)
def test_hostile_limit_values_name_file_and_line(line, field, write_yaml):
    text = SWEEP.format(limits="  " + line, overrides="{}", order="up", volts="[48]")
    path = write_yaml(text)
    with pytest.raises(ConfigError) as exc:
        load_protocol(path)
    lineno = text.splitlines().index("  " + line.split("\n")[0]) + 1
    assert f"{path}:{lineno}" in str(exc.value) and field in str(exc.value)


def test_a_swept_voltage_outside_the_bus_limits_is_a_file_error(write_yaml):
    text = SWEEP.format(limits="  max_bus_v: 45", overrides="{}", order="up", volts="[40, 48]")
    path = write_yaml(text)
    with pytest.raises(ConfigError) as exc:
        load_protocol(path)
    lineno = text.splitlines().index("  max_bus_v: 45") + 1
    assert f"{path}:{lineno}" in str(exc.value) and "48 V" in str(exc.value)


# -- thermistor --------------------------------------------------------------------------
def test_beta_thermistor_round_trips_and_rails_are_nan():
    th = Thermistor(beta_k=3950, r0_ohm=10_000, t0_c=25, series_ohm=10_000, adc_max=4095)
    assert th.counts(25.0) == 2048  # R = R0: half scale
    temps = th.temperature_c(np.array([th.counts(t) for t in (0.0, 25.0, 60.0, 100.0)]))
    assert np.allclose(temps, [0, 25, 60, 100], atol=0.5)
    assert np.isnan(th.temperature_c(np.array([0, 4095, -3, 9999]))).all()
    high = Thermistor(beta_k=3950, position="high")
    assert high.temperature_c(np.array([high.counts(70.0)]))[0] == pytest.approx(70, abs=0.5)


def test_steinhart_hart_agrees_with_a_10k_ntc():
    # a common 10 k NTC's coefficients: 25 degC at 10 k, about 85 degC at 1.07 k
    th = Thermistor(steinhart_hart=(1.009249522e-3, 2.378405444e-4, 2.019202697e-7))
    x = 10_000 / (10_000 + 10_000)
    assert th.temperature_c(np.array([x * 4095]))[0] == pytest.approx(25, abs=0.5)


@pytest.mark.parametrize("fields", [
    {}, {"beta_k": 3950, "steinhart_hart": [1e-3, 2e-4, 2e-7]}, {"beta_k": -1},
    {"beta_k": float("nan")}, {"steinhart_hart": [1e-3, -2e-4, 2e-7]}, {"beta_k": 3950, "adc_max": 0},
])
def test_hostile_thermistor_sections_are_refused(fields):
    with pytest.raises(ValueError):
        Thermistor(**fields)


# -- a thermistor on the bridge's ADC, over real transports --------------------------------
BENCH_PROTOCOL = """\
rigtool_protocol: 1
name: hot-motor
command: {unit: pwm_counts, values: [0, 300, 300, 300]}
depth: {unit: cm, values: [30]}
timing:
  settle: {seconds: 0.3}
  acquire: {samples: 300, rate_hz: 1000}
  tare: at_start
  tare_s: 0.2
limits:
  max_thrust_n: 20
  max_temperature_c: 35
  debounce_samples: 3
"""


SLOW_BENCH_PROTOCOL = BENCH_PROTOCOL.replace("[0, 300, 300, 300]", "[0, 300, 300, 300, 300]").replace(
    "{samples: 300, rate_hz: 1000}", "{seconds: 2, rate_hz: 1000}")


@pytest.mark.slow
@pytest.mark.parametrize("telemetry_hz, adc_max, protocol_text, reason", [
    (50, 4095, BENCH_PROTOCOL, None),
    # one frame every 0.5 s: the blocks between frames hold none and must not reset the count
    (2, 4095, SLOW_BENCH_PROTOCOL, None),
    # every count beyond a 10-count full scale: railed, no temperature at all
    (50, 10, SLOW_BENCH_PROTOCOL, "no valid reading"),
])
def test_thermistor_telemetry_from_the_bridge_trips_the_temperature_limit(
        telemetry_hz, adc_max, protocol_text, reason, tmp_path, capsys):
    """The STM32 bridge twin on TCP prints the motor's thermistor as ADC counts (Beta 3950,
    10 k divider); the rig file's `thermistor:` converts them; the motor heats at 300 counts.
    Slow telemetry still trips in time; a railed thermistor stops the run, it does not turn
    the limit off."""
    import dataclasses

    from rigtool.sim.live import LiveTwin
    from rigtool.sim.netft_twin import NetFTTwin
    from rigtool.sim.physics import ThrusterTwin
    from rigtool.sim.stm32_twin import Dialect, Stm32BridgeTwin
    from rigtool.thruster_profiles import PROFILES

    profile = dataclasses.replace(PROFILES["stm32-pwm"], heating_c_per_a2_s=3.0,
                                  feedback=("speed_rpm", "current_a", "voltage_v", "temperature_c"))
    thermistor = Thermistor(beta_k=3950)
    live = LiveTwin(ThrusterTwin(profile, seed=5)).start()
    fw = Stm32BridgeTwin(live, telemetry_hz=telemetry_hz, thermistor=thermistor, dialect=Dialect(
        telemetry="TEL {speed_rpm:.1f} {current_a:.3f} {voltage_v:.2f} {thermistor_counts}")).start()
    box = NetFTTwin(live).start()
    try:
        host, port = box.address
        regex = (r"TEL (?P<speed_rpm>\S+) (?P<current_a>\S+) (?P<voltage_v>\S+) "
                 r"(?P<thermistor_counts>\d+)")
        rig = tmp_path / "rig.yaml"
        rig.write_text(
            "rigtool_rig: 1\nname: hot-bench\nthrust: {channel: fz, sign: -1}\n"
            f"actuator: {{driver: stm32-bridge, url: '{fw.url}', timeout_s: 0.5,\n"
            f"  telemetry_regex: '{regex}',\n"
            f"  thermistor: {{beta_k: 3950, r0_ohm: 10000, series_ohm: 10000, adc_max: {adc_max}}}}}\n"
            f"sensor: {{driver: ati-netft, host: {host}, port: {port}, "
            f"http_port: {box.http_port}}}\n")
        protocol = tmp_path / "p.yaml"
        protocol.write_text(protocol_text)
        db = tmp_path / "db.sqlite"
        assert main(["sweep", str(protocol), "--rig", str(rig), "--db", str(db)]) == 1
        store = Store(db)
        run_id = store.resolve_run_id("last")
        trip = store.events(run_id, "limit_trip")[0]["detail"]
        assert trip["limit"] == "max_temperature_c" and trip["source"] == "actuator"
        if reason is None:
            assert trip["value"] > 35 and trip["readings"] >= 3
        else:
            assert trip["reason"] == reason and "no valid reading" in trip["message"]
        assert fw.ccr[fw.thruster_channel] == fw.neutral_ccr  # at neutral
        assert "max_temperature_c" in capsys.readouterr().err
    finally:
        for part in (box, fw, live):
            part.stop()


@pytest.mark.slow
def test_a_gauge_line_temperature_trips_the_limit_over_a_pty(write_yaml, db_path):
    """An HX711 sketch printing `millis,raw,temperature_c` at 80 Hz; the motor heats."""
    import dataclasses

    from rigtool.clock import RealClock
    from rigtool.devices.ascii_gauge import AsciiGauge
    from rigtool.devices.depth import PresetDepth
    from rigtool.plan import expand
    from rigtool.rig import RigSet
    from rigtool.sim.gauge_twin import GaugeTwin
    from rigtool.sim.live import LiveTwin
    from rigtool.sim.physics import ThrusterTwin
    from rigtool.thruster_profiles import PROFILES

    from .test_netft import LiveActuator

    profile = dataclasses.replace(PROFILES["can-bldc"], heating_c_per_a2_s=2.0,
                                  feedback=("speed_rpm", "current_a", "voltage_v", "temperature_c"))
    live = LiveTwin(ThrusterTwin(profile, seed=2)).start()
    twin = GaugeTwin(live, "hx711-csv", rate_hz=80, scale=0.001, offset=8000,
                     temperature=True).start()
    path = write_yaml("""\
rigtool_protocol: 1
name: gauge-temperature
command: {unit: percent, values: [0, 80, 80]}
depth: {unit: m, values: [1.0]}
timing: {settle: {seconds: 0.5}, acquire: {seconds: 1, rate_hz: 80}, tare: at_start, tare_s: 0.2}
limits: {max_thrust_n: 90, max_temperature_c: 30, debounce_samples: 4}
""")
    protocol, _ = load_protocol(path)
    try:
        sensor = AsciiGauge({"driver": "ascii-gauge", "url": twin.port, "mode": "stream",
                             "unit": "N", "scale": 0.001, "offset": 8000, "pattern":
                             r"(?P<seq>\d+),(?P<value>\d+),(?P<temperature_c>[-0-9.na]+)"})
        rigset = RigSet(actuator=LiveActuator(live), sensor=sensor, depth_stage=PresetDepth(),
                        clock=RealClock(), thrust_channel=0, thrust_sign=1)
        store = Store(db_path)
        run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                                  metadata={}, seed=2, command_unit="percent", tool_version="test")
        try:
            outcome = Engine(protocol, expand(protocol), rigset, store, run_id).run()
        finally:
            rigset.close()
    finally:
        twin.stop()
        live.stop()
    assert outcome.status == "aborted" and "max_temperature_c" in outcome.reason
    trip = store.events(run_id, "limit_trip")[0]["detail"]
    assert trip["source"] == "sensor" and 30 < trip["value"] < 45 and trip["readings"] >= 4
    assert live.twin.command == 0.0


def test_power_from_the_programmed_supply_alone(write_yaml, db_path):
    """The stm32-pwm twin reports no feedback; its supply's volts x amps (60 W at 300
    counts) is the power limit's source, so the limit is accepted and trips from it."""
    text = NO_FEEDBACK.format(limit="  max_power_w: 40").replace(
        "timing:", "voltage: {unit: V, values: [12], settle_s: 0.2}\ntiming:").replace(
        "settle: {seconds: 0.2}", "settle: {seconds: 1.0}")
    setup = resolve(write_yaml(text), sim=True)
    rigset = open_checked(setup)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="pwm_counts", tool_version="test")
    try:
        outcome = Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
    finally:
        rigset.close()
    assert outcome.status == "aborted"
    trip = store.events(run_id, "limit_trip")[0]["detail"]
    assert trip["limit"] == "max_power_w" and trip["source"] == "supply"
    assert trip["value"] == pytest.approx(12 * 5.06, rel=0.02)
    assert rigset.world.twin.supply_voltage_v == 0.0
