"""The force sensor's real sample rate, found before a sweep starts, and the timing it allows.

A driver that knows its rate says so (`rate_hz`, e.g. the Net F/T box's RDT rate); one that
samples at the rate asked (`follows_rate`, the twin) needs nothing; any other is measured
from the times of about `PROBE_S` of its samples.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigtool.config import locate
from rigtool.devices.base import ForceSensor
from rigtool.errors import ConfigError, DeviceError
from rigtool.plan import SensorTiming, TimingRefused, sensor_timing
from rigtool.protocol import Protocol
from rigtool.rig import Rig, RigSet

PROBE_S = 0.5  # seconds of samples timed to measure a sensor's rate
PROBE_BLOCK = 16  # samples per read while probing
MAX_PROBE_READS = 10_000


def native_rate_hz(sensor: ForceSensor, asked_hz: float) -> float | None:
    """The rate `sensor` delivers samples at when asked for `asked_hz`; None if it follows it."""
    if getattr(sensor, "follows_rate", False):
        return None
    known = getattr(sensor, "rate_hz", None)
    if known:
        return float(known)
    times: list = []
    for _ in range(MAX_PROBE_READS):
        t = sensor.read(PROBE_BLOCK, asked_hz).t_s
        times.extend(t.tolist())
        if len(times) > 2 and times[-1] - times[0] >= PROBE_S:
            return fitted_rate_hz(np.asarray(times))
    span = times[-1] - times[0] if times else 0.0
    raise DeviceError(f"could not measure the sensor's sample rate: {len(times)} samples in "
                      f"{span:.3g} s")


def fitted_rate_hz(t_s: np.ndarray) -> float:
    """Samples per second from their arrival times: the slope of the sample count against
    time, so bursts (a datagram batch, a USB frame) weigh in on both sides of the line."""
    slope = np.polyfit(t_s - t_s[0], np.arange(len(t_s), dtype=float), 1)[0]
    return float(slope)


def check_sensor_rate(protocol: Protocol, path: Path, rigset: RigSet) -> SensorTiming:
    """Find the sensor's rate, keep it on `rigset` for the engine, and refuse (file:line of
    the protocol field) a protocol whose timing it cannot meet."""
    rate = native_rate_hz(rigset.sensor, protocol.timing.acquire.rate_hz)
    try:
        timing = sensor_timing(protocol, rate)
    except TimingRefused as exc:
        field = ".".join(exc.field)
        raise ConfigError([f"{locate(path, exc.field)}: {field}: {exc}"]) from None
    rigset.sensor_rate_hz = rate
    return timing


def dry_run_rate(protocol: Protocol, rig: Rig) -> str:
    """The acquisition timing as far as the files tell it (a dry run opens no device)."""
    if rig.simulator is not None:
        return f"{sensor_timing(protocol, None).describe()} (the twin samples at the rate asked)"
    driver = getattr(rig.sensor, "driver", "?")
    where = ("the box's RDT rate (netftapi2.xml)" if driver == "ati-netft"
             and getattr(rig.sensor, "counts_per_force", None) is None
             else "measured over 0.5 s")
    return (f"{protocol.timing.acquire.n_samples} samples at {protocol.timing.acquire.rate_hz:g} Hz "
            f"per point if the {driver} sensor runs at that rate; its rate is {where} when it "
            "opens, then a multiple is averaged down, another rate acquires the protocol's "
            "duration, too few samples are refused (docs/protocols.md)")
