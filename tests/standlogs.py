"""Thrust-stand logs in other stands' designs, built from known truth by physics of their own
(not the twin): one-way step tables tared once, up-down tables with a hysteretic ESC, and
thrust laws other than C_p |n| n. Used through `rigtool import` and `rigtool calibrate`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HEADER = "Time (s),ESC signal (µs),Thrust (N),Voltage (V),Current (A),Motor Optical Speed (RPM)"


@dataclass(frozen=True)
class Stand:
    """A forward-only ESC thruster: n = top (cmd - 1500) / 400 once turning; it starts from
    rest at 1500 + start_us and stops coming back below 1500 + stop_us. Thrust by `law`."""

    law: str = "quadratic"  # or "quadratic+linear", "power"
    cp: float = 5e-7  # N/(r/min)^2
    linear: float = 0.0  # N/(r/min), for quadratic+linear
    k: float = 2.0  # for power: f = cp top^2 (n / top)^k
    top_rpm: float = 3000.0
    start_us: float = 25.0
    stop_us: float = 25.0
    noise_n: float = 0.01
    offset_n: float = 0.0
    drift_n_per_h: float = 0.0  # the load cell's zero drifting after its one tare
    # torque leaking into the thrust reading: this fraction of full-scale thrust at full
    # torque (the torque grows as n^2), as a datasheet's crosstalk in % of full scale
    crosstalk_frac: float = 0.0

    def thrust(self, n: np.ndarray) -> np.ndarray:
        """True thrust (N) at speed n (r/min, >= 0)."""
        if self.law == "quadratic":
            return self.cp * n**2
        if self.law == "quadratic+linear":
            return self.cp * n**2 + self.linear * n
        return self.cp * self.top_rpm**2 * (n / self.top_rpm) ** self.k


def step_table(stand: Stand, seed: int, step_us: float = 25.0, updown: bool = False,
               hold_s: float = 5.0) -> tuple[str, np.ndarray, np.ndarray]:
    """One averaged row per command, 1500 -> 1900 us (and back with `updown`): the CSV text,
    the commands and the true speeds."""
    rng = np.random.default_rng(seed)
    up = np.arange(1500.0, 1900.0 + step_us / 2, step_us)
    cmds = np.concatenate([up, up[-2::-1]]) if updown else up
    n = np.zeros(cmds.size)
    spinning = False
    for i, c in enumerate(cmds):
        d = c - 1500.0
        spinning = d >= (stand.stop_us if spinning else stand.start_us)
        n[i] = stand.top_rpm * d / 400.0 if spinning else 0.0
    t = 2.0 + hold_s * np.arange(cmds.size)
    full = stand.thrust(np.array([stand.top_rpm]))[0]
    f = (stand.thrust(n) + stand.offset_n + stand.drift_n_per_h * t / 3600.0
         + stand.crosstalk_frac * full * (n / stand.top_rpm) ** 2
         + rng.normal(0.0, stand.noise_n, n.size))
    current = 0.3 + 2e-10 * n**3 + rng.normal(0.0, 0.01, n.size)
    rpm = np.where(n > 0, n + rng.normal(0.0, 2.0, n.size), 0.0)
    rows = [HEADER] + [f"{a:.2f},{c:g},{b:.5f},16.00,{i:.4f},{s:.1f}"
                       for a, c, b, i, s in zip(t, cmds, f, current, rpm, strict=True)]
    return "\n".join(rows) + "\n", cmds, n


def ramp_log(stand: Stand, seed: int, rate_hz: float = 5.0, ramp_s: float = 60.0,
             hold_s: float = 5.0, end_hold_s: float = 0.0, tau_s: float = 0.5,
             speed: bool = False, lag_s: float = 0.0) -> str:
    """A continuous command ramp 1500 -> 1900 us sampled at `rate_hz`, neutral held
    `hold_s` before it, no speed column (a command ramp of a stand without a tachometer).
    `end_hold_s`: then a step back to neutral held that long, the propeller spinning down
    with time constant `tau_s` (its thrust decays over the first seconds there). `speed`:
    with an optical speed column (r/min, 2 r/min noise). `lag_s`: the thrust channel reads
    the true thrust through a first-order filter of that time constant (a load cell's), so
    it lags the speed."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hold_s + ramp_s + end_hold_s, 1.0 / rate_hz)
    n = _ramp_speed(stand, t, hold_s, ramp_s, end_hold_s, tau_s)
    cmd = 1500.0 + 400.0 * np.clip((t - hold_s) / ramp_s, 0.0, 1.0)
    cmd[t >= hold_s + ramp_s] = 1500.0 if end_hold_s else cmd[t >= hold_s + ramp_s]
    f = stand.thrust(n)
    if lag_s > 0:
        fine = np.arange(0.0, t[-1] + LAG_DT_S, LAG_DT_S)
        true = stand.thrust(_ramp_speed(stand, fine, hold_s, ramp_s, end_hold_s, tau_s))
        f = np.interp(t, fine, _first_order(true, LAG_DT_S / lag_s))
    f = f + stand.offset_n + rng.normal(0.0, stand.noise_n, n.size)
    if speed:
        rpm = np.where(n > 0, n + rng.normal(0.0, 2.0, n.size), 0.0)
        rows = ["Time (s),ESC signal (µs),Thrust (N),Motor Optical Speed (RPM)"]
        rows += [f"{a:.3f},{c:.2f},{b:.5f},{r:.1f}" for a, c, b, r in zip(t, cmd, f, rpm,
                                                                          strict=True)]
        return "\n".join(rows) + "\n"
    rows = ["Time (s),ESC signal (µs),Thrust (N)"]
    rows += [f"{a:.3f},{c:.2f},{b:.5f}" for a, c, b in zip(t, cmd, f, strict=True)]
    return "\n".join(rows) + "\n"


LAG_DT_S = 1e-3  # time step of the filter a lagging thrust channel is simulated with


def _ramp_speed(stand: Stand, t: np.ndarray, hold_s: float, ramp_s: float, end_hold_s: float,
                tau_s: float) -> np.ndarray:
    """True speed (r/min) of `ramp_log`'s thruster at the times `t`."""
    cmd = 1500.0 + 400.0 * np.clip((t - hold_s) / ramp_s, 0.0, 1.0)
    d = cmd - 1500.0
    n = np.where(d >= stand.start_us, stand.top_rpm * d / 400.0, 0.0)
    after = t - (hold_s + ramp_s)
    return np.where(end_hold_s and after >= 0,
                    stand.top_rpm * np.exp(-np.maximum(after, 0) / tau_s), n)


def _first_order(x: np.ndarray, k: float) -> np.ndarray:
    """x through the first-order filter y += k (x - y), started at x[0]."""
    from scipy.signal import lfilter

    y, _ = lfilter([k], [1.0, k - 1.0], x, zi=[x[0] * (1.0 - k)])
    return y


def rov_table(seed: int, cp_fwd: float = 5e-6, rev_ratio: float = 0.8, per_side: int = 10,
              noise_frac: float = 0.015, stated_std: float | None = None) -> str:
    """An in-water thruster table: `per_side` commands each way beyond a +-25 us dead band,
    one row each with unsigned RPM, thrust off by white noise of `noise_frac` of full scale.
    With `stated_std` (N) the table also gives a thrust std over 100 samples per row, so the
    rows state errors `stated_std / 10` that the scatter may exceed (lack of fit)."""
    rng = np.random.default_rng(seed)
    side = np.linspace(1540.0, 1900.0, per_side)
    cmds = np.concatenate([3000.0 - side[::-1], side])
    n = 3000.0 * (cmds - 1500.0) / 400.0
    f = np.where(n > 0, cp_fwd, cp_fwd * rev_ratio) * np.abs(n) * n
    full = cp_fwd * 2700.0**2
    f_read = f + rng.normal(0.0, noise_frac * full, n.size)
    head = "PWM (µs),RPM,Force (N)" + (",Force std (N),Samples" if stated_std else "")
    rows = [head]
    for c, s, b in zip(cmds, np.abs(n), f_read, strict=True):
        row = f"{c:g},{s:.0f},{b:.4f}"
        rows.append(row + (f",{stated_std:.4f},100" if stated_std else ""))
    return "\n".join(rows) + "\n"
