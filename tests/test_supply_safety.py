"""The bench supply at the edges, through the CLI with the real drivers: the STM32 bridge twin
on TCP drives the LiveTwin, the Net F/T twin streams it over UDP, and the SCPI supply twin
answers on a pty or TCP. A supply left at a high setpoint is never switched on there, a dry run
sends it nothing, a current-limited point trips instead of being stored under the set voltage,
and a run that stops before its first voltage point leaves the supply as it was found."""

from __future__ import annotations

import contextlib
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time

import pytest

from rigtool.cli import main
from rigtool.devices.scpi_supply import ScpiSupply, ScpiSupplyConfig
from rigtool.engine import Engine
from rigtool.errors import DeviceError
from rigtool.sim.live import LiveTwin
from rigtool.sim.netft_twin import NetFTTwin
from rigtool.sim.physics import ThrusterTwin
from rigtool.sim.scpi_supply_twin import ScpiSupplyTwin
from rigtool.sim.stm32_twin import Stm32BridgeTwin
from rigtool.store import Store
from rigtool.sweep import open_checked, resolve
from rigtool.thruster_profiles import PROFILES

from .helpers import wait_for

PROTOCOL = """\
rigtool_protocol: 1
name: supply-edges
command: {{unit: pwm_counts, values: [0, 300]}}
depth: {{unit: cm, values: [30]}}
voltage: {{unit: V, values: {volts}, order: up, settle_s: 0.2}}
timing:
  settle: {{seconds: 0.3}}
  acquire: {{samples: 200, rate_hz: 1000}}
  tare: at_start
  tare_s: 0.2
limits: {{max_thrust_n: 20, max_current_a: {amps}}}
"""


@pytest.fixture(params=["pty", "tcp"])
def bench(request, tmp_path):
    """Write (protocol, rig) files for a bridge + Net F/T + SCPI supply bench; yields a
    function taking the supply twin's settings and the rig's supply section."""
    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=5)).start()
    fw = Stm32BridgeTwin(live).start()
    box = NetFTTwin(live).start()
    supplies: list[ScpiSupplyTwin] = []

    def _make(volts=(12.0, 16.0), amps=5.0, supply_section="", **twin_kw):
        twin = ScpiSupplyTwin(load_ohm=4.0, source_ohm=0.0, **twin_kw).start()
        supplies.append(twin)
        url = twin.pty_path if request.param == "pty" else twin.url
        host, port = box.address
        rig = tmp_path / "rig.yaml"
        rig.write_text(
            "rigtool_rig: 1\nname: supply-bench\nthrust: {channel: fz, sign: -1}\n"
            f"actuator: {{driver: stm32-bridge, url: '{fw.url}', timeout_s: 0.5}}\n"
            f"sensor: {{driver: ati-netft, host: {host}, port: {port}, "
            f"http_port: {box.http_port}}}\n"
            f"supply: {{driver: scpi-supply, url: '{url}', timeout_s: 0.5, slew_v_per_s: 200, "
            f"max_voltage_v: 24{supply_section}}}\n")
        protocol = tmp_path / "p.yaml"
        protocol.write_text(PROTOCOL.format(volts=list(volts), amps=amps))
        return twin, protocol, rig

    yield _make
    for part in (*supplies, box, fw, live):
        part.stop()


def _sweep(protocol, rig, db, *extra) -> int:
    return main(["sweep", str(protocol), "--rig", str(rig), "--db", str(db), *extra])


def _switched_on_outside(twin: ScpiSupplyTwin, max_v: float, max_a: float) -> list:
    return [(v, a) for v, a in twin.on_states if v > max_v or a > max_a + 1e-9]


@pytest.mark.slow
def test_leftover_48v_setpoint_is_never_on_and_the_run_completes(bench, tmp_path):
    twin, protocol, rig = bench(setpoint_v=48.0, max_voltage_v=60.0)
    assert _sweep(protocol, rig, tmp_path / "db.sqlite") == 0
    assert twin.on_states == [(0.0, 5.0)] and _switched_on_outside(twin, 24.0, 5.0) == []
    assert max(v for what, v in twin.history if what == "VOLT") == 16.0
    assert ("VOLT:PROT", 24.0) in twin.history  # the protection held the rig's limit
    assert not twin.output and not twin.watchdog and twin.ovp_v == 60.0  # restored as found
    store = Store(tmp_path / "db.sqlite")
    assert {s["voltage_set_v"] for s in store.steps(store.resolve_run_id("last"))} == {12.0, 16.0}


@pytest.mark.slow
def test_dry_run_sends_the_supply_nothing(bench, tmp_path, capsys):
    twin, protocol, rig = bench(setpoint_v=12.0, supply_section=", on_exit: safe_voltage, "
                                                                "safe_voltage_v: 12")
    assert _sweep(protocol, rig, tmp_path / "db.sqlite", "--dry-run") == 0
    assert twin.lines == [] and not twin.output
    assert "4 points" in capsys.readouterr().out


@pytest.mark.slow
def test_current_limited_supply_trips_and_stores_no_point_under_its_label(bench, tmp_path,
                                                                          capsys):
    """3.5 A into the 4 ohm load: 12 V (3 A) holds, 16 V would need 4 A and goes
    constant-current at 14 V; and at 0.5 A even 12 V collapses to 2 V."""
    twin, protocol, rig = bench(amps=3.5)
    db = tmp_path / "db.sqlite"
    assert _sweep(protocol, rig, db) == 1
    store = Store(db)
    run_id = store.resolve_run_id("last")
    assert {s["voltage_set_v"] for s in store.steps(run_id)} == {12.0}
    trip = store.events(run_id, "limit_trip")[0]["detail"]
    assert trip["check"] == "bus_voltage" and trip["set_v"] == 16.0
    assert trip["measured_v"] == pytest.approx(14.0) and trip["limit_a"] == 3.5
    assert "current-limited" in capsys.readouterr().err and not twin.output

    twin, protocol, rig = bench(amps=0.5)
    assert _sweep(protocol, rig, db) == 1
    run_id = store.resolve_run_id("last")
    assert store.steps(run_id) == [] and not twin.output
    assert store.events(run_id, "limit_trip")[0]["detail"]["measured_v"] == pytest.approx(2.0)


SIM_PROTOCOL = """\
rigtool_protocol: 1
name: t
simulator: {profile: esc-1100-1900}
command: {unit: pulse_us, values: [1500, 1700]}
depth: {unit: m, values: [1.0]}
voltage: {unit: V, values: [12]}
timing: {settle: {seconds: 0.2}, acquire: {samples: 50, rate_hz: 500}, tare: at_start}
"""


def _run_with_supply(tmp_path, url: str, read, **supply) -> tuple[Store, object]:
    """The in-process ESC twin at 12 V with the real SCPI driver at `url`; the sensor's
    reads go through `read(inner_read, *args)`. Returns the store and the outcome."""
    protocol = tmp_path / "p.yaml"
    protocol.write_text(SIM_PROTOCOL)
    setup = resolve(protocol, sim=True)
    rigset = open_checked(setup)
    rigset.supply = ScpiSupply(ScpiSupplyConfig(driver="scpi-supply", url=url,
                                                max_voltage_v=24.0, **supply))
    inner = rigset.sensor.read
    rigset.sensor.read = lambda *args: read(inner, *args)
    store = Store(tmp_path / "db.sqlite")
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="pulse_us", tool_version="t")
    try:
        return store, Engine(setup.protocol, setup.plan, rigset, store, run_id).run()
    finally:
        with contextlib.suppress(Exception):
            rigset.close()


@pytest.mark.parametrize("transport", ["pty_path", "url"])
def test_run_stopped_before_its_first_voltage_leaves_the_supply_as_found(tmp_path, transport):
    """A sensor lost during the first tare: the supply, left off at 12 V with `on_exit:
    safe_voltage`, is sent no setting at all."""

    def lost(inner, *args):
        raise DeviceError("sensor lost")

    with ScpiSupplyTwin(setpoint_v=12.0) as twin:
        _, outcome = _run_with_supply(tmp_path, getattr(twin, transport), lost,
                                      on_exit="safe_voltage", safe_voltage_v=12.0)
        assert outcome.status == "aborted" and "sensor lost" in outcome.reason
        assert not twin.output and twin.history == []
        assert all(line.endswith("?") for line in twin.lines)


@pytest.mark.slow
def test_kill_9_leaves_the_output_to_the_supplys_watchdog(bench, tmp_path):
    """Nothing on the host acts after kill -9: the watchdog armed on the supply switches the
    output off once the host falls silent."""
    twin, protocol, rig = bench(supply_section=", watchdog_s: 1")
    protocol.write_text(protocol.read_text().replace("samples: 200", "samples: 20000"))
    proc = subprocess.Popen([sys.executable, "-m", "rigtool.cli", "sweep", str(protocol),
                             "--rig", str(rig), "--db", str(tmp_path / "db.sqlite")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert wait_for(lambda: twin.output, timeout_s=30.0), "the sweep never switched on"
        time.sleep(2.5)  # alive: the keep-alive holds the output on past the watchdog delay
        assert twin.output and twin.watchdog
        proc.kill()
        proc.wait(10)
        assert wait_for(lambda: not twin.output, timeout_s=5.0)
        assert ("WDOG", 0.0) in twin.history
    finally:
        if proc.poll() is None:
            proc.kill()


@pytest.mark.slow
@pytest.mark.parametrize("protection", [True, False])
def test_check_reports_the_supplys_protections_and_leaves_it_as_found(bench, capsys, protection):
    twin, _, rig = bench(setpoint_v=48.0, max_voltage_v=60.0, protection=protection)
    assert main(["check", str(rig), "--seconds", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "RIGTOOL,SIM-PSU" in out and "setpoint 48 V" in out
    if protection:
        assert "over-voltage protection: yes" in out and "output watchdog: yes" in out
    else:
        assert "output watchdog: NO" in out and "stays on" in out
    assert twin.history == [] and all(line.endswith("?") for line in twin.lines)


def _voltage_reads(twin: ScpiSupplyTwin) -> int:
    """How many times the sweep has read the supply's terminal voltage so far."""
    return sum(1 for line in list(twin.lines) if line.upper().startswith("MEAS:VOLT"))


def _held(twin: ScpiSupplyTwin, stop: threading.Event, flip_s: float) -> bool:
    """Wait `flip_s`, then until the supply's voltage has been read once more; True when
    `stop` was set meanwhile."""
    reads = _voltage_reads(twin)
    if stop.wait(flip_s):
        return True
    while _voltage_reads(twin) <= reads:
        if stop.wait(0.01):
            return True
    return False


def _cc_part_way(twin: ScpiSupplyTwin, db, after_points: int, flip_s: float | None = None):
    """Once `after_points` points are stored, the load grows so that 12 V needs 12 A: the
    supply goes constant-current (3.5 A into 1 ohm: 3.5 V); with `flip_s` it comes and goes,
    each state held for at least `flip_s` and until the sweep has read the voltage in it (a
    count, not a wall-clock window: a loaded machine slows the reads, not what they see)."""
    stop = threading.Event()
    seen: list[int] = []

    def _watch() -> None:
        while not stop.is_set():
            if db.exists():
                with contextlib.suppress(sqlite3.Error):
                    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)
                    n = conn.execute("SELECT count(*) FROM steps").fetchone()[0]
                    conn.close()
                    if n >= after_points:
                        seen.append(n)
                        break
            time.sleep(0.01)
        while not stop.is_set():
            twin.load_ohm = 1.0
            if flip_s is None or _held(twin, stop, flip_s):
                return
            twin.load_ohm = 4.0
            _held(twin, stop, flip_s)

    thread = threading.Thread(target=_watch, daemon=True)
    thread.start()
    return stop, seen


@pytest.mark.slow
@pytest.mark.parametrize("flip_s", [None, 0.2])
def test_constant_current_part_way_through_trips_before_the_point_is_labelled(
        bench, tmp_path, flip_s):
    """A supply that goes constant-current during a point, for good or coming and going, trips
    the run, and the point acquired meanwhile is not stored (a point that ended before is)."""
    twin, protocol, rig = bench(volts=(12.0,), amps=3.5)
    protocol.write_text(protocol.read_text().replace("values: [0, 300]", "values: [0, 100, 200, "
                                                     "300, 400]"))
    db = tmp_path / "db.sqlite"
    stop, seen = _cc_part_way(twin, db, after_points=2, flip_s=flip_s)
    try:
        assert _sweep(protocol, rig, db) == 1
    finally:
        stop.set()
    store = Store(db)
    run_id = store.resolve_run_id("last")
    assert seen and len(store.steps(run_id)) <= seen[0] + 1 < 5
    trip = store.events(run_id, "limit_trip")[0]["detail"]
    assert trip["check"] == "bus_voltage" and trip["measured_v"] < 4.0 and not twin.output


@pytest.mark.slow
def test_a_supply_just_short_of_its_current_limit_still_trips(bench, tmp_path):
    """9.5 V at a 12 V point with 3.94 A against a 4 A limit (meter accuracy): the supply's
    terminals are outside its constant-voltage band, whatever the current reads."""
    twin, protocol, rig = bench(volts=(12.0,), amps=4.0, meter_gain=0.985)
    twin.load_ohm = 9.5 / 4.0  # wants 5.05 A at 12 V: constant current, 9.5 V, reads 3.94 A
    db = tmp_path / "db.sqlite"
    assert _sweep(protocol, rig, db) == 1
    store = Store(db)
    run_id = store.resolve_run_id("last")
    assert store.steps(run_id) == []
    trip = store.events(run_id, "limit_trip")[0]["detail"]
    assert trip["measured_v"] == pytest.approx(9.5) and trip["current_a"] == pytest.approx(3.94)


def test_ctrl_c_before_the_first_voltage_point_never_switches_the_supply_on(tmp_path):
    """A first Ctrl-C during the opening tare: the run stops before any point, and the supply,
    found off, is sent no setting."""

    def read_then_ctrl_c(inner, *args):
        os.kill(os.getpid(), signal.SIGINT)
        return inner(*args)

    with ScpiSupplyTwin(setpoint_v=12.0) as twin:
        store, outcome = _run_with_supply(tmp_path, twin.pty_path, read_then_ctrl_c)
        assert outcome.status == "aborted" and "Ctrl-C" in outcome.reason
        assert store.steps(outcome.run_id) == [] and twin.history == [] and not twin.output
