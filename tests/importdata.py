"""Synthetic thrust-stand logs in the formats `rigtool import` reads (written into tmp_path)."""

from __future__ import annotations

from dataclasses import dataclass

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


G_N_PER_KGF = 9.80665


@dataclass(frozen=True)
class TwoWayThruster:
    """A two-way thruster with known coefficients, and how a foreign file records it.

    `deadband` is the half-width of the stop band about neutral, `step` the command grid, both
    in command units; `noise` scales every noise term (1 = a decent stand); `mirrored` puts
    forward thrust on the low side of neutral (ESC direction or mounting reversed); `signed`
    gives the speed column a sign; `spread` adds thrust std and sample count columns.
    """

    cp_fwd: float = 2.0e-6  # N/(r/min)^2
    rev_ratio: float = 0.8
    cn: float = 4e-10  # A/(r/min)^3: 17 A at 3500 r/min
    i0_a: float = 0.3
    max_rpm: float = 3500.0
    rev_speed_ratio: float = 0.95
    unit: str = "pulse_us"
    deadband: float = 25.0
    step: float = 10.0
    noise: float = 1.0
    seed: int = 0
    signed: bool = False
    spread: bool = False
    mirrored: bool = False

    @property
    def cp_rev(self) -> float:
        return self.cp_fwd * self.rev_ratio

    @property
    def neutral(self) -> float:
        return 1500.0 if self.unit == "pulse_us" else 0.0

    @property
    def span(self) -> float:
        return 400.0 if self.unit == "pulse_us" else 100.0

    def commands(self) -> np.ndarray:
        """The command grid from full reverse to full forward, through neutral."""
        half = np.arange(0.0, self.span + self.step / 2, self.step)
        return np.concatenate((self.neutral - half[:0:-1], self.neutral + half))

    def speed(self, command: np.ndarray) -> np.ndarray:
        """Signed steady propeller speed (r/min) at each command: zero inside the deadband."""
        offset = np.asarray(command, dtype=float) - self.neutral
        beyond = np.maximum(np.abs(offset) - self.deadband, 0.0) / (self.span - self.deadband)
        side = np.sign(offset) * (-1.0 if self.mirrored else 1.0)
        top = np.where(side > 0, self.max_rpm, self.max_rpm * self.rev_speed_ratio)
        return side * top * beyond**0.9

    def at_speed(self, n_rpm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Thrust (N, f = C_p |n| n per direction) and current (A, C_n |n|^3 + I_0)."""
        n = np.asarray(n_rpm, dtype=float)
        f = np.where(n >= 0, self.cp_fwd, self.cp_rev) * np.abs(n) * n
        return f, self.cn * np.abs(n) ** 3 + self.i0_a

    def speed_reading(self, n_rpm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """What the tachometer shows: 0 when stopped, only the magnitude unless `signed`."""
        n = np.asarray(n_rpm, dtype=float)
        noisy = n + rng.normal(0, 1, n.shape) * self.noise * (3 + 0.003 * np.abs(n))
        read = np.where(np.abs(n) > 1.0, noisy, 0.0)
        return read if self.signed else np.abs(read)


def stand_log(th: TwoWayThruster, hold_s: float = 3.0, rate_hz: float = 20.0,
              updown: bool = False, averaged: bool = False) -> str:
    """A Tyto/RCbenchmark log: each command held `hold_s`, the speed lags it (0.2 s).

    Thrust noise grows with thrust (vibration); the load cell keeps a zero offset and drifts;
    the electrical-speed column is there but unusable without the pole pairs. `averaged`
    writes one row per command, the mean of its last second (the stand's step-test script).
    """
    rng = np.random.default_rng(th.seed)
    cmds = th.commands()
    if updown:
        cmds = np.concatenate((cmds, cmds[-2::-1]))
    rows = int(round(hold_s * rate_hz))
    command = np.repeat(cmds, rows)
    t = np.arange(command.size) / rate_hz
    target = th.speed(command)
    n = np.empty(command.size)
    level, gain = 0.0, 1 - np.exp(-1 / rate_hz / 0.2)
    for k, goal in enumerate(target):
        level += (goal - level) * gain
        n[k] = level
    f, i = th.at_speed(n)
    zero_n = rng.normal(0, 0.05 * th.noise) + rng.normal(0, 2e-4 * th.noise) * t
    f_read = f + zero_n + rng.normal(0, 1, n.size) * th.noise * (0.02 + 0.01 * np.abs(f))
    i_read = i + rng.normal(0, 1, n.size) * th.noise * (0.02 + 0.005 * i)
    rpm = th.speed_reading(n, rng)
    volts = 16.0 - 0.05 * i_read
    unit = "µs" if th.unit == "pulse_us" else "%"
    lines = [f"Time (s),ESC signal ({unit}),Torque (N·m),Thrust (kgf),Voltage (V),Current (A),"
             "Motor Electrical Speed (RPM),Motor Optical Speed (RPM),Electrical Power (W)"]
    cols = [t, command, 0.01 * f, f_read / G_N_PER_KGF, volts, i_read, 7 * np.abs(n), rpm,
            volts * i_read]
    if averaged:
        last = (np.arange(command.size) % rows) >= rows - int(round(rate_hz))
        step = np.arange(command.size)[last] // rows
        cols = [np.bincount(step, c[last]) / np.bincount(step) for c in cols]
        cols[0] = t[rows - 1::rows]
    lines += [f"{c[0]:.3f},{c[1]:g},{c[2]:.5f},{c[3]:.5f},{c[4]:.3f},{c[5]:.4f},{c[6]:.0f},"
              f"{c[7]:.1f},{c[8]:.2f}" for c in np.column_stack(cols)]
    return "\n".join(lines) + "\n"


def maker_table(th: TwoWayThruster) -> str:
    """A manufacturer's table: one row per command, unsigned RPM (unless `signed`), force in
    kgf (negative in reverse), current, power; no spread or count unless `spread`.

    Each row is a point mean: thrust off by its averaging error and by a scatter of about
    1 % that the averaging does not show (temperature, supply, repeat to repeat).
    """
    rng = np.random.default_rng(th.seed)
    cmds = th.commands()
    n = th.speed(cmds)
    f, i = th.at_speed(n)
    count = rng.integers(50, 500, cmds.size)
    std_n = th.noise * (0.03 + 0.02 * np.abs(f))
    f_mean = f + rng.normal(0, 1, f.size) * th.noise * (0.005 + 0.01 * np.abs(f))
    if th.spread:
        f_mean = f_mean + rng.normal(0, 1, f.size) * std_n / np.sqrt(count)
    rpm = th.speed_reading(n, rng)
    i_mean = i + rng.normal(0, 1, i.size) * th.noise * (0.005 + 0.005 * i)
    name = "PWM (µs)" if th.unit == "pulse_us" else "Throttle (%)"
    head = [name, "RPM", "Current (A)", "Voltage (V)", "Power (W)", "Force (Kg f)"]
    if th.spread:
        head += ["Force std (Kg f)", "Samples"]
    lines = [",".join(head)]
    for k in range(cmds.size):
        row = [f"{cmds[k]:g}", f"{rpm[k]:.0f}", f"{i_mean[k]:.3f}", "16", f"{16 * i_mean[k]:.1f}",
               f"{f_mean[k] / G_N_PER_KGF:.4f}"]
        if th.spread:
            row += [f"{std_n[k] / G_N_PER_KGF:.4f}", f"{count[k]}"]
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def maker_table_args(th: TwoWayThruster) -> list[str]:
    """`rigtool import` options that map `maker_table` columns."""
    unit = "pulse_us" if th.unit == "pulse_us" else "percent"
    args = ["--col", "command=1", "--col", "speed=RPM", "--col", "current=Current",
            "--col", "voltage=Voltage", "--col", "thrust=Force", "--unit", "thrust=kgf",
            "--command-unit", unit, "--neutral", f"{th.neutral:g}"]
    if th.spread:
        args += ["--col", "thrust_std=Force std", "--unit", "thrust_std=kgf",
                 "--col", "n_samples=Samples"]
    return args


def random_thruster(seed: int, **fixed: object) -> TwoWayThruster:
    """A thruster drawn from `seed` (coefficients, speeds, deadband, grid, noise 0.5-1.5);
    `fixed` sets fields instead (unit, signed, spread, mirrored, ...)."""
    rng = np.random.default_rng(seed)
    unit = str(fixed.get("unit", "pulse_us"))
    span = 400.0 if unit == "pulse_us" else 100.0
    max_rpm = float(rng.uniform(2000, 4000))
    drawn = {
        "cp_fwd": float(np.exp(rng.uniform(np.log(1e-6), np.log(2e-5)))),
        "rev_ratio": float(rng.uniform(0.7, 0.9)),
        "cn": float(rng.uniform(3, 25)) / max_rpm**3, "i0_a": float(rng.uniform(0.1, 0.6)),
        "max_rpm": max_rpm, "rev_speed_ratio": float(rng.uniform(0.85, 1.0)),
        "deadband": span * float(rng.uniform(0.03, 0.1)),
        "step": float(rng.choice([4, 10, 20, 25] if unit == "pulse_us" else [1, 2, 2.5, 5])),
        "noise": float(rng.uniform(0.5, 1.5)), "seed": seed,
    }
    return TwoWayThruster(**(drawn | fixed))
