"""ATI Net F/T driver against its twin over loopback UDP and HTTP, plus the pure pieces.

The twin streams real-time LiveTwin samples, so assertions are on ranges and counts.
"""

from __future__ import annotations

import contextlib
import socket
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from rigtool.clock import RealClock
from rigtool.devices import mmsg
from rigtool.devices.base import ActuatorInfo, FeedbackBlock, ForceSensor
from rigtool.devices.depth import PresetDepth
from rigtool.devices.netft import (
    CMD_STOP,
    RECORD,
    NetFTConfig,
    NetFTSensor,
    pack_request,
    parse_netftapi2,
)
from rigtool.engine import Engine
from rigtool.errors import DeviceError
from rigtool.plan import expand
from rigtool.protocol import load_protocol
from rigtool.rig import RigSet
from rigtool.sim.live import LiveTwin
from rigtool.sim.netft_twin import NetFTFaults, NetFTTwin
from rigtool.store import Store
from rigtool.thruster_profiles import PROFILES
from rigtool.units import FORCE_UNITS_N, unit_factor

from .conftest import ROOT
from .helpers import wait_for

BIAS_N = PROFILES["can-bldc"].bias_n  # the twin's offset on fx at zero thrust
NOISE_N = PROFILES["can-bldc"].force_noise_n


@pytest.fixture
def box(live):
    """A started NetFTTwin on an ephemeral loopback port; stopped after the test."""
    started = []

    def _make(**kwargs) -> NetFTTwin:
        twin = NetFTTwin(live, **kwargs).start()
        started.append(twin)
        return twin

    yield _make
    for twin in started:
        twin.stop()


def sensor_for(twin: NetFTTwin, **overrides) -> NetFTSensor:
    host, port = twin.address
    config = {"driver": "ati-netft", "host": host, "port": port, **overrides}
    if twin.http_port is not None:
        config.setdefault("http_port", twin.http_port)
    return NetFTSensor(config)


# -- pure pieces ------------------------------------------------------------------------
def test_request_and_record_layout():
    assert pack_request(0x0002, 0) == bytes.fromhex("1234000200000000")
    assert pack_request(0x0042) == bytes.fromhex("1234004200000000")
    assert RECORD.size == 36
    rec = RECORD.pack(7, 9, 0, -1, 2, 3, 4, 5, -6)
    assert RECORD.unpack(rec) == (7, 9, 0, -1, 2, 3, 4, 5, -6)


def test_calibration_from_xml_converts_box_units_to_si():
    xml = ("<netft><cfgcpf>1000000</cfgcpf><cfgcpt>1000</cfgcpt><scfgfu>lbf</scfgfu>"
           "<scfgtu>lbf-in</scfgtu><comrdtrate>7000</comrdtrate></netft>")
    cal = parse_netftapi2(xml)
    assert cal.counts_per_n == pytest.approx(1e6 / 4.4482216152605)
    assert cal.counts_per_nm == pytest.approx(1e3 / 0.1129848290276167)
    assert cal.rate_hz == 7000
    cal = parse_netftapi2("<netft><cfgcpf>1e6</cfgcpf><cfgcpt>1e6</cfgcpt><scfgfu>kN</scfgfu>"
                          "<scfgtu>N-mm</scfgtu></netft>")
    assert (cal.counts_per_n, cal.counts_per_nm) == pytest.approx((1e3, 1e9))


@pytest.mark.parametrize("xml, fragment", [
    ("<netft><cfgcpf>1</cfgcpf></netft>", "no cfgcpt, scfgfu, scfgtu"),
    ("<netft><cfgcpf>1</cfgcpf><cfgcpt>1</cfgcpt><scfgfu>furlong</scfgfu>"
     "<scfgtu>N-m</scfgtu></netft>", "unknown force unit 'furlong'"),
    ("not xml at all", "not valid XML"),
])
def test_bad_calibration_pages_are_named(xml, fragment):
    with pytest.raises(DeviceError, match=fragment):
        parse_netftapi2(xml, "http://box/netftapi2.xml")


def test_unit_names_are_forgiving():
    assert unit_factor("lbF", FORCE_UNITS_N, "force") == pytest.approx(4.4482216152605)
    assert unit_factor(" N ", FORCE_UNITS_N, "force") == 1.0


@pytest.mark.parametrize("fields, fragment", [
    ({"counts_per_force": 1e6}, "give both counts_per_force and counts_per_torque"),
    ({"force_unit": "stone"}, "unknown force unit"),
    ({"port": 70000}, "less than or equal to 65535"),
    ({"on_status": "ignore"}, "'fault' or 'warn'"),
    ({"colour": "red"}, "Extra inputs"),
])
def test_config_errors(fields, fragment):
    with pytest.raises(ValidationError, match=fragment):
        NetFTConfig.model_validate({"driver": "ati-netft", "host": "192.168.1.1", **fields})


def test_example_rig_file_is_valid():
    rig = yaml.safe_load((ROOT / "protocols" / "rigs" / "netft-example.yaml").read_text())
    cfg = NetFTConfig.model_validate(rig["sensor"])
    assert (cfg.port, cfg.counts_per_force, cfg.on_status) == (49152, None, "fault")


# -- over loopback UDP ------------------------------------------------------------------
@pytest.mark.slow
def test_reads_newtons_from_box_with_non_si_calibration(live, box):
    twin = box(force_unit="lbf", torque_unit="lbf-in", counts_per_force=1e6, counts_per_torque=1e6)
    with sensor_for(twin) as sensor:
        assert isinstance(sensor, ForceSensor)
        assert sensor.calibration.source.endswith("/netftapi2.xml")
        assert sensor.calibration.rate_hz == live.rate_hz
        block = sensor.read(300, 1000)
        assert block.ft.shape == (300, 6)
        assert np.all(np.diff(block.seq) > 0) and np.all(np.diff(block.t_s) >= 0)
        assert abs(block.ft[:, 0].mean() - BIAS_N) < 0.1
        assert np.all(np.abs(block.ft[:, 1:3]) < 6 * NOISE_N)
        live.set_command(50)
        time.sleep(1.5)  # tau 0.3 s: settled
        _, thrust_n, _ = live.twin.steady_state(50)
        fx = sensor.read(500, 1000).ft[:, 0]
        assert abs(fx.mean() - (thrust_n + BIAS_N)) < 0.4
    # The stop datagram is handled on the twin's own thread: give it time under load.
    assert wait_for(lambda: twin.stats.stops == 1 and not twin.streaming)


@pytest.mark.slow
def test_configured_counts_skip_http(box):
    twin = box(http_port=None, force_unit="kN", counts_per_force=1e6)
    sensor = sensor_for(twin, counts_per_force=1e6, counts_per_torque=1e6, force_unit="kN")
    try:
        assert sensor.calibration.source == "config"
        assert abs(sensor.read(200, 1000).ft[:, 0].mean() - BIAS_N) < 0.1
    finally:
        sensor.close()
        sensor.close()  # idempotent


@pytest.mark.slow
def test_rate_is_the_boxs_not_the_callers(box):
    with sensor_for(box()) as sensor:
        t0 = time.monotonic()
        block = sensor.read(500, 10.0)  # 50 s at the advisory rate; 0.5 s at the box's 1 kHz
        assert time.monotonic() - t0 < 2.0
        assert 0.3 < block.t_s[-1] - block.t_s[0] < 1.0


@pytest.mark.skipif(sys.platform != "linux", reason="kernel arrival stamps are read on Linux")
def test_batched_receiver_keeps_each_records_own_arrival_time(box):
    """The receiver wakes every RECEIVE_BATCH_S, not per datagram, yet every datagram keeps the
    kernel's stamp of its own arrival, not the time the receiver woke to take it."""
    with sensor_for(box()) as sensor:
        assert sensor._batched and sensor._batch_s > 0
        before = time.monotonic()
        block = sensor.read(1000, 1000.0)
        after = time.monotonic()
    dt = np.diff(block.t_s)
    assert np.all(dt >= 0) and before - 0.5 < block.t_s[0] and block.t_s[-1] <= after
    assert np.mean(dt == 0) < 0.05  # stamps taken at wake-up would repeat for a whole batch
    assert 0.8 < block.t_s[-1] - block.t_s[0] < 1.3  # the box's 1 kHz


@pytest.mark.skipif(sys.platform != "linux", reason="kernel arrival stamps are read on Linux")
def test_batched_receiver_without_recvmmsg_takes_datagrams_one_call_each(box, monkeypatch):
    """Where recvmmsg is missing (32-bit Linux), the batched receiver reads the queue with
    one recvmsg per datagram and the same checks."""
    monkeypatch.setattr(mmsg, "available", lambda: False)
    with sensor_for(box(faults=NetFTFaults(garbage=0.05, oversized=0.05))) as sensor:
        assert sensor._batched and sensor._multi is None
        block = sensor.read(500, 1000.0)
        stats = sensor.stats
    assert np.all(np.diff(block.seq) > 0) and np.mean(np.diff(block.t_s) == 0) < 0.05
    assert stats["bad_size"] > 0 and stats["records"] >= 500


def test_receiver_on_another_clock_wakes_per_datagram_and_stamps_with_that_clock(box):
    """No kernel stamps where the driver's clock is not the monotonic one (a test's clock,
    or an OS without them): each datagram is timed by the driver's clock as it is taken."""
    twin = box(faults=NetFTFaults(garbage=0.05, oversized=0.05))
    host, port = twin.address
    config = {"driver": "ati-netft", "host": host, "port": port, "http_port": twin.http_port}
    with NetFTSensor(config, now=lambda: time.monotonic() + 1000.0) as sensor:
        assert not sensor._batched
        block = sensor.read(300, 1000.0)
        stats = sensor.stats
    assert len(block.t_s) == 300 and np.all(np.diff(block.t_s) >= 0)
    assert block.t_s[0] > time.monotonic() + 900.0
    assert stats["bad_size"] > 0 and stats["records"] >= 300


def test_receiver_without_kernel_stamps_falls_back_to_per_datagram_times(box):
    with sensor_for(box()) as sensor:
        before = time.monotonic()
        t = sensor._arrival([], 0.0)
        assert sensor._batch_s == 0.0 and before <= t <= time.monotonic()
        assert len(sensor.read(200, 1000.0).t_s) == 200


@contextlib.contextmanager
def scripted_box(send: Callable[[Callable[[bytes], object]], None]):
    """A hand-written box on loopback UDP: after the start request, `send(sendto)` sends
    its datagrams from a thread. Yields (sensor config with counts, no HTTP; the thread)."""
    box = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    box.bind(("127.0.0.1", 0))
    box.settimeout(2.0)

    def serve() -> None:
        _, host = box.recvfrom(64)  # the start request
        send(lambda data: box.sendto(data, host))

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    try:
        yield ({"driver": "ati-netft", "host": "127.0.0.1", "port": box.getsockname()[1],
                "counts_per_force": 100.0, "counts_per_torque": 100.0}, server)
    finally:
        server.join(5.0)
        box.close()


def test_buffered_datagrams_mixed_with_single_records_and_oversized_ones():
    """A box in buffered mode sends several records per datagram: each record is kept, in
    order, whether it shares a receive with single-record datagrams or with one too long
    to be RDT (counted as a bad size, not a crash)."""
    def send(sendto) -> None:
        seq = 1
        for k in range(60):
            per = (1, 2, 1, 3, 1, 1, 40)[k % 7]
            sendto(b"".join(RECORD.pack(seq + i, seq + i, 0, 100 * (seq + i), 0, 0, 0, 0, 0)
                            for i in range(per)))
            seq += per
            if k % 10 == 5:
                sendto(b"\0" * 5000)
            time.sleep(0.002 if k % 20 else 0.05)

    with scripted_box(send) as (config, server), NetFTSensor(config) as sensor:
        block = sensor.read(300, 1000.0)
        server.join(5.0)
        time.sleep(0.1)  # for the receiver to take the last datagrams
        stats = sensor.stats
    assert np.all(np.diff(block.seq) == 1) and block.seq[0] <= 41  # the first read drops
    # what came before it (here the first datagram or two)
    np.testing.assert_allclose(block.ft[:, 0], block.seq)  # 100 counts per N
    assert stats["bad_size"] == 6 and stats["records"] == 399  # all sent: 8 * 49 + 7


def test_sequence_wrapping_past_2_32_with_gaps_is_counted_not_rejected():
    """rdt_sequence is 32-bit: across its wrap to 0 the stream goes on, and the two records
    skipped (one each side of the wrap) are counted as lost packets."""
    seqs = [q % (1 << 32) for q in range((1 << 32) - 60, (1 << 32) + 60)
            if q not in ((1 << 32) - 10, (1 << 32) + 3)]

    def send(sendto) -> None:
        for i, q in enumerate(seqs):
            sendto(RECORD.pack(q, q, 0, 100, 0, 0, 0, 0, 0))
            time.sleep(0.0005 if i % 30 else 0.05)

    with scripted_box(send) as (config, _), NetFTSensor(config) as sensor:
        sensor.read(5, 1000.0)  # the first read drops what came before it (up to a burst)
        block = sensor.read(60, 1000.0)
        stats = sensor.stats
    first = seqs.index(int(block.seq[0]))
    assert block.seq.tolist() == seqs[first:first + 60]
    assert block.seq[0] < (1 << 32) - 10 and block.seq[-1] > 3
    assert stats["lost_packets"] == 2 and stats["bad_sequence"] == 0


@pytest.mark.slow
def test_lost_reordered_and_malformed_datagrams_are_counted_and_kept_out(box):
    faults = NetFTFaults(drop=0.1, reorder=0.05, garbage=0.05, short=0.02, oversized=0.02,
                         bad_header=0.02, duplicate=0.02)
    twin = box(faults=faults, seed=3)
    with sensor_for(twin) as sensor:
        block = sensor.read(2000, 1000)
        s = sensor.stats
    assert np.all(np.diff(block.seq) > 0)  # late and duplicate packets never reach the caller
    assert np.all(np.abs(block.ft[:, 0] - BIAS_N) < 8 * NOISE_N)  # no corrupt values
    assert np.all(np.abs(block.ft[:, 3:]) < 1.0)
    gaps = int(np.sum(np.diff(block.seq) - 1))
    assert 0.08 < gaps / (block.seq[-1] - block.seq[0]) < 0.25  # drops + reorders + corrupt
    assert s["lost_packets"] >= gaps
    assert s["out_of_order"] + s["reordered"] > 10  # overtaken: late, or kept in place
    assert s["duplicates"] > 10
    assert s["bad_size"] > 50  # short, oversized and most garbage
    assert s["bad_sequence"] > 5  # bad_header records (and 36-byte garbage) rejected


@pytest.mark.slow
@pytest.mark.parametrize("on_status", ["fault", "warn"])
def test_status_word(box, on_status):
    twin = box()
    with sensor_for(twin, on_status=on_status) as sensor:
        sensor.read(50, 1000)
        twin.faults.status = 0x80010000
        time.sleep(0.1)
        if on_status == "fault":
            with pytest.raises(DeviceError, match=r"status word 0x80010000 on \d+ of 400 samples"):
                sensor.read(400, 1000)
        else:
            assert len(sensor.read(400, 1000)) == 400
            assert any("0x80010000" in w for w in sensor.pop_warnings())
            assert sensor.pop_warnings() == []
        assert sensor.stats["status_records"] > 0
        assert sensor.stats["last_status"] == 0x80010000


@pytest.mark.slow
def test_silent_box_is_a_fault_naming_the_box(box):
    twin = box()
    with sensor_for(twin, timeout_s=0.6) as sensor:
        sensor.read(50, 1000)
        twin.faults.silent = True
        t0 = time.monotonic()
        with pytest.raises(DeviceError, match=r"Net F/T at 127\.0\.0\.1:\d+: no RDT data for"):
            sensor.read(5000, 1000)
        assert 0.5 < time.monotonic() - t0 < 2.0
        assert sensor.stats["restarts"] == 1


@pytest.mark.slow
def test_stream_stopped_by_someone_else_is_restarted(box):
    twin = box()
    with sensor_for(twin, timeout_s=0.6) as sensor:
        sensor.read(50, 1000)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.sendto(pack_request(CMD_STOP), twin.address)
        time.sleep(0.1)
        assert not twin.streaming
        assert len(sensor.read(500, 1000)) == 500
        assert sensor.stats["restarts"] == 1
        assert any("sent a new start request" in w for w in sensor.pop_warnings())


@pytest.mark.slow
def test_finite_sample_count_is_re_requested(box):
    twin = box()
    with sensor_for(twin, sample_count=100) as sensor:
        block = sensor.read(450, 1000)
        assert len(block) == 450
        assert sensor.stats["restarts"] == 0
    assert twin.stats.starts >= 5


@pytest.mark.slow
def test_nothing_listening_fails_at_open_naming_host_and_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    with pytest.raises(DeviceError, match=rf"Net F/T at 127\.0\.0\.1:{port}: no RDT data within"):
        NetFTSensor({"driver": "ati-netft", "host": "127.0.0.1", "port": port, "timeout_s": 0.3,
                     "counts_per_force": 1e6, "counts_per_torque": 1e6})
    assert time.monotonic() - t0 < 1.5


def test_unreachable_calibration_page_is_named():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DeviceError, match=rf"http://127\.0\.0\.1:{port}/netftapi2\.xml"):
        NetFTSensor({"driver": "ati-netft", "host": "127.0.0.1", "http_port": port,
                     "timeout_s": 0.3})


@pytest.mark.slow
def test_host_bias_accumulates_like_the_engine_expects(box):
    with sensor_for(box()) as sensor:
        offset = sensor.read(300, 1000).ft.mean(axis=0)
        sensor.set_bias(offset)
        after = sensor.read(300, 1000).ft.mean(axis=0)
        assert np.all(np.abs(after) < 0.05)
        sensor.set_bias(after)  # a second tare refines the first
        assert abs(sensor.read(300, 1000).ft[:, 0].mean()) < 0.05
        with pytest.raises(ValueError, match="6 finite numbers"):
            sensor.set_bias([1.0, 2.0])


@pytest.mark.slow
def test_device_bias_zeroes_the_box(box):
    twin = box()
    with sensor_for(twin, bias="device") as sensor:
        assert abs(sensor.read(200, 1000).ft[:, 0].mean() - BIAS_N) < 0.1
        sensor.set_bias(np.full(6, 123.0))  # values ignored: the box zeroes itself
        time.sleep(0.05)
        fx = sensor.read(300, 1000).ft[:, 0]
        assert twin.stats.biases == 1
        assert abs(fx.mean()) < 5 * NOISE_N  # zeroed on one noisy sample, not an average


@pytest.mark.slow
def test_samples_from_a_pause_are_dropped(box):
    with sensor_for(box(), max_gap_s=0.2) as sensor:
        sensor.read(100, 1000)
        time.sleep(0.6)  # e.g. the engine ramping the command without reading
        t_call = time.monotonic()
        block = sensor.read(100, 1000)
        assert block.t_s[0] >= t_call  # also those the receiver took only after the call
        assert sensor.stats["stale"] > 300
        # back-to-back reads stay contiguous: nothing missing between blocks
        nxt = sensor.read(100, 1000)
        assert nxt.seq[0] == block.seq[-1] + 1


@pytest.mark.slow
def test_read_from_another_thread_sees_receiver_failure(box):
    """Closing the socket under a waiting reader ends its wait with an error, not a hang."""
    twin = box()
    sensor = sensor_for(twin)
    twin.faults.silent = True
    errors: list[BaseException] = []

    def reader():
        try:
            sensor.read(10_000, 1000)
        except BaseException as exc:  # noqa: BLE001 - recorded for the assertion
            errors.append(exc)

    th = threading.Thread(target=reader)
    th.start()
    time.sleep(0.2)
    sensor.close()
    th.join(timeout=3.0)
    assert not th.is_alive()
    assert errors and isinstance(errors[0], DeviceError)


class LiveActuator:
    """The LiveTwin's motor driver, in process: the engine's commands reach the physics."""

    def __init__(self, live: LiveTwin) -> None:
        p = live.twin.profile
        self.live = live
        self.info = ActuatorInfo(p.command_unit, p.neutral, p.command_min, p.command_max)

    def set_command(self, value: float) -> None:
        self.live.set_command(value)

    def neutral(self) -> None:
        self.live.set_command(self.info.neutral)

    def read_feedback(self) -> FeedbackBlock:
        return FeedbackBlock(np.empty(0))

    def close(self) -> None:
        return None


ENGINE_PROTOCOL = """\
rigtool_protocol: 1
name: netft-engine
command: {unit: percent, values: [0, 50]}
depth: {unit: m, values: [1.0]}
timing:
  settle: {seconds: 1.2}
  acquire: {samples: 300, rate_hz: 1000}
  rest_s: 0.1
  tare: at_start
  tare_s: 0.2
limits: {max_thrust_n: 90, max_staleness_s: 0.5}
"""


@pytest.mark.slow
def test_engine_sweeps_with_the_driver_on_a_real_clock(live, box, write_yaml, db_path):
    protocol, _ = load_protocol(write_yaml(ENGINE_PROTOCOL))
    plan = expand(protocol)
    sensor = sensor_for(box(force_unit="lbf", torque_unit="lbf-in"))
    rigset = RigSet(actuator=LiveActuator(live), sensor=sensor, depth_stage=PresetDepth(),
                    clock=RealClock(), thrust_channel=0, thrust_sign=1)
    store = Store(db_path)
    run_id = store.create_run(name="t", protocol={}, protocol_path=None, rig={}, plan=[],
                              metadata={}, seed=1, command_unit="percent", tool_version="test")
    try:
        outcome = Engine(protocol, plan, rigset, store, run_id).run()
    finally:
        rigset.close()
    assert outcome.status == "completed", outcome.reason
    steps = store.steps(run_id)
    assert [s["n"] for s in steps] == [300, 300]
    assert abs(steps[0]["thrust_all_mean_n"]) < 0.1  # tared at neutral: the 3 N offset is gone
    _, thrust_n, _ = live.twin.steady_state(50)
    assert abs(steps[1]["thrust_all_mean_n"] - thrust_n) < 0.4
    t = store.samples(run_id, ["t_s"])["t_s"]
    assert np.all(np.diff(t) >= 0) and 0 < t[0] < t[-1] < 10  # run clock: monotonic arrival
