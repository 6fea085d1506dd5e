"""The force sensor's real sample rate, found before a sweep starts, and the timing it allows.

A driver that samples at the rate asked (`follows_rate`, the twin) needs nothing; any other
is measured from the times of about `PROBE_S` of its samples. A driver whose `seq` numbers
every sample the device sent (`numbers_samples`, the Net F/T's rdt_sequence) is counted by
those numbers, so samples lost while the reader was held up do not lower the rate.
A driver that knows its rate (`rate_hz`, e.g. the Net F/T box's RDT rate from its XML) is
measured too: when the two disagree by more than RATE_MATCH_FRAC the measured rate is used,
with a note the run records. Every rate must be finite and within MIN_RATE_HZ..MAX_RATE_HZ.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rigtool.bounds import MAX_RATE_HZ, MIN_RATE_HZ
from rigtool.config import locate
from rigtool.devices.base import ForceSensor
from rigtool.errors import ConfigError, DeviceError
from rigtool.plan import RATE_MATCH_FRAC, SensorTiming, TimingRefused, sensor_timing
from rigtool.protocol import Protocol
from rigtool.rig import Rig, RigSet

PROBE_S = 0.5  # seconds of samples timed to measure a sensor's rate
PROBE_BLOCK = 16  # samples per read while probing
MAX_PROBE_READS = 10_000


def native_rate_hz(sensor: ForceSensor, asked_hz: float) -> tuple[float | None, str | None]:
    """The rate `sensor` delivers samples at when asked for `asked_hz` (None if it follows
    it), and a note when the rate it states was not the rate it streams at."""
    if getattr(sensor, "follows_rate", False):
        return None, None
    name = getattr(sensor, "name", type(sensor).__name__)
    known = getattr(sensor, "rate_hz", None)
    if known is not None:
        _check_rate(name, "stated", float(known))
    measured = _check_rate(name, "measured", measured_rate_hz(sensor, asked_hz))
    if known is None:
        return measured, None
    if abs(measured / float(known) - 1) <= RATE_MATCH_FRAC:
        return float(known), None
    return measured, (f"{name}: the sensor states {float(known):g} Hz but streams at "
                      f"{measured:.6g} Hz (measured over {PROBE_S:g} s): the measured rate "
                      "is used")


def _check_rate(name: str, how: str, rate_hz: float) -> float:
    """`rate_hz` if it is a sample rate rigtool can use; else a DeviceError naming it."""
    if not (math.isfinite(rate_hz) and MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ):
        raise DeviceError(f"{name}: {how} sample rate {rate_hz!r} Hz is not a usable rate "
                          f"(finite, {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz)")
    return rate_hz


def measured_rate_hz(sensor: ForceSensor, asked_hz: float) -> float:
    """The rate of `sensor`'s samples over about `PROBE_S` of them, counted by the device's
    own sample numbers where it has them (`numbers_samples`), else by arrival."""
    numbered = bool(getattr(sensor, "numbers_samples", False))
    times: list = []
    seqs: list = []
    for _ in range(MAX_PROBE_READS):
        block = sensor.read(PROBE_BLOCK, asked_hz)
        times.extend(block.t_s.tolist())
        if numbered and block.seq is not None:
            seqs.extend(block.seq.tolist())
        if len(times) > 2 and times[-1] - times[0] >= PROBE_S:
            counts = sample_counts(np.asarray(seqs)) if len(seqs) == len(times) else None
            return fitted_rate_hz(np.asarray(times), counts)
    span = times[-1] - times[0] if times else 0.0
    raise DeviceError(f"could not measure the sensor's sample rate: {len(times)} samples in "
                      f"{span:.3g} s")


def sample_counts(seq: np.ndarray) -> np.ndarray:
    """How many samples the device had sent at each of its sample numbers `seq`: a skip is
    samples lost, and a step back (a new stream, a wrap) counts as the next sample."""
    steps = np.diff(np.asarray(seq, dtype=np.int64))
    steps[steps <= 0] = 1
    return np.r_[0, np.cumsum(steps)].astype(float)


def fitted_rate_hz(t_s: np.ndarray, counts: np.ndarray | None = None) -> float:
    """Samples per second from their arrival times: the slope of the upper envelope of the
    sample count (`counts`, default the order of arrival) against time, on its edge at the
    middle of the time span. A sample can only arrive late, never early, so late ones (a
    busy sender catching up, a backlog read at once, a USB frame's batch) fall below that
    envelope and do not pull it, as they pulled a least-squares line."""
    t = np.asarray(t_s, dtype=float)
    count = np.arange(len(t), dtype=float) if counts is None else np.asarray(counts, dtype=float)
    order = np.lexsort((count, t))
    t, count = t[order], count[order]
    last = np.r_[t[1:] != t[:-1], True]  # the highest count at each stamp
    hull = _upper_hull(t[last], count[last])
    if len(hull) < 2:
        return math.inf
    t_hull, count_hull = t[last][hull], count[last][hull]
    edge = int(np.clip(np.searchsorted(t_hull, (t[0] + t[-1]) / 2), 1, len(hull) - 1))
    return float((count_hull[edge] - count_hull[edge - 1]) / (t_hull[edge] - t_hull[edge - 1]))


def _upper_hull(t: np.ndarray, count: np.ndarray) -> list[int]:
    """Indices of the upper convex hull of the points (t, count), t strictly increasing
    (a monotone chain: scipy's Qhull refuses the collinear points of a regular stream)."""
    hull: list[int] = []
    for i in range(len(t)):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            if ((t[b] - t[a]) * (count[i] - count[a])
                    - (count[b] - count[a]) * (t[i] - t[a])) >= 0:
                hull.pop()  # b lies on or below the chord from a to i
            else:
                break
        hull.append(i)
    return hull


def check_sensor_rate(protocol: Protocol, path: Path, rigset: RigSet) -> SensorTiming:
    """Find the sensor's rate, keep it on `rigset` for the engine, and refuse (file:line of
    the protocol field) a protocol whose timing it cannot meet."""
    rate, note = native_rate_hz(rigset.sensor, protocol.timing.acquire.rate_hz)
    try:
        timing = sensor_timing(protocol, rate)
    except TimingRefused as exc:
        field = ".".join(exc.field)
        raise ConfigError([f"{locate(path, exc.field)}: {field}: {exc}"]) from None
    rigset.sensor_rate_hz = rate
    rigset.sensor_rate_note = note
    return timing


def dry_run_rate(protocol: Protocol, rig: Rig) -> str:
    """The acquisition timing as far as the files tell it (a dry run opens no device)."""
    if rig.simulator is not None:
        return f"{sensor_timing(protocol, None).describe()} (the twin samples at the rate asked)"
    driver = getattr(rig.sensor, "driver", "?")
    stated = rig.sensor.stated_rate() if rig.sensor is not None else None
    where = f"{stated}, checked over 0.5 s" if stated else "measured over 0.5 s"
    return (f"{protocol.timing.acquire.n_samples} samples at {protocol.timing.acquire.rate_hz:g} Hz "
            f"per point if the {driver} sensor runs at that rate; its rate is {where} when it "
            "opens, then a multiple is averaged down, another rate acquires the protocol's "
            "duration, too few samples are refused (docs/protocols.md)")
