"""Serial ASCII force gauge driver against its pty twin, plus line parsing and config checks.

The twin reads a real-time LiveTwin, so assertions are on ranges and counts.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from pydantic import ValidationError

from rigtool.devices.ascii_gauge import AsciiGauge, AsciiGaugeConfig, LineParser
from rigtool.devices.base import ForceSensor
from rigtool.errors import DeviceError
from rigtool.sim.gauge_twin import GaugeTwin
from rigtool.thruster_profiles import PROFILES

LBF_N = 4.4482216152605
BIAS_N = PROFILES["can-bldc"].bias_n
NOISE_N = PROFILES["can-bldc"].force_noise_n


@pytest.fixture
def gauge_twin(live):
    started = []

    def _make(preset="mark10", **kwargs) -> GaugeTwin:
        twin = GaugeTwin(live, preset, **kwargs).start()
        started.append(twin)
        return twin

    yield _make
    for twin in started:
        twin.stop()


def config(**fields) -> AsciiGaugeConfig:
    return AsciiGaugeConfig.model_validate({"driver": "ascii-gauge", "url": "loop://", **fields})


def parser(**fields) -> LineParser:
    return LineParser(config(**fields))


# -- pure pieces ------------------------------------------------------------------------
def test_mark10_lines():
    p = parser(preset="mark10")
    assert p("-18.78 lbF") == (None, pytest.approx(-18.78 * LBF_N))
    assert p("  2.5 N\r") == (None, pytest.approx(2.5))
    assert p("1200 gF") == (None, pytest.approx(1.2 * 9.80665))
    assert p("0.35 kgF") == (None, pytest.approx(0.35 * 9.80665))
    for junk in ("", "lbF", "OVERLOAD", "-18.78 lbF extra", "-18.78 parsecs", "1.2.3 N"):
        assert p(junk) is None
    assert parser(preset="mark10", unit="N")("4.5") == (None, pytest.approx(4.5))
    assert parser(preset="mark10")("4.5") is None  # no unit on the line, none configured


def test_hx711_lines_scale_offset_sign():
    p = parser(preset="hx711-csv", scale=0.002, offset=1000, sign=-1)
    assert p("123456,1500") == (123456, pytest.approx(-1.0))
    assert p("77;1000.0") == (77, pytest.approx(0.0))
    assert parser(preset="hx711-csv", unit="gf")("10,250") == (10, pytest.approx(0.25 * 9.80665))
    for junk in ("123456", "abc,12", "12,", ",12"):
        assert p(junk) is None


def test_custom_pattern():
    p = parser(mode="stream", pattern=r"F=(?P<value>\S+)\s*(?P<unit>\w+)")
    assert p("F=3.0 kN") == (None, pytest.approx(3000.0))
    assert p("F=nan N") is None


@pytest.mark.parametrize("fields, fragment", [
    ({"mode": "poll", "pattern": "(?P<value>.*)", "unit": "N"}, "needs a `query`"),
    ({"mode": "stream", "pattern": "(?P<value>[0-9", "unit": "N"}, "not a valid regular"),
    ({"mode": "stream", "pattern": "([0-9]+)", "unit": "N"}, "named group `value`"),
    ({"mode": "stream", "pattern": "(?P<value>[0-9]+)"}, "give the `unit`"),
    ({"preset": "mark10", "unit": "furlong"}, "unknown force unit"),
    ({"pattern": "(?P<value>.*)", "unit": "N"}, "mode: poll"),
    ({"preset": "mark10", "channel": "tx"}, "'fx', 'fy' or 'fz'"),
    ({"preset": "hx711-csv", "scale": 0}, "non-zero"),
    ({"preset": "hx711"}, "'mark10' or 'hx711-csv'"),
])
def test_config_errors(fields, fragment):
    with pytest.raises(ValidationError, match=fragment):
        config(**fields)


def test_preset_fills_only_what_is_not_given():
    cfg = config(preset="mark10", query="!\r", unit="N")
    assert (cfg.mode, cfg.query, cfg.unit) == ("poll", "!\r", "N")


# -- over a pseudo-terminal -------------------------------------------------------------
@pytest.mark.slow
def test_mark10_polled_over_pty(live, gauge_twin):
    twin = gauge_twin("mark10", unit="lbF")
    with AsciiGauge({"driver": "ascii-gauge", "url": twin.port, "preset": "mark10"}) as gauge:
        assert isinstance(gauge, ForceSensor)
        block = gauge.read(30, 1000)
        assert block.ft.shape == (30, 6)
        assert np.all(np.isnan(block.ft[:, 1:]))
        assert abs(block.ft[:, 0].mean() - BIAS_N) < 4 * NOISE_N
        assert np.all(np.diff(block.seq) == 1) and np.all(np.diff(block.t_s) > 0)
        live.set_command(50)
        time.sleep(1.5)
        _, thrust_n, _ = live.twin.steady_state(50)
        fx = gauge.read(30, 1000).ft[:, 0]
        assert abs(fx.mean() - (thrust_n + BIAS_N)) < 0.5
        assert np.all(np.abs(np.round(fx / LBF_N, 2) - fx / LBF_N) < 1e-9)  # 0.01 lbF steps
    assert twin.stats["queries"] >= 61


@pytest.mark.slow
def test_poll_rate_is_honoured_when_the_gauge_keeps_up(gauge_twin):
    twin = gauge_twin("mark10")
    with AsciiGauge({"driver": "ascii-gauge", "url": twin.port, "preset": "mark10"}) as gauge:
        t0 = time.monotonic()
        block = gauge.read(10, 20.0)
        assert 0.4 < time.monotonic() - t0 < 1.0
        assert 0.4 < block.t_s[-1] - block.t_s[0] < 0.7


@pytest.mark.slow
def test_garbled_answers_are_counted_and_polled_again(gauge_twin):
    twin = gauge_twin("mark10", garbage=0.3, seed=5)
    with AsciiGauge({"driver": "ascii-gauge", "url": twin.port, "preset": "mark10",
                     "max_failures": 10}) as gauge:
        block = gauge.read(60, 1000)
        s = gauge.stats
    assert np.all(np.abs(block.ft[:, 0] - BIAS_N) < 6 * NOISE_N)
    assert s["unparseable"] == twin.stats["garbage"] > 5
    assert s["readings"] == 61  # the open check's reading and these 60
    assert s["timeouts"] == 0  # a garbled answer is re-polled at once, not waited out


@pytest.mark.slow
def test_hx711_stream_over_pty(live, gauge_twin):
    twin = gauge_twin("hx711-csv", rate_hz=80, scale=0.001, offset=8000, garbage=0.2, seed=2)
    cfg = {"driver": "ascii-gauge", "url": twin.port, "preset": "hx711-csv", "scale": 0.001,
           "offset": 8000, "channel": "fz", "sign": -1}
    with AsciiGauge(cfg) as gauge:
        block = gauge.read(40, 1000)  # 80 Hz whatever the caller asks
        s = gauge.stats
    span = block.t_s[-1] - block.t_s[0]
    assert 0.35 < span < 0.7
    assert np.all(np.diff(block.seq) > 0)  # the board's millis
    assert 350 < (block.seq[-1] - block.seq[0]) < 700
    assert np.all(np.isnan(block.ft[:, [0, 1, 3, 4, 5]]))
    assert abs(block.ft[:, 2].mean() + BIAS_N) < 3 * NOISE_N
    assert s["unparseable"] > 0


@pytest.mark.slow
def test_stream_drops_lines_from_a_pause(gauge_twin):
    twin = gauge_twin("hx711-csv", rate_hz=80)
    cfg = {"driver": "ascii-gauge", "url": twin.port, "preset": "hx711-csv", "scale": 0.001,
           "offset": 8000, "max_gap_s": 0.1}
    with AsciiGauge(cfg) as gauge:
        gauge.read(5, 80)
        time.sleep(0.5)
        t_call = time.monotonic()
        block = gauge.read(5, 80)
        assert block.t_s[0] >= t_call
        assert gauge.stats["stale"] >= 30


@pytest.mark.slow
def test_bias_on_the_gauges_channel(gauge_twin):
    twin = gauge_twin("mark10", unit="N")
    cfg = {"driver": "ascii-gauge", "url": twin.port, "preset": "mark10", "channel": "fy"}
    with AsciiGauge(cfg) as gauge:
        offset = gauge.read(40, 1000).ft.mean(axis=0)  # as the engine tares: NaN elsewhere
        gauge.set_bias(offset)
        assert abs(gauge.read(40, 1000).ft[:, 1].mean()) < 4 * NOISE_N
        with pytest.raises(ValueError, match="channel fy"):
            gauge.set_bias(np.full(6, np.nan))


@pytest.mark.slow
def test_silent_gauge_is_a_fault_naming_the_port(gauge_twin):
    twin = gauge_twin("mark10")
    with AsciiGauge({"driver": "ascii-gauge", "url": twin.port, "preset": "mark10",
                     "timeout_s": 0.1, "max_failures": 3}) as gauge:
        twin.silent = True
        t0 = time.monotonic()
        with pytest.raises(DeviceError, match=rf"force gauge on {twin.port}: no valid reading"):
            gauge.read(10, 100)
        assert time.monotonic() - t0 < 1.0
        assert gauge.stats["timeouts"] == 3


@pytest.mark.slow
def test_silent_stream_fails_at_open(gauge_twin):
    twin = gauge_twin("hx711-csv")
    twin.silent = True
    with pytest.raises(DeviceError, match="no valid reading for 0.3 s"):
        AsciiGauge({"driver": "ascii-gauge", "url": twin.port, "preset": "hx711-csv",
                    "timeout_s": 0.3})


def test_missing_port_is_named():
    with pytest.raises(DeviceError, match="cannot open /dev/does-not-exist"):
        AsciiGauge({"driver": "ascii-gauge", "url": "/dev/does-not-exist", "preset": "mark10"})
