"""Safety checks on every sample block: debounced limits, and feedback that must follow the command."""

from __future__ import annotations

import bisect
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rigtool.devices.base import ActuatorInfo, FeedbackBlock
from rigtool.errors import SafetyTrip
from rigtool.protocol import Limits


def _run_lengths(mask: np.ndarray, carry: int) -> tuple[int, int]:
    """Longest run of True in `mask` continuing a run of `carry` before it; and the trailing run."""
    if mask.size == 0:
        return carry, carry
    if mask.all():
        total = carry + mask.size
        return total, total
    false_idx = np.flatnonzero(~mask)
    lead = carry + int(false_idx[0])
    trail = int(mask.size - 1 - false_idx[-1])
    edges = np.diff(false_idx) - 1
    inner = int(edges.max()) if edges.size else 0
    return max(lead, trail, inner), trail


@dataclass(frozen=True)
class _Limit:
    """One protocol limit: the quantity it watches, how it compares, its threshold."""

    field: str  # the protocol's field, e.g. max_bus_v
    quantity: str  # the reading checked, e.g. bus_v
    sense: str  # "abs": |x| > threshold; "max": x > threshold; "min": x < threshold
    threshold: float

    def outside(self, v: np.ndarray) -> np.ndarray:
        """Readings beyond the threshold; NaN compares False, so missing data never trips."""
        if self.sense == "abs":
            return np.abs(v) > self.threshold
        return v > self.threshold if self.sense == "max" else v < self.threshold

    def all_within(self, v: np.ndarray) -> bool:
        """Whether a non-empty block has no NaN and no reading beyond the threshold, from its
        extremes alone (a NaN makes them NaN, which compares False)."""
        if not v.size:
            return False
        if self.sense == "max":
            return bool(np.maximum.reduce(v) <= self.threshold)
        if self.sense == "min":
            return bool(np.minimum.reduce(v) >= self.threshold)
        return bool(np.maximum.reduce(v) <= self.threshold
                    and np.minimum.reduce(v) >= -self.threshold)

    def worst(self, v: np.ndarray) -> float:
        """The reading furthest beyond the threshold, as reported in the trip."""
        if self.sense == "abs":
            return float(np.nanmax(np.abs(v)))
        return float(np.nanmax(v) if self.sense == "max" else np.nanmin(v))


UNITS = {"thrust_n": "N", "current_a": "A", "speed_rpm": "r/min", "bus_v": "V", "power_w": "W",
         "torque_nm": "N m", "temperature_c": "degC"}


def protocol_limits(limits: Limits) -> list[_Limit]:
    """The limits a protocol sets, each once (fields left out are not checked)."""
    table = (("max_thrust_n", "thrust_n", "abs"), ("max_current_a", "current_a", "abs"),
             ("max_speed_rpm", "speed_rpm", "abs"), ("min_bus_v", "bus_v", "min"),
             ("max_bus_v", "bus_v", "max"), ("max_power_w", "power_w", "abs"),
             ("max_torque_nm", "torque_nm", "abs"), ("max_temperature_c", "temperature_c", "max"))
    return [_Limit(f, q, sense, getattr(limits, f)) for f, q, sense in table
            if getattr(limits, f) is not None]


SUPPLY_DEBOUNCE = 2  # a supply is read at most every BUS_CHECK_S: two readings in a row trip


NO_READING_S = 3.0  # a limit whose source gives blocks without one valid reading this long trips


class LimitMonitor:
    """Trips (raises SafetyTrip) when a quantity is beyond its limit for `debounce` readings in a row.

    Each quantity is counted in its own readings, per source: force samples for thrust and
    torque, feedback frames for current, speed, bus voltage, power and temperature, and one
    reading per supply measurement (source "supply"; those are at least `BUS_CHECK_S` apart,
    so `SUPPLY_DEBOUNCE` of them in a row trip, or `debounce` if smaller). Only a valid
    reading within the limit restarts the count: a block without readings (a slow source) or
    with NaN ones (a railed thermistor) leaves it as it is. A source that keeps delivering
    blocks with no valid reading for `NO_READING_S` (on the `now` clock) trips too: a lost
    sensor must not turn its limit off.
    """

    def __init__(self, limits: Limits, now: Callable[[], float] | None = None) -> None:
        self.debounce = limits.debounce_samples
        self.limits = protocol_limits(limits)
        self.checks = {lim.quantity for lim in self.limits}
        self._now = now
        self._carry: dict[tuple[str, str], int] = {}
        self._invalid_since: dict[tuple[str, str], float] = {}

    def check(self, values: dict[str, np.ndarray | None], source: str = "") -> None:
        """Judge one block of readings from `source` (the quantities it lacks are None)."""
        for lim in self.limits:
            v = values.get(lim.quantity)
            if v is None:
                continue
            v = np.asarray(v, dtype=float)
            key = (lim.field, source)
            if lim.all_within(v):
                # the common block: every reading valid and within the limit ends any run
                self._invalid_since.pop(key, None)
                self._carry[key] = 0
                continue
            v = v[~np.isnan(v)]
            if v.size == 0:
                self._no_reading(lim, key, source)
                continue
            self._invalid_since.pop(key, None)
            longest, self._carry[key] = _run_lengths(lim.outside(v), self._carry.get(key, 0))
            if longest >= (min(self.debounce, SUPPLY_DEBOUNCE) if source == "supply"
                           else self.debounce):
                self._trip(lim, v, longest, source)

    def _no_reading(self, lim: _Limit, key: tuple[str, str], source: str) -> None:
        """A block with no valid reading: trip once they have lasted `NO_READING_S`."""
        if self._now is None:
            return
        now = self._now()
        since = self._invalid_since.setdefault(key, now)
        if now - since >= NO_READING_S:
            by = f" from the {source}" if source else ""
            raise SafetyTrip(f"limit trip: {lim.field}: no valid reading of {lim.quantity}{by} "
                             f"for {now - since:.1f} s (a lost or railed sensor; limit "
                             f"{NO_READING_S:g} s)",
                             {"check": "limit", "limit": lim.field, "quantity": lim.quantity,
                              "value": None, "threshold": lim.threshold,
                              "unit": UNITS.get(lim.quantity, ""), "readings": 0,
                              "source": source or None, "reason": "no valid reading",
                              "seconds": now - since})

    @staticmethod
    def _trip(lim: _Limit, v: np.ndarray, longest: int, source: str) -> None:
        value = lim.worst(v)
        unit = UNITS.get(lim.quantity, "")
        shown = f"|{lim.quantity}|" if lim.sense == "abs" else lim.quantity
        side = "below" if lim.sense == "min" else "above"
        by = f" (from the {source})" if source else ""
        raise SafetyTrip(f"limit trip: {shown} reached {value:.4g}{by}, {side} the limit "
                         f"{lim.field} {lim.threshold:g} {unit} for {longest} readings in a row",
                         {"check": "limit", "limit": lim.field, "quantity": lim.quantity,
                          "value": value, "threshold": lim.threshold, "unit": unit,
                          "readings": longest, "source": source or None})

    def reset(self) -> None:
        self._carry = {}
        self._invalid_since = {}


FOLLOW_WINDOW_S = 0.2  # feedback is judged as means over windows this long
FOLLOW_SETTLE_S = 1.0  # the command map is checked this long after the command is held (3 tau)
FOLLOW_BAND = {"speed_rpm": 0.5, "current_a": 0.3}  # below this fraction: not following
FOLLOW_MIN_FRAC = 0.1  # the map is checked only where it expects this fraction of full speed
FOLLOW_NOISE_K = 5.0  # a fall counts only after a rise of this many noise deviations
FOLLOW_WINDOWS = 2  # consecutive failing windows before a trip
_MAP_GRID = 801  # commands at which the map is sampled to find its full-scale speed
_MAD_TO_SD = 0.954  # median |x[i+1] - x[i]| of white noise, in noise standard deviations


@dataclass
class _Window:
    """One window of feedback: mean, noise estimate and start time."""

    t0_s: float
    mean: float
    noise: float  # feedback noise or resolution, whichever is larger; NaN with too few frames


def _median(v: np.ndarray) -> float:
    """np.median of a non-empty array without NaN, from one partition (np.median's NaN check
    and two-element mean cost more than the partition on a window); the same value."""
    half = v.size // 2
    if v.size % 2:
        return float(np.partition(v, half)[half])
    part = np.partition(v, (half - 1, half))
    return (float(part[half - 1]) + float(part[half])) / 2


def _sorted_median(values: list[float]) -> float:
    """np.median of a sorted, non-empty list without NaN (the same value: the middle element,
    or the mean of the two), without converting and partitioning the list on every window."""
    half = len(values) // 2
    if len(values) % 2:
        return values[half]
    return (values[half - 1] + values[half]) / 2


def _window(t: np.ndarray, v: np.ndarray) -> _Window:
    """Mean of a window, and its noise: the standard deviation from successive differences
    (robust to a trend), at least the smallest step between frames (quantised feedback)."""
    mean = float(np.add.reduce(v)) / v.size  # np.mean's sum and division, without its wrapper
    if v.size < 3:
        return _Window(float(t[0]), mean, float("nan"))
    steps = np.abs(v[1:] - v[:-1])
    moved = steps[steps > 0]
    noise = max(_median(steps) / _MAD_TO_SD,
                float(np.minimum.reduce(moved)) if moved.size else 0.0)
    return _Window(float(t[0]), mean, noise)


class FollowMonitor:
    """Trips (raises SafetyTrip) when the actuator's feedback stops following a held command.

    Two checks, both judged on `FOLLOW_WINDOW_S` means of the feedback the driver already
    reads (speed, else current; nothing without either), and both only while the command of
    a point is held:
    - map: where the actuator knows the speed its command should give
      (`expected_speed_rpm`), the speed must reach `FOLLOW_BAND` of it once the command
      has been held `FOLLOW_SETTLE_S`; commands whose expected speed is below
      `FOLLOW_MIN_FRAC` of full speed (dead zones) are not checked.
    - fall: a feedback level that rose clearly during the point (by `FOLLOW_NOISE_K` noise
      deviations from its lowest window) must not fall below `FOLLOW_BAND` of its peak. A
      speed still decaying from the previous point never rises, so a command in a dead
      zone cannot trip it.
    `FOLLOW_WINDOWS` failing windows in a row trip.
    """

    def __init__(self, info: ActuatorInfo,
                 speed_map: Callable[[float], float | None] | None = None) -> None:
        self.signal = next((s for s in ("speed_rpm", "current_a") if s in info.feedback), None)
        self.unit = info.command_unit
        self.band = FOLLOW_BAND.get(self.signal, 0.0)
        self.speed_map = speed_map if self.signal == "speed_rpm" else None
        self.full_scale = self._full_scale(info) if self.speed_map else 0.0
        self._reset(active=False)

    def _full_scale(self, info: ActuatorInfo) -> float:
        """Largest |speed| the map gives over the command range (0: the map knows nothing)."""
        grid = np.linspace(info.command_min, info.command_max, _MAP_GRID)
        speeds = [self.speed_map(c) for c in grid]
        return max((abs(s) for s in speeds if s is not None), default=0.0)

    def start_point(self) -> None:
        """A point begins (its ramp from neutral): forget the previous point."""
        self._reset(active=self.signal is not None)

    def _reset(self, active: bool) -> None:
        self._active = active
        self._hold_t: float | None = None
        self._command = float("nan")
        self._expected: float | None = None
        self._t = np.empty(0)
        self._v = np.empty(0)
        self._trough = float("inf")
        self._peak = 0.0
        self._armed = False  # the level rose clearly during the point: a fall now means a stop
        self._noise: list[float] = []  # the point's window noise levels, kept sorted
        self._failed = 0

    def hold(self, command: float, t_s: float) -> None:
        """The command reached the point's value at time `t_s`; checks apply from now on."""
        self._hold_t, self._command = t_s, command
        expected = self.speed_map(command) if self.speed_map else None
        checkable = expected is not None and abs(expected) >= FOLLOW_MIN_FRAC * self.full_scale > 0
        self._expected = expected if checkable else None

    def release(self) -> None:
        """The point's command is being left (ramp to neutral): stop checking until the next."""
        self._active = False

    def check(self, feedback: FeedbackBlock) -> None:
        """Take the feedback of one read; judge every window it completes."""
        values = getattr(feedback, self.signal) if self._active else None
        if values is None or not len(feedback):
            return
        ok = np.isfinite(values)
        t, v = (feedback.t_s, values) if ok.all() else (feedback.t_s[ok], values[ok])
        if self._t.size:
            t, v = np.concatenate([self._t, t]), np.concatenate([self._v, v])
        self._t, self._v = np.asarray(t, dtype=float), np.asarray(v, dtype=float)
        while self._t.size and self._t[-1] - self._t[0] >= FOLLOW_WINDOW_S:
            cut = int(np.searchsorted(self._t, self._t[0] + FOLLOW_WINDOW_S))
            window = _window(self._t[:cut], self._v[:cut])
            self._t, self._v = self._t[cut:], self._v[cut:]
            self._judge(window)

    def _judge(self, w: _Window) -> None:
        if np.isfinite(w.noise):
            bisect.insort(self._noise, w.noise)
        held = self._hold_t is not None and w.t0_s >= self._hold_t
        problem = self._map_problem(w) if held else None
        problem = problem or (self._fall_problem(w) if held else None)
        if problem is None:
            self._failed = 0
            self._track(abs(w.mean))
            return
        self._failed += 1
        if self._failed >= FOLLOW_WINDOWS:
            held_s = w.t0_s + FOLLOW_WINDOW_S - self._hold_t
            raise SafetyTrip(
                f"actuator not following the command: {self.signal} {w.mean:.4g} with "
                f"{self._command:g} {self.unit} held for {held_s:.2f} s ({problem}); a drive "
                "that timed out (keep-alive, watchdog), was disabled or lost its supply?",
                detail={"check": "follow", "command": self._command, "signal": self.signal,
                        "value": w.mean, "expected": self._expected, "peak": self._peak,
                        "held_s": held_s})

    def _track(self, level: float) -> None:
        """Follow the point's lowest level and the peak after it, until the rise is clear."""
        if not self._armed and level < self._trough:
            self._trough = self._peak = level
        self._peak = max(self._peak, level)
        rise = self._peak - self._trough
        self._armed = self._armed or (
            bool(self._noise) and rise >= FOLLOW_NOISE_K * _sorted_median(self._noise))

    def _map_problem(self, w: _Window) -> str | None:
        """Why the window misses the command map's speed, or None."""
        if self._expected is None or w.t0_s < self._hold_t + FOLLOW_SETTLE_S:
            return None
        if np.sign(self._expected) * w.mean >= self.band * abs(self._expected):
            return None
        return f"expected about {self._expected:.4g}"

    def _fall_problem(self, w: _Window) -> str | None:
        """Why the window is a fall from a level the point clearly reached, or None."""
        if not self._armed or abs(w.mean) >= self.band * self._peak:
            return None
        return f"fell from {self._peak:.4g} earlier in the point"


BUS_CHECK_S = 0.5  # the supply's own measurement is read at most this often during a point
BUS_FLOOR_V = 0.5  # the actuator's band is never narrower than this
BUS_WINDOWS = 2  # actuator blocks outside the band in a row that trip (its readings are noisy)
SUPPLY_BAND_FRAC = 0.03  # a supply in constant-voltage mode holds its terminals this close...
SUPPLY_FLOOR_V = 0.25  # ...or this close, whichever is wider (setpoint and meter accuracy)
CC_FRACTION = 0.97  # a supply delivering this much of its current limit is current-limited


class BusVoltageMonitor:
    """Trips when the bus is not at the voltage a point is labelled with.

    Two witnesses. The supply's own measurement of its terminals (at most every
    `BUS_CHECK_S`, and once more before a point is stored): a supply in constant-voltage mode
    holds them within `SUPPLY_BAND_FRAC` (at least `SUPPLY_FLOOR_V`) of the setpoint, so one
    reading outside that, or a current at `CC_FRACTION` of the limit with the voltage below
    the setpoint, trips at once: constant-current mode, a supply switched off by its protection
    or by hand. The actuator's voltage feedback (the median of each block) sees the bus after
    the leads, sag included, so it gets the protocol's `tolerance_frac` (at least
    `BUS_FLOOR_V`) and `BUS_WINDOWS` blocks in a row; it also covers a manual supply set
    wrong. No point is stored under a voltage it did not have."""

    def __init__(self, tolerance_frac: float) -> None:
        self.tolerance_frac = tolerance_frac
        self._outside = 0
        self._last_supply_check = -np.inf

    def band_v(self, set_v: float) -> float:
        """Half-width of the actuator feedback's band around `set_v`."""
        return max(BUS_FLOOR_V, self.tolerance_frac * set_v)

    @staticmethod
    def supply_band_v(set_v: float) -> float:
        """Half-width of the supply measurement's band around `set_v`."""
        return max(SUPPLY_FLOOR_V, SUPPLY_BAND_FRAC * set_v)

    def supply_due(self, now: float) -> bool:
        """Whether the supply's measurement should be read now (and mark it read)."""
        if now - self._last_supply_check < BUS_CHECK_S:
            return False
        self._last_supply_check = now
        return True

    def check_supply(self, set_v: float, measured_v: float, source: str,
                     current_a: float | None = None, limit_a: float | None = None) -> None:
        """One reading of the supply's terminals: outside its band, or current-limited, trips."""
        band = self.supply_band_v(set_v)
        limited = (current_a is not None and limit_a is not None
                   and current_a >= CC_FRACTION * limit_a and measured_v < set_v - SUPPLY_FLOOR_V)
        if not limited and abs(measured_v - set_v) <= band:
            return
        why = (f"current-limited at {current_a:.3g} A (limit {limit_a:g} A)" if limited
               else f"outside {set_v:g} ± {band:.2g} V")
        self._trip(set_v, measured_v, source, why,
                   {"current_a": current_a, "limit_a": limit_a, "band_v": band})

    def check_feedback(self, set_v: float, measured_v: float) -> None:
        """The median of a block of the actuator's voltage feedback (NaN: none)."""
        if not np.isfinite(measured_v) or abs(measured_v - set_v) <= self.band_v(set_v):
            self._outside = 0
            return
        self._outside += 1
        if self._outside >= BUS_WINDOWS:
            self._outside = 0
            self._trip(set_v, measured_v, "actuator",
                       f"outside {set_v:g} ± {self.band_v(set_v):.2g} V",
                       {"band_v": self.band_v(set_v)})

    @staticmethod
    def _trip(set_v: float, measured_v: float, source: str, why: str, detail: dict) -> None:
        raise SafetyTrip(
            f"supply voltage trip: the {source} measures {measured_v:.3g} V at a {set_v:g} V "
            f"point, {why}; the point is not stored under {set_v:g} V",
            {"check": "bus_voltage", "set_v": set_v, "measured_v": measured_v,
             "source": source, **detail})
