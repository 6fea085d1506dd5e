"""Pre-flight check of a rig: open every device, read for a while, summarise what came in.

Commands nothing beyond neutral unless a test command is asked for explicitly, and writes
nothing; the engine alone drives devices through a run (docs/design.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from rigtool.devices.registry import open_device
from rigtool.rig import RigSet
from rigtool.sensor_rate import native_rate_hz
from rigtool.units import FT_CHANNELS

if TYPE_CHECKING:
    from rigtool.devices.scpi_supply import ScpiSupplyConfig

FEEDBACK = {"speed_rpm": "r/min", "current_a": "A", "voltage_v": "V"}
SETTLE_S = 1.0  # after a test command, before measuring
CHUNK_S = 0.1  # seconds of samples per read


@dataclass
class ChannelStats:
    """Mean and noise (standard deviation) of one channel over the check."""

    name: str
    unit: str
    n: int
    mean: float
    std: float


@dataclass
class CheckReport:
    """What `rigtool check` found."""

    samples: int
    seconds: float
    rate_hz: float
    channels: list[ChannelStats]
    feedback: list[ChannelStats]
    feedback_rate_hz: float
    counters: dict[str, dict] = field(default_factory=dict)


def _stats(name: str, unit: str, values: np.ndarray) -> ChannelStats | None:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return None
    return ChannelStats(name, unit, int(v.size), float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0)


def run_check(rigset: RigSet, seconds: float = 3.0, rate_hz: float = 1000.0,
              command: float | None = None) -> CheckReport:
    """Read the sensor and feedback for `seconds` (optionally at a test `command`), then neutral.

    Each read asks for CHUNK_S of samples at the rate the sensor streams at (measured, as a
    sweep does, unless it samples as asked), so a slow gauge reads for `seconds`, not for the
    time `rate_hz` samples would take it."""
    act, sensor = rigset.actuator, rigset.sensor
    act.neutral()
    act.read_feedback()
    try:
        native, _ = native_rate_hz(sensor, rate_hz)
        chunk = max(1, round(CHUNK_S * (native or rate_hz)))
        if command is not None:
            act.set_command(command)
            for _ in range(round(SETTLE_S / CHUNK_S)):
                sensor.read(chunk, rate_hz)
            act.read_feedback()
        blocks, feedback = [], []
        for _ in range(max(1, round(seconds / CHUNK_S))):
            blocks.append(sensor.read(chunk, rate_hz))
            feedback.append(act.read_feedback())
    finally:
        act.neutral()
    t = np.concatenate([b.t_s for b in blocks])
    ft = np.concatenate([b.ft for b in blocks])
    span = float(t[-1] - t[0]) if t.size > 1 else 0.0
    channels = [s for i, name in enumerate(FT_CHANNELS)
                if (s := _stats(name, "N" if name.startswith("f") else "N m", ft[:, i]))]
    fb_t = np.concatenate([f.t_s for f in feedback]) if feedback else np.empty(0)
    fb_stats = []
    for name, unit in FEEDBACK.items():
        parts = [getattr(f, name) for f in feedback if getattr(f, name) is not None]
        if parts and (s := _stats(name, unit, np.concatenate(parts))):
            fb_stats.append(s)
    fb_span = float(fb_t[-1] - fb_t[0]) if fb_t.size > 1 else 0.0
    counters = {}
    for role, dev in (("actuator", act), ("sensor", sensor), ("depth stage", rigset.depth_stage)):
        stats = getattr(dev, "stats", None)
        if stats:
            counters[role] = dict(stats)
    return CheckReport(
        samples=int(t.size), seconds=span, rate_hz=(t.size - 1) / span if span > 0 else 0.0,
        channels=channels, feedback=fb_stats,
        feedback_rate_hz=(fb_t.size - 1) / fb_span if fb_span > 0 else 0.0, counters=counters,
    )


def supply_lines(config: ScpiSupplyConfig) -> list[str]:
    """What `rigtool check` says of a rig's SCPI supply: identity, the state it was found in,
    and which protections it has. Only queries are sent; the supply is left as found."""
    with open_device("supply", config) as supply:
        found, have = supply.found, supply.protection
        lines = [f"supply: {supply.identity} on {config.where}",
                 f"  found: output {'ON' if found.output_on else 'off'}, setpoint "
                 f"{found.setpoint_v:g} V, current limit {found.current_limit_a:g} A (rig "
                 f"max_voltage_v {config.max_voltage_v:g} V; a sweep switches it off, programs "
                 "the limit and 0 V, then switches it on)"]
        ovp = ("yes: a sweep sets it to max_voltage_v" if have.over_voltage
               else "no (VOLT:PROT not answered)")
        lines.append(f"  over-voltage protection: {ovp}")
        if have.watchdog and config.watchdog != "off":
            lines.append(f"  output watchdog: yes: a sweep arms it at {config.watchdog_s:g} s, "
                         "so the output goes off if rigtool is killed (kill -9) or the host hangs")
        else:
            lines.append("  output watchdog: NO: after kill -9 or a host crash the output stays "
                         "on at the last voltage until switched off by hand (docs/safety.md)")
        return lines
