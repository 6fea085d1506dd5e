"""The sensor's real rate, not the plan's: a Net F/T box at 1 kHz under a 500 Hz protocol is
averaged down to 500 Hz over the protocol's whole duration, an 80 Hz gauge acquires the
protocol's duration at 80 Hz, and a rate that cannot meet the protocol is refused before
the run starts. The rate stored with every point is the rate of its stored samples."""

from __future__ import annotations

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.clock import RealClock
from rigtool.devices.ascii_gauge import AsciiGauge
from rigtool.devices.depth import PresetDepth
from rigtool.devices.netft import NetFTSensor
from rigtool.engine import Engine, decimated
from rigtool.errors import DeviceError
from rigtool.plan import TimingRefused, expand, sensor_timing
from rigtool.protocol import load_protocol
from rigtool.rig import RigSet
from rigtool.sensor_rate import check_sensor_rate, fitted_rate_hz
from rigtool.sim.gauge_twin import GaugeTwin
from rigtool.sim.netft_twin import NetFTTwin
from rigtool.store import Store

from .test_netft import LiveActuator

PROTOCOL = """\
rigtool_protocol: 1
name: rate
command: {{unit: percent, values: [0, 50]}}
depth: {{unit: m, values: [1.0]}}
timing:
  settle: {settle}
  acquire: {acquire}
  tare: at_start
  tare_s: 0.2
limits: {{max_thrust_n: 90, max_staleness_s: 0.5}}
"""


def _protocol(write_yaml, acquire="{seconds: 1.0, rate_hz: 500}", settle="{seconds: 0.3}"):
    path = write_yaml(PROTOCOL.format(acquire=acquire, settle=settle))
    return load_protocol(path)[0], path


# -- the rule ----------------------------------------------------------------------------
def test_timing_per_case(write_yaml):
    protocol, _ = _protocol(write_yaml)  # 500 samples at 500 Hz: 1 s
    same = sensor_timing(protocol, None)
    assert (same.how, same.sensor_rate_hz, same.n_read, same.decimate) == ("as planned", 500, 500, 1)
    near = sensor_timing(protocol, 505.0)  # within 2 %: the protocol's count at the real rate
    assert (near.how, near.n_stored, near.stored_rate_hz) == ("as planned", 500, 505.0)
    off = sensor_timing(protocol, 1010.0)  # 1 % fast: stored at what was acquired, 505 Hz
    assert (off.how, off.decimate, off.n_stored, off.stored_rate_hz) == ("decimated", 2, 500, 505.0)
    fast = sensor_timing(protocol, 1000.0)
    assert (fast.how, fast.decimate, fast.n_read, fast.n_stored, fast.stored_rate_hz) == (
        "decimated", 2, 1000, 500, 500.0)
    slow = sensor_timing(protocol, 80.0)
    assert (slow.how, slow.n_read, slow.stored_rate_hz, slow.acquire_s) == ("duration", 80, 80.0, 1.0)
    odd = sensor_timing(protocol, 700.0)  # not a multiple: the duration at 700 Hz
    assert (odd.how, odd.n_read, odd.stored_rate_hz) == ("duration", 700, 700.0)
    with pytest.raises(TimingRefused) as exc:
        sensor_timing(protocol, 5.0)  # 5 samples in the protocol's second
    assert exc.value.field == ("timing", "acquire", "rate_hz") and "5 Hz" in str(exc.value)
    steady = "{until_steady: {window_s: 0.1, tolerance_n: 0.5, timeout_s: 5}}"
    protocol, _ = _protocol(write_yaml, acquire="{seconds: 3, rate_hz: 500}", settle=steady)
    with pytest.raises(TimingRefused) as exc:
        sensor_timing(protocol, 10.0)
    assert exc.value.field == ("timing", "settle", "until_steady", "window_s")


def test_decimation_averages_whole_groups():
    block = {"t_s": np.arange(6.0), "fx": np.array([1.0, 3, 5, 7, np.nan, 1]),
             "seq": np.arange(10, 16.0)}
    out = decimated(block, 2)
    assert out["t_s"].tolist() == [0.5, 2.5, 4.5] and out["fx"][:2].tolist() == [2.0, 6.0]
    assert np.isnan(out["fx"][2]) and out["seq"].tolist() == [11, 13, 15]


# -- over real transports ------------------------------------------------------------------
def _sweep(protocol, path, sensor, live, db_path):
    rigset = RigSet(actuator=LiveActuator(live), sensor=sensor, depth_stage=PresetDepth(),
                    clock=RealClock(), thrust_channel=0, thrust_sign=1)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    try:
        timing = check_sensor_rate(protocol, path, rigset)  # as the sweep does on opening
        outcome = Engine(protocol, expand(protocol), rigset, store, run_id).run()
    finally:
        rigset.close()
    assert outcome.status == "completed", outcome.reason
    return store, run_id, timing


def _acquired_s(store, run_id, step) -> float:
    got = store.samples(run_id, ["t_s", "step_id"])
    t = got["t_s"][got["step_id"] == step["id"]]
    return float(t[-1] - t[0]) + 1.0 / step["rate_hz"]


@pytest.mark.slow
@pytest.mark.parametrize("counts", [False, True], ids=["rate-from-xml", "rate-measured"])
def test_a_1khz_netft_under_a_500hz_protocol_is_averaged_over_the_whole_duration(
        live, write_yaml, db_path, counts):
    """The reproduction: before, each level was held 0.5 s (500 records at 1 kHz) and the
    points said 500 Hz. The box's rate comes from its netftapi2.xml, or is measured when
    the rig file gives the calibration counts (no XML read)."""
    box = NetFTTwin(live).start()
    try:
        host, port = box.address
        config = {"driver": "ati-netft", "host": host, "port": port, "http_port": box.http_port}
        if counts:
            config.update(counts_per_force=1_000_000, counts_per_torque=1_000_000)
        protocol, path = _protocol(write_yaml)
        store, run_id, timing = _sweep(protocol, path, NetFTSensor(config), live, db_path)
    finally:
        box.stop()
    assert timing.how == "decimated" and timing.decimate == 2
    for step in store.steps(run_id):
        assert step["rate_hz"] == pytest.approx(500.0, rel=0.02) and step["n"] == 500
        assert step["rate_hz"] == timing.stored_rate_hz
        assert _acquired_s(store, run_id, step) == pytest.approx(1.0, abs=0.05)
        assert step["t_end_s"] - step["t_acquire_s"] >= 0.95
    event = store.events(run_id, "sensor_rate")[0]["detail"]
    assert event["how"] == "decimated" and event["sensor_rate_hz"] == pytest.approx(1000, rel=0.02)


def _twin_box(live, xml_rate: str | None, monkeypatch) -> NetFTTwin:
    """A Net F/T twin streaming at the live twin's rate whose XML states `xml_rate`."""
    if xml_rate is not None:
        stated = NetFTTwin.netftapi2_xml
        monkeypatch.setattr(NetFTTwin, "netftapi2_xml", lambda self: stated(self).replace(
            f"<comrdtrate>{self.live.rate_hz:g}</comrdtrate>", f"<comrdtrate>{xml_rate}</comrdtrate>"))
    return NetFTTwin(live).start()


@pytest.mark.slow
@pytest.mark.parametrize("live_hz, xml_rate, stored_hz, note", [
    (1000.0, "500", 500.0, True),  # the XML is wrong: the measured 1 kHz is averaged 2 to 1
    (1010.0, None, 505.0, False),  # 1 % fast and says so: stored at 505 Hz, as acquired
    (990.0, None, 495.0, False),
])
def test_a_netft_rate_is_checked_and_stored_as_acquired(live_hz, xml_rate, stored_hz, note,
                                                        write_yaml, db_path, monkeypatch):
    """Before: the XML's rate was trusted (500 stated, 1 kHz streamed: each point 0.5 s)
    and a box 1 % off stored its points at the protocol's 500 Hz."""
    from rigtool.sim.live import LiveTwin
    from rigtool.sim.physics import ThrusterTwin
    from rigtool.thruster_profiles import PROFILES

    live = LiveTwin(ThrusterTwin(PROFILES["can-bldc"], seed=1), rate_hz=live_hz).start()
    box = _twin_box(live, xml_rate, monkeypatch)
    try:
        host, port = box.address
        config = {"driver": "ati-netft", "host": host, "port": port, "http_port": box.http_port}
        protocol, path = _protocol(write_yaml)
        store, run_id, timing = _sweep(protocol, path, NetFTSensor(config), live, db_path)
    finally:
        box.stop()
        live.stop()
    assert timing.decimate == 2
    event = store.events(run_id, "sensor_rate")[0]["detail"]
    assert event["sensor_rate_hz"] == pytest.approx(live_hz, rel=0.01)
    for step in store.steps(run_id):
        assert step["rate_hz"] == pytest.approx(stored_hz, rel=0.005) and step["n"] == 500
        assert _acquired_s(store, run_id, step) == pytest.approx(500 / stored_hz, abs=0.05)
    warned = [e["detail"]["message"] for e in store.events(run_id, "warning")]
    assert any("states 500 Hz but streams at" in m for m in warned) == note


def _late_arrivals(pattern: str, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    """Arrival times of 0.5 s of a stream at `rate_hz` (plus a backlog), delayed as
    `pattern` says; a sample never arrives before it is sent."""
    n = int(1.5 * rate_hz)
    sent = np.arange(n) / rate_hz
    arrived = sent + rng.exponential(50e-6, n)  # network and kernel latency
    if pattern == "backlog":  # 60 % of the samples queued before the probe read them at once
        arrived[: int(0.6 * n)] = arrived[int(0.6 * n)]
    elif pattern == "sender-stalls":  # a busy sender stops for 5-20 ms, then catches up
        for start in np.r_[0.0, rng.uniform(0, sent[-1], 11)]:
            stalled = (sent >= start) & (sent < start + rng.uniform(5e-3, 20e-3))
            arrived[stalled] = np.maximum(arrived[stalled], start + 20e-3)
    elif pattern == "frames":  # a USB frame of 16 samples arrives after its last one
        arrived = np.repeat(arrived[15::16], 16)[:n]
    return np.maximum.accumulate(arrived)


@pytest.mark.parametrize("pattern", ["jitter", "backlog", "sender-stalls", "frames"])
@pytest.mark.parametrize("rate_hz", [80.0, 1000.0, 7000.0])
def test_the_measured_rate_ignores_late_samples(pattern, rate_hz):
    """Before: a least-squares line through the arrival times read a 1 kHz twin box whose
    sender a loaded machine delayed at 1008.8 Hz, and a backlog read at once as 1966 Hz."""
    for seed in range(5):
        arrived = _late_arrivals(pattern, rate_hz, np.random.default_rng(seed))
        assert fitted_rate_hz(arrived) == pytest.approx(rate_hz, rel=2e-3)


@pytest.mark.parametrize("rate", ["nan", "inf", "-5", "0", "1e9"])
def test_a_hostile_rdt_rate_is_a_clear_error(rate, live):
    """comrdtrate nan/inf was a traceback, 1e9 a 2,000,000:1 decimation that hung the run."""
    from rigtool.devices.netft import parse_netftapi2

    box = NetFTTwin(live)
    xml = box.netftapi2_xml().replace(f"<comrdtrate>{live.rate_hz:g}</comrdtrate>",
                                      f"<comrdtrate>{rate}</comrdtrate>")
    with pytest.raises(DeviceError, match=f"comrdtrate '{rate}' is not a usable RDT rate"):
        parse_netftapi2(xml, "http://box/netftapi2.xml")


@pytest.mark.slow
def test_an_80hz_gauge_under_a_500hz_protocol_acquires_the_protocols_duration(
        live, write_yaml, db_path):
    """Before, 500 lines at 80 Hz held each level 6.25 s and the points said 500 Hz."""
    twin = GaugeTwin(live, "hx711-csv", rate_hz=80, scale=0.001, offset=8000).start()
    try:
        sensor = AsciiGauge({"driver": "ascii-gauge", "url": twin.port, "preset": "hx711-csv",
                             "scale": 0.001, "offset": 8000})
        protocol, path = _protocol(write_yaml)
        store, run_id, timing = _sweep(protocol, path, sensor, live, db_path)
    finally:
        twin.stop()
    assert timing.how == "duration" and timing.sensor_rate_hz == pytest.approx(80, rel=0.05)
    for step in store.steps(run_id):
        assert step["rate_hz"] == pytest.approx(80, rel=0.05) and step["n"] == timing.n_read
        assert 76 <= step["n"] <= 84
        assert _acquired_s(store, run_id, step) == pytest.approx(1.0, abs=0.1)


RIG = """\
rigtool_rig: 1
name: slow-gauge
actuator: {{driver: stm32-bridge, url: '{url}', timeout_s: 0.5}}
sensor: {{driver: ascii-gauge, url: '{port}', preset: hx711-csv, scale: 0.001, offset: 8000}}
"""

CLI_PROTOCOL = """\
rigtool_protocol: 1
name: too-fast
command: {unit: pwm_counts, values: [0, 300]}
depth: {unit: cm, values: [30]}
timing:
  settle: {seconds: 0.2}
  acquire: {samples: 250, rate_hz: 500}
limits: {max_thrust_n: 20}
"""


@pytest.mark.slow
def test_a_rate_that_cannot_meet_the_protocol_is_refused_before_the_run(tmp_path, capsys):
    """A 10 Hz gauge and half a second per point: 5 samples. Exit 2, naming the rig's rate
    and the protocol's field, and no run is created; the actuator never left neutral."""
    from rigtool.sim.live import LiveTwin
    from rigtool.sim.physics import ThrusterTwin
    from rigtool.sim.stm32_twin import Stm32BridgeTwin
    from rigtool.thruster_profiles import PROFILES

    live = LiveTwin(ThrusterTwin(PROFILES["stm32-pwm"], seed=5)).start()
    fw = Stm32BridgeTwin(live).start()
    gauge = GaugeTwin(live, "hx711-csv", rate_hz=10, scale=0.001, offset=8000).start()
    try:
        rig = tmp_path / "rig.yaml"
        rig.write_text(RIG.format(url=fw.url, port=gauge.port))
        protocol = tmp_path / "p.yaml"
        protocol.write_text(CLI_PROTOCOL)
        db = tmp_path / "db.sqlite"
        assert main(["sweep", str(protocol), "--rig", str(rig), "--db", str(db)]) == 2
        err = capsys.readouterr().err
        assert f"{protocol}:7" in err and "timing.acquire.rate_hz" in err
        assert "streams at 10" in err or "streams at 9.9" in err
        assert not db.exists() or Store(db).runs() == []
        assert fw.ccr[fw.thruster_channel] == fw.neutral_ccr
        assert main(["sweep", str(protocol), "--rig", str(rig), "--dry-run"]) == 0
        assert "measured over 0.5 s when it opens" in capsys.readouterr().out
    finally:
        for part in (gauge, fw, live):
            part.stop()


def test_dry_run_shows_the_timing_used_on_the_twin(write_yaml, capsys):
    from .conftest import SMALL_PROTOCOL

    assert main(["sweep", str(write_yaml(SMALL_PROTOCOL)), "--sim", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "sensor timing: 200 samples at 500 Hz (0.4 s) per point (the twin samples" in out


@pytest.mark.parametrize("counts", [False, True], ids=["rate-from-xml", "rate-measured"])
def test_records_lost_while_the_reader_is_held_up_do_not_lower_the_measured_rate(live, counts):
    """Issue 49: an attacked in-process watch server held the probe's reader up, records
    were lost, and a 7 kHz box was measured at 4.3-5.7 kHz. The probe now counts the box's
    own rdt_sequence numbers: a third of the records lost (seeded) still reads the box's rate."""
    from rigtool.sensor_rate import native_rate_hz
    from rigtool.sim.netft_twin import NetFTFaults

    box = NetFTTwin(live, faults=NetFTFaults(drop=0.3), seed=49).start()
    try:
        host, port = box.address
        config = {"driver": "ati-netft", "host": host, "port": port, "http_port": box.http_port}
        if counts:
            config.update(counts_per_force=1_000_000, counts_per_torque=1_000_000)
        sensor = NetFTSensor(config)
        try:
            rate, note = native_rate_hz(sensor, 500.0)
            lost = sensor.stats["lost_packets"]
        finally:
            sensor.close()
    finally:
        box.stop()
    assert lost > 100  # the records really were lost
    assert note is None
    assert rate == pytest.approx(live.rate_hz, rel=0.01)
