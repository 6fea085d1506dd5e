"""Synthetic thrust-stand logs in the formats `rigtool import` reads (written into tmp_path)."""

from __future__ import annotations

import numpy as np

NEUTRAL = 1500.0
DEADBAND = 25.0
FWD_MAX_KGF = 4.0
REV_MAX_KGF = 3.2
COMMANDS = np.arange(1100.0, 1901.0, 25.0)


def thrust_kgf(command: np.ndarray) -> np.ndarray:
    """ESC thruster: zero inside +-25 us of 1500 us, quadratic outside, reverse 0.8 x forward."""
    x = np.maximum(np.abs(command - NEUTRAL) - DEADBAND, 0.0) / (400.0 - DEADBAND)
    return np.where(command >= NEUTRAL, FWD_MAX_KGF, -REV_MAX_KGF) * x**2


def rcbenchmark_log(hold_s: float = 3.0, rate_hz: float = 20.0, seed: int = 0,
                    bad_line_at: int | None = None) -> str:
    """A Tyto/RCbenchmark-style time series: each command held `hold_s`, a lag at each change."""
    rng = np.random.default_rng(seed)
    header = ("Time (s),ESC signal (µs),Thrust (kgf),Torque (N·m),Voltage (V),Current (A),"
              "Motor Electrical Speed (RPM),Motor Optical Speed (RPM),")
    lines = [header]
    t = 0.0
    level = 0.0
    for cmd in COMMANDS:
        target = float(thrust_kgf(np.array([cmd]))[0])
        for _ in range(int(hold_s * rate_hz)):
            level += (target - level) * 0.4  # first-order lag: the settling transient
            f = level + rng.normal(0, 0.002)
            rpm = 3800 * np.sqrt(abs(level) / FWD_MAX_KGF)
            cur = 0.1 + 20 * abs(level) / FWD_MAX_KGF
            lines.append(f"{t:.3f},{cmd:.0f},{f:.5f},{0.01 * f:.5f},{16 - 0.02 * cur:.3f},"
                         f"{cur:.3f},{7 * rpm:.0f},{rpm:.0f},")
            t += 1 / rate_hz
        lines.append("")  # blank line between commands, as some exports have
    if bad_line_at is not None:
        cells = lines[bad_line_at - 1].split(",")
        cells[2] = "abc"
        lines[bad_line_at - 1] = ",".join(cells)
    return "\ufeff" + "\n".join(lines) + "\n"


def point_table(decimal_comma: bool = False, noise_kgf: float = 0.004, seed: int = 1) -> str:
    """A per-point table (one row per command: mean thrust in kgf, std, n), generic headers."""
    rng = np.random.default_rng(seed)
    sep, lines = (";" if decimal_comma else ","), []
    lines.append(sep.join(["pwm", "F_z [kgf]", "F_std [kgf]", "count", "V", "note"]))
    for cmd in COMMANDS:
        f = float(thrust_kgf(np.array([cmd]))[0])
        mean = f + rng.normal(0, noise_kgf / 10)
        row = [f"{cmd:.0f}", f"{mean:.5f}", f"{noise_kgf + 0.01 * abs(f):.5f}", "500", "16.0",
               "ok", ""]
        if decimal_comma:
            row = [v.replace(".", ",") for v in row]
        lines.append(sep.join(row))
    return "\n".join(lines) + "\n"
