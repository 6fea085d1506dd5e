"""Manufacturer-style thruster tables (Blue Robotics T200 style) built from known truth.

A table has one row per PWM command and per supply voltage: unsigned RPM, current, the
voltage, electrical power, force in kgf and efficiency in g/W, each rounded to the table's
resolution (the public T200 tables give current in 0.05 A steps). The truth is

    f = C_p |n| n (C_p per direction),   I = C(U) |n|^k + I_0,   C(U) = C_ref U_ref / U,
    n_max(U) = n_max_ref U / U_ref,

so thrust from current is f = C_i (I - I_0)^(2/k) with C_i = C_p / C(U)^(2/k); k = 3 is the
textbook law, a real T200 gives about 3.4.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

G_N_PER_KGF = 9.80665
GRAMS_PER_NEWTON = 1000.0 / G_N_PER_KGF


@dataclass(frozen=True)
class MakerThruster:
    """A thruster with known coefficients and how its maker tabulated it.

    `noise` scales the scatter of the point means (thrust about 1 %, current about 0.5 %);
    `current_step`, `force_step_kgf` and `rpm_step` are the table's resolution.
    """

    cp_fwd: float = 3.9e-6  # N/(r/min)^2
    rev_ratio: float = 0.8
    k: float = 3.4  # exponent of the current law
    i0_a: float = 0.1
    max_rpm: float = 3600.0  # at u_ref
    max_current_a: float = 24.0  # at full forward speed and u_ref
    u_ref: float = 16.0
    deadband_us: float = 25.0
    step_us: float = 4.0
    noise: float = 1.0
    current_step: float = 0.05
    force_step_kgf: float = 0.01
    rpm_step: float = 1.0
    seed: int = 0

    @property
    def cp_rev(self) -> float:
        return self.cp_fwd * self.rev_ratio

    def c_law(self, volts: float) -> float:
        """C(U) of I = C |n|^k + I_0, A/(r/min)^k."""
        return (self.max_current_a - self.i0_a) / self.max_rpm**self.k * self.u_ref / volts

    def ci(self, volts: float, direction: str = "fwd") -> float:
        """C_i = C_p / C(U)^(2/k), N/A^(2/k)."""
        cp = self.cp_fwd if direction == "fwd" else self.cp_rev
        return cp / self.c_law(volts) ** (2 / self.k)

    def commands(self) -> np.ndarray:
        return np.arange(1100.0, 1900.0 + self.step_us / 2, self.step_us)

    def speed(self, command: np.ndarray, volts: float) -> np.ndarray:
        """Signed steady speed (r/min): zero inside the deadband, reverse 0.95 x forward."""
        offset = command - 1500.0
        beyond = np.maximum(np.abs(offset) - self.deadband_us, 0.0) / (400.0 - self.deadband_us)
        top = self.max_rpm * volts / self.u_ref * np.where(offset > 0, 1.0, 0.95)
        return np.sign(offset) * top * beyond**0.85


def _round(x: np.ndarray, step: float) -> np.ndarray:
    return np.round(x / step) * step if step > 0 else x


def rows(th: MakerThruster, volts: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One voltage's table columns (SI except force in kgf), rounded as the maker prints them."""
    cmd = th.commands()
    n = th.speed(cmd, volts)
    f = np.where(n >= 0, th.cp_fwd, th.cp_rev) * np.abs(n) * n
    i = th.c_law(volts) * np.abs(n) ** th.k + th.i0_a
    f = f + rng.normal(0, 1, f.size) * th.noise * (0.01 + 0.01 * np.abs(f))
    i = i + rng.normal(0, 1, i.size) * th.noise * (0.005 + 0.005 * i)
    rpm = np.abs(n) + rng.normal(0, 1, n.size) * th.noise * (2 + 0.002 * np.abs(n))
    rpm = np.where(np.abs(n) > 1, rpm, 0.0)
    stopped = np.abs(n) < 1
    i = np.where(stopped, 0.0, i)  # the maker's stand reads no current with the motor stopped
    f = np.where(stopped, 0.0, f)
    cur = np.maximum(_round(i, th.current_step), 0.0)
    force = _round(f / G_N_PER_KGF, th.force_step_kgf)
    power = cur * volts
    with np.errstate(divide="ignore", invalid="ignore"):
        eff = np.where(power > 0, np.abs(force) * 1000 / power, 0.0)
    return {"command": cmd, "rpm": _round(rpm, th.rpm_step), "current": cur,
            "voltage": np.full(cmd.size, volts), "power": power, "force": force, "eff": eff}


HEAD = ["PWM (µs)", "RPM", "Current (A)", "Voltage (V)", "Power (W)", "Force (Kg f)",
        "Efficiency (g/W)"]


def table(th: MakerThruster, voltages: tuple[float, ...] = (16.0,),
          supply: str | None = "Supply Voltage (V)") -> str:
    """The maker's CSV: one block of rows per voltage; `supply` names the column of the
    voltage set (None: no such column, the voltages are only in `Voltage (V)`)."""
    rng = np.random.default_rng(th.seed)
    head = HEAD + ([supply] if supply else [])
    lines = [",".join(head)]
    for volts in voltages:
        c = rows(th, volts, rng)
        for k in range(c["command"].size):
            row = [f"{c['command'][k]:g}", f"{c['rpm'][k]:g}", f"{c['current'][k]:.2f}",
                   f"{volts:g}", f"{c['power'][k]:.2f}", f"{c['force'][k]:.3f}",
                   f"{c['eff'][k]:.2f}"]
            lines.append(",".join(row + ([f"{volts:g}"] if supply else [])))
    return "\n".join(lines) + "\n"


def random_maker(seed: int, **fixed: object) -> MakerThruster:
    """A thruster drawn from `seed`: coefficients, speed, current, exponent, resolution and
    noise; `fixed` sets fields instead (k=3.0 for a textbook current law, say)."""
    rng = np.random.default_rng(seed)
    drawn = {
        "cp_fwd": float(np.exp(rng.uniform(np.log(1.5e-6), np.log(8e-6)))),
        "rev_ratio": float(rng.uniform(0.7, 0.9)),
        "k": float(rng.uniform(3.25, 3.6)), "i0_a": float(rng.uniform(0.05, 0.4)),
        "max_rpm": float(rng.uniform(2800, 4200)),
        "max_current_a": float(rng.uniform(12, 30)),
        "deadband_us": float(rng.uniform(15, 40)),
        "step_us": float(rng.choice([4.0, 5.0, 10.0])),
        "noise": float(rng.uniform(0.5, 1.5)),
        "current_step": float(rng.choice([0.01, 0.05, 0.1])),
        "force_step_kgf": float(rng.choice([0.001, 0.01])),
        "seed": seed,
    }
    return replace(MakerThruster(), **(drawn | fixed))
