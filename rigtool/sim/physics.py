"""The thruster twin: a pure, clock-injected model of thruster, driver, sensor and ventilation.

Callers pass times (s, on any monotonic scale); the twin never reads a clock. Between
calls the command is piecewise constant and the propeller speed follows the exact
solution of a first-order lag. All randomness comes from one seeded generator, so the
same seed and the same call sequence give identical output.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from rigtool.models import laws
from rigtool.thruster_profiles import ThrusterProfile

_TIME_SLACK_S = 1e-9  # tolerated round-off when a caller's time lies just before the last one
_SETTLED_FRAC = 1e-5  # speed within this fraction of max of its target counts as settled
_RK4_PER_TAU = 40  # integration steps per time constant for the nonlinear speed/inflow laws
_BLOCK_SAMPLES = 4096  # normals are drawn in blocks of this many samples
# Rows of the work block. Each sample() fills a column range and turns it into outputs with
# two small matrix products: ft = rows[0:9].T @ ft_mix, feedback = fb_mix @ rows[8:14].
_THRUST, _TIME, _ONE = 6, 7, 8  # rows 0-5: sensor normals (thrust channel pre-scaled by its std)
_SPEED, _CURRENT = 12, 13  # rows 9-11: speed, current, voltage normals


def _new_block(size: int) -> np.ndarray:
    """Work block of 14 rows (see above) with its row of ones set."""
    block = np.empty((14, size))
    block[_ONE] = 1.0
    return block


def _bus_v(p: ThrusterProfile, supply_v: float) -> float:
    """The bus at no load: the supply's setpoint, plus its rise when it is on."""
    return supply_v + p.supply_rise_v if supply_v > 0 and p.supply_rise_v else supply_v


def _mixing_matrices(p: ThrusterProfile, t0: float, supply_v: float) -> tuple[np.ndarray, np.ndarray]:
    """Matrices mapping work-block rows to the six F/T channels and to speed, current, voltage."""
    ch, sign = p.thrust_channel, p.thrust_sign
    ft_mix = np.zeros((9, 6))
    ft_mix[:6, :6] = np.diag([p.force_noise_n] * 3 + [p.torque_noise_nm] * 3)
    ft_mix[_THRUST] = p.crosstalk
    drift_per_s = sign * p.drift_n_per_h / 3600.0
    ft_mix[:, ch] = 0.0
    ft_mix[ch, ch] = 1.0  # noise already scaled by the per-sample thrust std
    ft_mix[_THRUST, ch] = sign
    ft_mix[_TIME, ch] = drift_per_s
    ft_mix[_ONE, ch] = sign * p.bias_n - drift_per_s * t0
    fb_mix = np.zeros((3, 6))  # columns: one, 3 normals, speed, current
    fb_mix[0, [1, 4]] = p.speed_noise_rpm, 1.0
    fb_mix[1, [2, 5]] = p.current_noise_a, 1.0
    fb_mix[2, [0, 3, 5]] = _bus_v(p, supply_v), p.voltage_noise_v, -p.supply_resistance_ohm
    return ft_mix, fb_mix


@dataclass
class VentilationEvent:
    """Ground truth of one quasi-cavitation event (t_end_s may lie beyond the last sample)."""

    t_start_s: float  # thrust starts to fall
    t_end_s: float  # thrust fully recovered (ramps lie inside [t_start_s, t_end_s])
    drop_frac: float  # fraction of thrust lost once fully ventilated
    depth_m: float  # depth at onset
    speed_rpm: float  # propeller speed at onset


@dataclass
class TwinSamples:
    """One block of simulated samples at the requested times."""

    ft: np.ndarray  # (n, 6) raw fx..tz (N, N m): thrust, crosstalk, bias, drift and noise
    thrust_true_n: np.ndarray  # noise-free thrust including ventilation losses (for evaluation)
    speed_rpm: np.ndarray  # speed feedback with noise
    current_a: np.ndarray  # current feedback with noise
    voltage_v: np.ndarray  # bus voltage feedback with noise
    temperature_c: np.ndarray | None = None  # motor temperature, when the profile reports it


class ThrusterTwin:
    """Simulated thruster on a force sensor at a depth, advanced only by the times callers pass."""

    def __init__(
        self, profile: ThrusterProfile, seed: int, depth_m: float = 1.0, t0: float = 0.0
    ) -> None:
        self.profile = profile
        self.depth_m = float(depth_m)
        self.events: list[VentilationEvent] = []
        self._rng = np.random.default_rng(seed)
        self._t0 = float(t0)
        self._t = float(t0)  # time of the speed state below
        self._n = 0.0  # speed at self._t
        self._m = 0.0  # axial inflow state (r/min) at self._t; follows n (profile.inflow_tau_s)
        self._command = float(profile.neutral)
        self._n_target = 0.0
        self._pending: deque[tuple[float, float]] = deque()  # (due time, command) under delay
        self._active: VentilationEvent | None = None
        self._live = 0  # index of the first event that may still overlap future samples
        self._hazard = self._rng.standard_exponential()  # integrated onset rate left until onset
        self._block = _new_block(_BLOCK_SAMPLES)
        self._pos = _BLOCK_SAMPLES  # block used up: redrawn on first use
        p = profile
        self._settled_rpm = _SETTLED_FRAC * p.max_speed_rpm
        self._supply_v = p.supply_voltage_v
        self._cn, self._idle = p.cn, p.idle_current_a  # current law at the supply voltage
        self._ft_mix, self._fb_mix = _mixing_matrices(p, self._t0, self._supply_v)
        self._log_depths = np.array(p.cav_depth_table_m, dtype=float)
        self._log_onset = np.log(np.array(p.cav_mean_onset_s, dtype=float))
        self._log_duration = np.log(np.array(p.cav_mean_duration_s, dtype=float))
        self._set_depth_rates()
        self._heat = "temperature_c" in p.feedback
        self._temp_c = p.ambient_c  # motor temperature at self._temp_t
        self._temp_t = self._t0

    # ----- public API -----

    @property
    def t_s(self) -> float:
        """Time up to which the state has been advanced."""
        return self._t

    @property
    def command(self) -> float:
        """The command in force (after clipping)."""
        return self._command

    def set_command(self, t: float, command: float) -> None:
        """Advance to `t`, then apply `command` (clipped to the profile's range) from
        `t` + the profile's command delay on."""
        if not math.isfinite(command):
            raise ValueError(f"command must be finite, got {command!r}")
        self._advance(float(t))
        p = self.profile
        clipped = min(max(float(command), p.command_min), p.command_max)
        if p.command_delay_s > 0:
            self._pending.append((self._t + p.command_delay_s, clipped))
        else:
            self._apply_command(clipped)

    def _apply_command(self, command: float) -> None:
        """Make `command` the one in force from the twin's time on."""
        p = self.profile
        self._command = command
        self._n_target = self.target_speed_rpm(self._command)
        if abs(self._n_target) < p.cav_min_speed_rpm:
            self._end_active_event()

    @property
    def supply_voltage_v(self) -> float:
        """The supply voltage in force (the bus sags below it by R * current)."""
        return self._supply_v

    def set_supply_voltage(self, t: float, volts: float) -> None:
        """Advance to `t`, then supply `volts` (0: output off, motor stopped) from `t` on.

        Without a speed loop the speed reached per command scales with the voltage; the
        current drawn for the same shaft power scales with its inverse.
        """
        if not (math.isfinite(volts) and volts >= 0):
            raise ValueError(f"supply voltage must be finite and >= 0, got {volts!r}")
        self._advance(float(t))
        p = self.profile
        self._supply_v = float(volts)
        on = self._supply_v > 0
        self._cn = p.cn * p.supply_voltage_v / self._supply_v if on else 0.0
        self._idle = p.idle_current_a if on else 0.0
        self._fb_mix[2, 0] = _bus_v(p, self._supply_v)
        self._n_target = self.target_speed_rpm(self._command)
        if abs(self._n_target) < p.cav_min_speed_rpm:
            self._end_active_event()

    def set_depth(self, t: float, depth_m: float) -> None:
        """Advance to `t`, then put the propeller centre at `depth_m` below the surface."""
        self._advance(float(t))
        self.depth_m = float(depth_m)
        self._set_depth_rates()
        if self._base_rate == 0.0:
            self._end_active_event()

    def sample(self, t: np.ndarray) -> TwinSamples:
        """Sensor and feedback samples at increasing times `t` (all >= the last time passed in)."""
        t = np.asarray(t, dtype=float)
        size = t.size
        if size == 0:
            e = np.empty(0)
            return TwinSamples(np.empty((0, 6)), e, e.copy(), e.copy(), e.copy())
        t0, t1 = float(t[0]), float(t[-1])
        if t0 < self._t - _TIME_SLACK_S:
            raise ValueError(f"sample time {t0} lies before the twin's time {self._t}")
        if self._pending and self._pending[0][0] <= t1:  # a delayed command falls due
            cut = int(np.searchsorted(t, self._pending[0][0], side="left"))
            head = self.sample(t[:cut]) if cut else None
            self._advance(self._pending[0][0])
            tail = self.sample(t[cut:])
            return tail if head is None else _concat(head, tail)
        self._cavitate(t1)
        p = self.profile
        n0, nt = self._n, self._n_target
        inflow = p.inflow_gain > 0 and abs(self._m - nt) > self._settled_rpm
        if abs(n0 - nt) <= self._settled_rpm and not inflow:  # settled: scalars keep it cheap
            n = m = nt
        else:
            n, m = self._states_at(t)
        absn = abs(n)
        nn = n * absn
        if inflow and p.inflow_law == "healey":
            nn = nn + p.inflow_gain * absn * (n - m)
        elif inflow:
            nn = nn + p.inflow_gain * (nn - m * abs(m))
        if n0 >= 0 and nt >= 0:
            thrust = p.cp_forward * nn
        elif n0 <= 0 and nt <= 0:
            thrust = p.cp_reverse * nn
        else:
            thrust = np.where(n >= 0, p.cp_forward, p.cp_reverse) * nn
        current = laws.current_from_speed(absn, self._cn, self._idle)
        thrust_sd = np.hypot(p.vibration_noise_frac * thrust, p.force_noise_n)
        weight, drop = self._ventilation(t)
        if weight is not None:
            thrust_sd = np.hypot(thrust_sd, p.cav_noise_frac * weight * thrust)
            current = current * (1.0 - p.cav_current_drop * drop)
            thrust = thrust * (1.0 - drop)
        z = self._block_rows(size)
        z[p.thrust_channel] *= thrust_sd
        z[_THRUST], z[_TIME], z[_SPEED], z[_CURRENT] = thrust, t, n, current
        ft = z[: _ONE + 1].T @ self._ft_mix
        speed, current_fb, voltage = self._fb_mix @ z[_ONE:]
        self._n = float(n[-1]) if isinstance(n, np.ndarray) else float(n)
        self._m = float(m[-1]) if isinstance(m, np.ndarray) else float(m)
        self._t = t1
        thrust_true = thrust if isinstance(thrust, np.ndarray) else np.full(size, thrust)
        temperature = self._temperature(t, float(np.mean(current))) if self._heat else None
        return TwinSamples(ft, thrust_true, speed, current_fb, voltage, temperature)

    def _temperature(self, t: np.ndarray, current_a: float) -> np.ndarray:
        """Motor temperature at `t` under a block's mean current (first-order heating and
        cooling, exact for a constant current), advancing the thermal state to t[-1]."""
        p = self.profile
        steady = p.ambient_c + p.heating_c_per_a2_s * current_a**2 * p.thermal_tau_s
        temp = steady + (self._temp_c - steady) * np.exp(-(t - self._temp_t) / p.thermal_tau_s)
        self._temp_c, self._temp_t = float(temp[-1]), float(t[-1])
        return temp

    def steady_state(self, command: float) -> tuple[float, float, float]:
        """Noise-free steady (speed_rpm, thrust_n, current_a) at `command`, without ventilation."""
        p = self.profile
        n = self.target_speed_rpm(min(max(float(command), p.command_min), p.command_max))
        return n, self._thrust(n), float(laws.current_from_speed(n, self._cn, self._idle))

    def target_speed_rpm(self, command: float) -> float:
        """Speed the propeller settles at under `command` (already within range) at the
        supply voltage in force."""
        p = self.profile
        if self._supply_v <= 0:
            return 0.0
        scale = 1.0 if p.speed_loop else self._supply_v / p.supply_voltage_v
        if p.command_map == "pwm_table":
            f = pwm_thrust_n(p, command)
            n = math.sqrt(abs(f) / (p.cp_forward if f > 0 else p.cp_reverse))
            return math.copysign(scale * n, f)
        u = command - p.neutral
        span = (p.command_max if u > 0 else p.command_min) - p.neutral
        if abs(u) <= p.deadband or abs(span) <= p.deadband:
            return 0.0
        frac = min(1.0, (abs(u) - p.deadband) / (abs(span) - p.deadband))
        return math.copysign(scale * frac * p.max_speed_rpm, u)

    def onset_rate_per_s(self, speed_rpm: float, depth_m: float | None = None) -> float:
        """Ventilation onset rate at `speed_rpm` and `depth_m` (default: current depth), 1/s."""
        base = self._base_rate if depth_m is None else self._depth_rates(depth_m)[0]
        p = self.profile
        if base == 0.0 or abs(speed_rpm) < p.cav_min_speed_rpm:
            return 0.0
        return base * (abs(speed_rpm) / p.cav_ref_speed_rpm) ** p.cav_speed_exponent

    def mean_duration_s(self, depth_m: float | None = None) -> float:
        """Mean ventilation event duration at `depth_m` (default: current depth), s."""
        return self._mean_duration if depth_m is None else self._depth_rates(depth_m)[1]

    # ----- internals -----

    def _thrust(self, n: float) -> float:
        """Noise-free thrust at speed n without ventilation."""
        return (self.profile.cp_forward if n >= 0 else self.profile.cp_reverse) * n * abs(n)

    def _speed_at(self, t: float) -> float:
        """Speed at time t >= self._t under the current command."""
        return self._n_target + (self._n - self._n_target) * math.exp(
            (self._t - t) / self.profile.tau_s
        )

    def _states_at(self, t: np.ndarray | float) -> tuple:
        """(speed, inflow) at times t >= self._t: n first order towards the target, the
        inflow m first order towards n (exact solution of the linear pair)."""
        p = self.profile
        if p.speed_law != "linear" or p.inflow_law != "linear":
            return self._integrate(t)
        c, e = self._n_target, self._n - self._n_target
        s = np.asarray(t, dtype=float) - self._t
        tn, ta = p.tau_s, p.inflow_tau_s
        if abs(tn - ta) < 1e-9 * tn:
            ta = tn * (1 + 1e-6)  # equal constants: the limit, to rounding
        fast = np.exp(-s / tn)
        a = e * tn / (tn - ta)
        m = c + a * fast + (self._m - c - a) * np.exp(-s / ta)
        return c + e * fast, m

    def _integrate(self, t: np.ndarray | float) -> tuple:
        """(speed, inflow) at increasing times t >= self._t by fixed-step RK4 (the nonlinear
        laws have no closed form here; the analysis' closed forms are checked against this)."""
        p = self.profile
        times = np.atleast_1d(np.asarray(t, dtype=float))
        h_max = min(p.tau_s, p.inflow_tau_s) / _RK4_PER_TAU
        n_out, m_out = np.empty(times.size), np.empty(times.size)
        now, n, m = self._t, self._n, self._m
        for i, target in enumerate(times):
            span = max(float(target) - now, 0.0)
            steps = max(1, math.ceil(span / h_max)) if span > 0 else 0
            for _ in range(steps):
                n, m = self._rk4(n, m, span / steps)
            now = max(now, float(target))
            n_out[i], m_out[i] = n, m
        if np.ndim(t) == 0:
            return n_out[0], m_out[0]
        return n_out, m_out

    def _rk4(self, n: float, m: float, h: float) -> tuple[float, float]:
        """One classical Runge-Kutta step of the speed and inflow laws."""
        k1 = self._rates(n, m)
        k2 = self._rates(n + 0.5 * h * k1[0], m + 0.5 * h * k1[1])
        k3 = self._rates(n + 0.5 * h * k2[0], m + 0.5 * h * k2[1])
        k4 = self._rates(n + h * k3[0], m + h * k3[1])
        return (n + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
                m + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))

    def _rates(self, n: float, m: float) -> tuple[float, float]:
        """(n', m') under the profile's speed and inflow laws at the target in force."""
        p = self.profile
        nt, top = self._n_target, p.max_speed_rpm
        if p.speed_law == "quadratic":
            dn = (nt * abs(nt) - n * abs(n)) / (2 * p.tau_s * top)
        else:
            dn = (nt - n) / p.tau_s
        if p.inflow_law == "healey":
            return dn, (n * abs(n) - m * abs(m)) / (2 * p.inflow_tau_s * top)
        return dn, (n - m) / p.inflow_tau_s

    def _depth_rates(self, depth_m: float) -> tuple[float, float]:
        """(onset rate at the reference speed, mean duration) at a depth; rate 0 if off or deep."""
        p = self.profile
        duration = math.exp(float(np.interp(depth_m, self._log_depths, self._log_duration)))
        if not p.cavitation or depth_m >= p.cav_max_depth_m:
            return 0.0, duration
        return math.exp(-float(np.interp(depth_m, self._log_depths, self._log_onset))), duration

    def _set_depth_rates(self) -> None:
        """Cache the depth-dependent cavitation rates (depth changes rarely)."""
        self._base_rate, self._mean_duration = self._depth_rates(self.depth_m)

    def _advance(self, t: float) -> None:
        """Run cavitation and speed state forward to t, applying delayed commands as they
        fall due."""
        if t < self._t - _TIME_SLACK_S:
            raise ValueError(f"time {t} lies before the twin's time {self._t}")
        t = max(t, self._t)
        while self._pending and self._pending[0][0] <= t:
            due, command = self._pending.popleft()
            self._run_to(max(due, self._t))
            self._apply_command(command)
        self._run_to(t)

    def _run_to(self, t: float) -> None:
        """Cavitation and speed state from the twin's time to t under the command in force."""
        self._cavitate(t)
        n, m = self._states_at(t)
        self._n, self._m = float(n), float(m)
        self._t = t

    def _block_rows(self, size: int) -> np.ndarray:
        """The next `size` columns of the work block, fresh normals in its noise rows."""
        if self._pos + size > self._block.shape[1]:
            block = self._block if size <= _BLOCK_SAMPLES else _new_block(size)
            self._rng.standard_normal(out=block[:6])
            self._rng.standard_normal(out=block[_ONE + 1 : _ONE + 4])
            if block is not self._block:
                return block
            self._pos = 0
        self._pos += size
        return self._block[:, self._pos - size : self._pos]

    def _end_active_event(self) -> None:
        """Let an ongoing event recover now (propeller stopped or taken deep)."""
        ev = self._active
        if ev is not None:
            ev.t_end_s = min(ev.t_end_s, max(self._t + self.profile.cav_ramp_out_s, ev.t_start_s))

    def _cavitate(self, t1: float) -> None:
        """Generate ventilation onsets in [self._t, t1]: Poisson, rate from speed and depth."""
        if self._active is None and self._base_rate == 0.0:
            return
        t = self._t
        while t < t1:
            ev = self._active
            if ev is not None:
                if ev.t_end_s >= t1:
                    return
                t, self._active = max(t, ev.t_end_s), None
                continue
            rate = self.onset_rate_per_s(self._speed_at(0.5 * (t + t1)))
            if rate <= 0.0:
                return
            if t + self._hazard / rate > t1:
                self._hazard -= rate * (t1 - t)
                return
            t += self._hazard / rate
            p = self.profile
            shape = p.cav_duration_shape
            duration = self._rng.gamma(shape, self._mean_duration / shape)
            drop = self._rng.uniform(p.cav_drop_min, p.cav_drop_max)
            self._active = VentilationEvent(t, t + duration, drop, self.depth_m, self._speed_at(t))
            self.events.append(self._active)
            self._hazard = self._rng.standard_exponential()

    def _ventilation(self, t: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(ventilation weight 0..1, thrust drop fraction) at times t, or (None, None) if none."""
        events = self.events
        while self._live < len(events) and events[self._live].t_end_s <= t[0]:
            self._live += 1
        weight = drop = None
        p = self.profile
        rin, rout = max(p.cav_ramp_in_s, 1e-9), max(p.cav_ramp_out_s, 1e-9)
        for ev in events[self._live :]:
            if ev.t_start_s >= t[-1]:
                break
            w = np.clip(np.minimum((t - ev.t_start_s) / rin, (ev.t_end_s - t) / rout), 0.0, 1.0)
            weight = w if weight is None else weight + w
            drop = ev.drop_frac * w if drop is None else drop + ev.drop_frac * w
        return weight, drop


def _concat(a: TwinSamples, b: TwinSamples) -> TwinSamples:
    """Two consecutive blocks of samples as one."""
    temperature = (None if a.temperature_c is None or b.temperature_c is None
                   else np.concatenate((a.temperature_c, b.temperature_c)))
    return TwinSamples(*(np.concatenate((x, y)) for x, y in
                         zip((a.ft, a.thrust_true_n, a.speed_rpm, a.current_a, a.voltage_v),
                             (b.ft, b.thrust_true_n, b.speed_rpm, b.current_a, b.voltage_v),
                             strict=True)), temperature)


def pwm_thrust_n(p: ThrusterProfile, command: float) -> float:
    """Steady-state thrust of the STM32 PWM table at a PWM value (rounded to an integer count)."""
    c = math.floor(command + 0.5)

    def line(c0: int, f0: float, c1: int, f1: float) -> float:
        return f0 + (f1 - f0) * (c - c0) / (c1 - c0)

    if c < p.pwm_fwd_start or p.pwm_fwd_end < c < p.pwm_rev_creep_start:
        return 0.0
    if c <= p.pwm_fwd_sat_end:
        return p.thrust_fwd_max_n
    if c <= p.pwm_fwd_end:
        return line(p.pwm_fwd_sat_end, p.thrust_fwd_max_n, p.pwm_fwd_end, p.thrust_fwd_min_n)
    if c < p.pwm_rev_breakaway:
        last = p.pwm_rev_breakaway - 1
        if last == p.pwm_rev_creep_start:
            return p.thrust_rev_creep_start_n
        return line(
            p.pwm_rev_creep_start, p.thrust_rev_creep_start_n, last, p.thrust_rev_creep_end_n
        )
    if c < p.pwm_rev_sat_start:
        return line(
            p.pwm_rev_breakaway, p.thrust_rev_breakaway_n, p.pwm_rev_sat_start, p.thrust_rev_max_n
        )
    return p.thrust_rev_max_n
