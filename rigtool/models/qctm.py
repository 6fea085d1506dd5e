"""Evaluate an exported QCTM-GP thrust model with numpy only (no scikit-learn, no scipy).

    model = load_model("calibrations/<run-id>")
    thrust_n, lo95, hi95 = model.predict(speed_rpm, current_a, depth_m, segment)
    p = model.evaluate(speed_rpm, current_a, depth_m, segment)   # + p.flags, p.distance

Inputs are consecutive block means (`features.block_s`, 0.2 s) of one record; `segment` (one
label per block, default: all one segment) marks where the record is cut (e.g. a new point).
GP inputs x = (n, z, h) with z = f_n(n) * shortfall, shortfall = 1 - |I| / (C_n |n|^3 + I_0)
averaged over a window of `features.window_blocks` blocks within the segment that reaches
`features.lead_blocks` blocks ahead (window_blocks // 2: centred; 0: causal, for a controller).
thrust = f_BETM(n, I) + y_mean + g(z) + sum_j a_j m(r_j) with the gated mean term
g(z) = beta z / (1 + exp(-(|z| - z0) / s)), m(r) = (1 + sqrt5 r + 5 r^2 / 3) exp(-sqrt5 r) and
r_j = || (x - X_j) / (x_scale * length_scales) ||; the noise variance of a new measurement is
exp(log_mean + log_bias + signal_var sum_j b_j m(r'_j)) (heteroscedastic). A model whose GP
signal variance is 0 (format 6, gp.signal false: the default fit) has no a_j and no
posterior-variance file: those terms are 0.

Safety (format 4): a block whose shortfall lies outside `bounds.shortfall` (current dropout,
current below idle, speed and current that disagree) is a current fault: it falls back to the
speed estimate f_n with the interval [0, f_n] widened by f_n's error, and is left out of its
neighbours' shortfall window. The corrected thrust is held between 0 and f_BETM +
`bounds.above_n` in the direction of the speed: a ventilating propeller loses thrust, it never
reverses it. Inputs outside `domain` (per-input ranges, distance to the training rows) are
flagged and their interval widened to that physical prior. See docs/cavitation.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigtool.errors import UsageError
from rigtool.files import check_regular_file, read_regular_bytes
from rigtool.models import laws
from rigtool.models.betm import Betm
from rigtool.models.domain import (
    CLAMPED,
    CURRENT_FAULT,
    OUT_OF_DOMAIN,
    Bounds,
    Domain,
    nearest_distance,
)
from rigtool.readback import INT, STR, Invalid, Obj, brief, parse_json, show

MODEL_FILE = "qctm_gp.json"
VARIANCE_FILE = "qctm_gp_kinv.npy"
FORMAT = "rigtool-qctm-gp"
MAX_MODEL_BYTES = 64 << 20  # qctm_gp.json: a few MB for the largest training budget
MAX_VARIANCE_BYTES = 256 << 20  # qctm_gp_kinv.npy: n_train^2 doubles (2000 rows: 32 MB)
# 7: the loss-side widening for ventilation the shortfall misses (noise.missed_*);
# 6: gp.signal (false: no GP mean or posterior terms, no alpha and no variance file);
# 5: noise bias per regime; 4: bounds, domain; 3: gate, lead_blocks; 2: beta z
FORMAT_VERSION = 7
SIGNAL_ARRAYS = ("alpha", "a_n", "weights", "variance_file")  # absent when gp.signal is false
Z95 = 1.959963984540054
VALIDATED_RUNS = 2  # a model's 95 % intervals are checked run by run from this many runs on
MAX_TRAINING_RUNS = 10_000
SQRT5 = 5.0**0.5
LOG_CHI2_BIAS = 1.2703628454614782  # -E[log chi^2_1]: exp(E[log e^2] + this) = var(e), e Gaussian
FEATURES = ("speed_rpm", "shortfall_thrust_n", "depth_m")


def matern52(a: np.ndarray, b: np.ndarray, length_scales: np.ndarray) -> np.ndarray:
    """Matern nu=5/2 correlation between rows of a and b (already standardised).

    Squared distances as |a|^2 + |b|^2 - 2 a.b (one matrix product, no (n, m, 3) array)."""
    a_s, b_s = np.asarray(a, float) / length_scales, np.asarray(b, float) / length_scales
    d2 = np.einsum("ij,ij->i", a_s, a_s)[:, None] + np.einsum("ij,ij->i", b_s, b_s) - 2.0 * (a_s @ b_s.T)
    s = SQRT5 * np.sqrt(np.maximum(d2, 0.0))
    return (1.0 + s + s * s / 3.0) * np.exp(-s)


def quadratic_rows(k: np.ndarray, m: np.ndarray) -> np.ndarray:
    """k_i . M . k_i for every row i of k: one matrix product (BLAS), not a three-operand
    einsum, whose loops are 20-30 x slower on a GP's training-set sized M."""
    return np.einsum("ij,ij->i", k @ m, k)


def segment_runs(segment: np.ndarray | None, size: int) -> list[tuple[int, int]]:
    """(start, stop) of the runs of equal consecutive labels (one run if `segment` is None)."""
    if segment is None or size == 0:
        return [(0, size)]
    seg = np.asarray(segment)
    cuts = np.flatnonzero(seg[1:] != seg[:-1]) + 1
    edges = np.r_[0, cuts, size]
    return list(zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True))


def window_mean(v: np.ndarray, segment: np.ndarray | None, window: int,
                lead: int | None = None, valid: np.ndarray | None = None) -> np.ndarray:
    """Mean of v over `window` samples ending `lead` samples ahead, truncated at segment ends.

    lead = window // 2 (the default) centres the window; lead = 0 uses past samples only.
    Samples where `valid` is False are left out of every window (0 where a window has none).
    """
    v = np.asarray(v, dtype=float)
    ok = np.ones(v.shape, bool) if valid is None else np.asarray(valid, bool)
    if window <= 1:
        return np.where(ok, v, 0.0)
    half_hi = window // 2 if lead is None else min(max(lead, 0), window - 1)
    half_lo = window - 1 - half_hi
    vals = np.where(ok, v, 0.0)
    out = np.empty_like(v)
    for a, b in segment_runs(segment, v.size):
        c = np.r_[0.0, np.cumsum(vals[a:b])]
        k = np.r_[0, np.cumsum(ok[a:b])]
        j = np.arange(b - a)
        lo, hi = np.maximum(j - half_lo, 0), np.minimum(j + half_hi + 1, b - a)
        count = k[hi] - k[lo]
        out[a:b] = np.where(count > 0, (c[hi] - c[lo]) / np.maximum(count, 1), 0.0)
    return out


def shortfall(betm: Betm, speed_rpm: np.ndarray, current_a: np.ndarray) -> np.ndarray:
    """1 - |I| / (C_n |n|^3 + I_0): the fraction of the expected current that is missing."""
    n = np.asarray(speed_rpm, dtype=float)
    i_hat = laws.current_from_speed(n, betm.c_n, betm.i_0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(i_hat > 0, 1.0 - np.abs(np.asarray(current_a, dtype=float)) / i_hat, 0.0)


def gp_features(betm: Betm, speed_rpm: np.ndarray, current_a: np.ndarray, depth_m: np.ndarray,
                segment: np.ndarray | None = None, window: int = 1,
                lead: int | None = None, valid: np.ndarray | None = None) -> np.ndarray:
    """GP inputs (n, z, h): z = f_n(n) * window mean of the shortfall over `valid` blocks (N)."""
    n, i, h = np.broadcast_arrays(np.atleast_1d(np.asarray(speed_rpm, float)),
                                  np.atleast_1d(np.asarray(current_a, float)),
                                  np.atleast_1d(np.asarray(depth_m, float)))
    short = window_mean(shortfall(betm, n, i), segment, window, lead, valid)
    return np.column_stack([n, betm.speed_estimate(n) * short, h])


def gate(z: np.ndarray, z0: float, s: float) -> np.ndarray:
    """1 / (1 + exp(-(|z| - z0) / s)): ~0 for current noise, ~1 for a real shortfall; 0 if s <= 0."""
    z = np.asarray(z, dtype=float)
    if s <= 0.0:
        return np.zeros(z.shape)
    u = np.clip((np.abs(z) - z0) / s, -700.0, 700.0)  # exp stays finite
    return 1.0 / (1.0 + np.exp(-u))


@dataclass(frozen=True)
class GatedMean:
    """Explicit mean term g(z) = beta z / (1 + exp(-(|z| - z0) / s)) of the GP (s = 0: beta z).

    Outside events z is current noise that a plain linear term would turn into thrust error;
    the gate switches the term off below about z0 (N)."""

    beta: float = 0.0
    z0: float = 0.0
    s: float = 0.0

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        if self.s <= 0.0:
            return self.beta * z
        return self.beta * z * gate(z, self.z0, self.s)

    def to_dict(self) -> dict:
        return {"beta": self.beta, "gate_z0": self.z0, "gate_s": self.s}


@dataclass
class LogNoise:
    """Heteroscedastic noise: var(x) = exp(log_mean + log_bias + k(x)^T alpha) (N^2)."""

    x_mean: np.ndarray
    x_scale: np.ndarray
    length_scales: np.ndarray
    signal_var: float
    log_mean: float
    x_train: np.ndarray  # raw inputs
    alpha: np.ndarray
    log_bias: float = LOG_CHI2_BIAS  # fitted: 95 % of the cross-fitted residuals covered
    # A second bias where the shortfall says "ventilating" (gate(z) -> 1), calibrated on those
    # rows alone: with one bias the many quiet rows set it and events were under-covered.
    log_bias_event: float | None = None  # None: log_bias everywhere
    gate_z0: float = 0.0
    gate_s: float = 0.0
    white_var: float | None = None  # the fit's white-noise level (refits reuse it; not exported)
    # Format 7: ventilation the shortfall misses only ever lowers the thrust, so the interval's
    # loss side is widened by (1 - gate(z)) * missed_lower_n interpolated at |speed| between
    # the missed_speed_rpm knots (numpy.interp); None: no widening.
    missed_speed_rpm: np.ndarray | None = None
    missed_lower_n: np.ndarray | None = None

    def bias(self, x: np.ndarray) -> np.ndarray:
        """log_bias + (log_bias_event - log_bias) gate(z), z = x[:, 1]."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        if self.log_bias_event is None:
            return np.full(len(x), self.log_bias)
        return self.log_bias + (self.log_bias_event - self.log_bias) * gate(
            x[:, 1], self.gate_z0, self.gate_s)

    def deviation(self, x: np.ndarray) -> np.ndarray:
        """The GP part of log var(x): signal_var k(x)^T alpha."""
        xs = (np.asarray(x, dtype=float) - self.x_mean) / self.x_scale
        xt = (self.x_train - self.x_mean) / self.x_scale
        out = np.empty(len(xs))
        for s in range(0, len(xs), 2048):
            k = self.signal_var * matern52(xs[s:s + 2048], xt, self.length_scales)
            out[s:s + 2048] = k @ self.alpha
        return out

    def var_n2(self, x: np.ndarray) -> np.ndarray:
        """Noise variance of a new measurement at inputs x (N^2)."""
        return np.exp(self.log_mean + self.bias(x) + self.deviation(x))

    def missed_lower(self, x: np.ndarray) -> np.ndarray:
        """Loss-side widening (N) at inputs x: (1 - gate(z)) * the missed-ventilation table at
        |speed| (0 without a table)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        if self.missed_speed_rpm is None or self.missed_lower_n is None:
            return np.zeros(len(x))
        table = np.interp(np.abs(x[:, 0]), self.missed_speed_rpm, self.missed_lower_n)
        return (1.0 - gate(x[:, 1], self.gate_z0, self.gate_s)) * table

    def to_dict(self) -> dict:
        out = {"kernel": "matern", "nu": 2.5, "x_mean": self.x_mean.tolist(),
               "x_scale": self.x_scale.tolist(), "length_scales": self.length_scales.tolist(),
               "signal_var": self.signal_var, "log_mean": self.log_mean,
               "log_bias": self.log_bias, "log_bias_event": self.log_bias_event,
               "gate_z0": self.gate_z0, "gate_s": self.gate_s,
               "x_train": self.x_train.tolist(), "alpha": self.alpha.tolist()}
        if self.missed_speed_rpm is not None and self.missed_lower_n is not None:
            out["missed_speed_rpm"] = self.missed_speed_rpm.tolist()
            out["missed_lower_n"] = self.missed_lower_n.tolist()
        return out

    @classmethod
    def from_dict(cls, d: dict) -> LogNoise:
        event = d.get("log_bias_event")
        knots, lower = missed_table(d.get("missed_speed_rpm"), d.get("missed_lower_n"))
        signal_var = float(_finite("signal_var", d["signal_var"]))
        if not 0.0 <= signal_var <= MAX_NOISE_SIGNAL_VAR:
            raise ValueError(f"noise.signal_var {signal_var!r} must be within "
                             f"0..{MAX_NOISE_SIGNAL_VAR:g}")
        x_mean, x_scale, length_scales, x_train = standardisation("noise", d)
        return cls(x_mean, x_scale, length_scales,
                   signal_var, _log_level("log_mean", d["log_mean"]), x_train,
                   bounded("noise.alpha", d["alpha"], -MAX_KERNEL_WEIGHT, MAX_KERNEL_WEIGHT),
                   _log_level("log_bias", d.get("log_bias", LOG_CHI2_BIAS)),
                   None if event is None else _log_level("log_bias_event", event),
                   float(_finite("gate_z0", d.get("gate_z0", 0.0))),
                   float(_finite("gate_s", d.get("gate_s", 0.0))),
                   missed_speed_rpm=knots, missed_lower_n=lower)


def _finite(name: str, value: object, positive: bool = False) -> np.ndarray:
    """A numeric field of the noise model, every value finite (and > 0 where it divides):
    NaN or inf would give NaN or infinite intervals instead of a refusal."""
    a = np.array(value, dtype=float)
    if not np.all(np.isfinite(a)) or (positive and not np.all(a > 0)):
        raise ValueError(f"noise.{name} must be finite" + (" and > 0" if positive else ""))
    return a


def missed_table(knots: object, lower: object) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The missed-ventilation table of a document, checked: both absent (None), or as many
    finite, strictly increasing speed knots (r/min) as finite widenings >= 0 (N)."""
    if knots is None and lower is None:
        return None, None
    k, v = np.array(knots, dtype=float), np.array(lower, dtype=float)
    if (k.ndim != 1 or v.shape != k.shape or k.size == 0 or not np.all(np.isfinite(k))
            or not np.all(np.isfinite(v)) or np.any(v < 0) or np.any(np.diff(k) <= 0)):
        raise ValueError("noise.missed_speed_rpm and noise.missed_lower_n must be as many "
                         "finite values, the speeds strictly increasing, the widths >= 0")
    return k, v


MAX_LOG_LEVEL = 100.0  # |log N^2| of a noise level: e^100 N^2 is far beyond any thruster
MAX_NOISE_SIGNAL_VAR = 1e3  # the noise GP's signal variance: the ceiling every fit has had
MAX_MODEL_VALUE = 1e6  # |any input, centre or level|: r/min, N and m of a thruster are far below
MIN_MODEL_SCALE = 1e-6  # the smallest scale or length scale a standardisation may divide by
MAX_KERNEL_WEIGHT = 1e12  # |alpha|: a GP's weights, normalised units


def bounded(name: str, value: object, lo: float, hi: float) -> np.ndarray:
    """A numeric field of a model file with every value within lo..hi: NaN, inf or values
    so extreme that standardising or squaring them overflows would give NaN or infinite
    intervals (or an overflow at prediction) instead of a refusal."""
    a = np.array(value, dtype=float)
    if not np.all((a >= lo) & (a <= hi)):
        raise ValueError(f"{name} must be finite and within {lo:g}..{hi:g}")
    return a


def standardisation(section: str, d: dict) -> tuple[np.ndarray, ...]:
    """x_mean, x_scale, length_scales and x_train of a kernel section, bounded."""
    big, small = MAX_MODEL_VALUE, MIN_MODEL_SCALE
    return (bounded(f"{section}.x_mean", d["x_mean"], -big, big),
            bounded(f"{section}.x_scale", d["x_scale"], small, big),
            bounded(f"{section}.length_scales", d["length_scales"], small, big),
            bounded(f"{section}.x_train", d["x_train"], -big, big))


def _log_level(name: str, value: object) -> float:
    """A log-variance level of the noise model, finite and within +-MAX_LOG_LEVEL: NaN, inf
    or 1e308 would give NaN or infinite intervals instead of a refusal."""
    level = float(value)  # type: ignore[arg-type]
    if not abs(level) <= MAX_LOG_LEVEL:
        raise ValueError(f"noise.{name} {level!r} is not a finite log variance within "
                         f"+-{MAX_LOG_LEVEL:g}")
    return level


@dataclass
class ThrustModel:
    """BETM + GP correction with 95 % intervals for a new measurement."""

    betm: Betm
    x_mean: np.ndarray
    x_scale: np.ndarray
    length_scales: np.ndarray
    signal_var: float
    noise_var: float
    y_mean: float
    y_std: float
    x_train: np.ndarray  # also the domain's training rows
    alpha: np.ndarray | None  # None: no GP signal (format 6 "signal": false), mean g(z) alone
    k_inv: np.ndarray | None
    noise: LogNoise | None = None  # heteroscedastic noise; None: constant noise_var
    window: int = 1  # shortfall averaging window (blocks)
    lead: int | None = None  # blocks the window reaches ahead (None: window // 2, centred)
    block_s: float = 0.2
    mean_term: GatedMean = GatedMean()  # explicit mean g(z)
    bounds: Bounds = Bounds()
    domain: Domain | None = None  # None in files older than format 4: nothing is flagged
    # How many runs trained it, and whether that is enough for its 95 % intervals to have been
    # checked run by run (VALIDATED_RUNS); None in files written before they were recorded.
    training_runs: int | None = None
    intervals_validated: bool | None = None

    def features(self, speed_rpm: np.ndarray, current_a: np.ndarray, depth_m: np.ndarray,
                 segment: np.ndarray | None = None) -> np.ndarray:
        """GP inputs (n, z, h) of consecutive block means; current faults are left out of the
        shortfall windows (see gp_features and `current_fault`)."""
        n = np.atleast_1d(np.asarray(speed_rpm, float))
        valid = ~self.current_fault(n, current_a) & np.isfinite(n)
        return gp_features(self.betm, n, current_a, depth_m, segment, self.window,
                           self.lead, valid)

    def current_fault(self, speed_rpm: np.ndarray, current_a: np.ndarray) -> np.ndarray:
        """True where the block's current cannot be a ventilating propeller's (see Bounds)."""
        n, i = np.broadcast_arrays(np.atleast_1d(np.asarray(speed_rpm, float)),
                                   np.atleast_1d(np.asarray(current_a, float)))
        s = shortfall(self.betm, n, i)
        lo, hi = self.bounds.shortfall
        return ~(np.isfinite(i) & (s >= lo) & (s <= hi))

    def correction(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(GP mean of f_measured - f_BETM, std of a new measurement) at GP inputs x, N."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        if self.alpha is None:  # signal_var 0: the kernel terms of mean and variance are 0
            var_n2 = np.full(len(x), self.y_std**2 * (max(self.signal_var, 0.0) + self.noise_var))
            if self.noise is not None:
                var_n2 = var_n2 + self.noise.var_n2(x)
            return self.y_mean + self.mean_term(x[:, 1]), np.sqrt(var_n2)
        xs = (x - self.x_mean) / self.x_scale
        xt = (self.x_train - self.x_mean) / self.x_scale
        out_mean = np.empty(len(xs))
        out_var = np.empty(len(xs))
        for s in range(0, len(xs), 2048):
            k = self.signal_var * matern52(xs[s:s + 2048], xt, self.length_scales)
            out_mean[s:s + 2048] = (self.y_mean + self.mean_term(x[s:s + 2048, 1])
                                    + self.y_std * (k @ self.alpha))
            var = np.full(len(k), self.signal_var)
            if self.k_inv is not None:
                var = var - quadratic_rows(k, self.k_inv)
            out_var[s:s + 2048] = np.maximum(var, 0.0) + self.noise_var
        var_n2 = self.y_std**2 * out_var
        if self.noise is not None:
            var_n2 = var_n2 + self.noise.var_n2(x)
        return out_mean, np.sqrt(var_n2)

    def prior_std(self, x: np.ndarray) -> np.ndarray:
        """Std of a new measurement under the GP prior (no training data), N."""
        var = self.y_std**2 * (self.signal_var + self.noise_var)
        if self.noise is not None:
            var = var + self.noise.var_n2(x)
        return np.sqrt(np.broadcast_to(var, (len(x),)))

    def evaluate(self, speed_rpm: np.ndarray, current_a: np.ndarray, depth_m: np.ndarray,
                 segment: np.ndarray | None = None) -> Prediction:
        """Thrust, 95 % interval, flags and domain distance for consecutive block means."""
        n, i, h = np.broadcast_arrays(np.atleast_1d(np.asarray(speed_rpm, float)),
                                      np.atleast_1d(np.asarray(current_a, float)),
                                      np.atleast_1d(np.asarray(depth_m, float)))
        fault = self.current_fault(n, i)
        # a block without a speed reading has no shortfall either: not in any window
        x = gp_features(self.betm, n, i, h, segment, self.window, self.lead,
                        ~fault & np.isfinite(n))
        good = np.all(np.isfinite(x), axis=1)
        x_safe = np.where(good[:, None], x, self.x_mean)
        est = self.betm.fuse(n, np.where(fault, np.nan, i))
        mean, std = self.correction(x_safe)
        raw = est.thrust_n + mean
        # physics: between 0 and f_BETM + above_n, in the direction the propeller turns
        up = np.sign(est.f_n) >= 0
        lo_b = np.where(up, 0.0, np.minimum(0.0, est.thrust_n - self.bounds.above_n))
        hi_b = np.where(up, np.maximum(0.0, est.thrust_n + self.bounds.above_n), 0.0)
        thrust = np.clip(raw, lo_b, hi_b)
        flags = np.where(np.isfinite(raw) & (thrust != raw), CLAMPED, 0)
        lo, hi = thrust - Z95 * std, thrust + Z95 * std
        if self.noise is not None:  # ventilation the shortfall misses: on the loss side only
            miss = self.noise.missed_lower(x_safe)
            lo, hi = np.where(up, lo - miss, lo), np.where(up, hi, hi + miss)
        # outside the training domain: widen to the physical prior [0, f_BETM] +- prior noise
        distance = np.full(len(n), np.inf)
        if self.domain is not None:
            distance[good] = nearest_distance(x[good], self.x_train, self.x_mean, self.x_scale)
            out = self.domain.outside({"speed_rpm": n, "current_a": np.abs(i), "depth_m": h,
                                       "shortfall_thrust_n": x[:, 1]})
            out |= ~(distance <= self.domain.max_distance)
        else:
            out = ~good
        wide = Z95 * self.prior_std(x_safe)
        phys_lo, phys_hi = np.minimum(0.0, est.thrust_n), np.maximum(0.0, est.thrust_n)
        lo = np.where(out, np.minimum(lo, phys_lo - wide), lo)
        hi = np.where(out, np.maximum(hi, phys_hi + wide), hi)
        flags = flags | np.where(out, OUT_OF_DOMAIN, 0)
        # current fault: the speed estimate, anywhere between no loss and total loss
        sd_n = np.sqrt(self.betm.variances(est.f_n)[0])
        f_lo, f_hi = np.minimum(0.0, est.f_n), np.maximum(0.0, est.f_n)
        thrust = np.where(fault, est.f_n, thrust)
        lo = np.where(fault, np.minimum(f_lo - Z95 * sd_n, lo), lo)
        hi = np.where(fault, np.maximum(f_hi + Z95 * sd_n, hi), hi)
        flags = flags | np.where(fault, CURRENT_FAULT, 0)
        bad = ~(np.isfinite(n) & np.isfinite(h))
        nan = np.where(bad, np.nan, 0.0)
        return Prediction(thrust + nan, lo + nan, hi + nan, flags.astype(np.int64), distance)

    def predict(self, speed_rpm: np.ndarray, current_a: np.ndarray, depth_m: np.ndarray,
                segment: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(thrust_n, lo95, hi95) for consecutive block means of speed, current and depth."""
        p = self.evaluate(speed_rpm, current_a, depth_m, segment)
        return p.thrust_n, p.lo95, p.hi95


@dataclass
class Prediction:
    """Per block: thrust, its 95 % interval, flags (models.domain bits) and domain distance."""

    thrust_n: np.ndarray
    lo95: np.ndarray
    hi95: np.ndarray
    flags: np.ndarray
    distance: np.ndarray


DOCUMENT = Obj({"format_version": INT, "gp": Obj({"variance_file": STR})})


class UnreadableModel(UsageError, ValueError):
    """A model folder's file is missing, too large, malformed or of another fit (exit 2)."""


def load_model(calibration_dir: str | Path) -> ThrustModel:
    """Read qctm_gp.json (and qctm_gp_kinv.npy), size-capped and checked, from a folder."""
    folder = Path(calibration_dir)
    path = folder / MODEL_FILE
    try:
        doc = parse_json(read_regular_bytes(path, MAX_MODEL_BYTES))
        DOCUMENT.check(doc)
    except Invalid as exc:
        raise UnreadableModel(f"{path}: {exc}") from None
    if doc.get("format") != FORMAT:
        raise UnreadableModel(f"{path} is not a {FORMAT} document")
    version = doc.get("format_version", 1)
    if version < 2:
        raise UnreadableModel(f"{path} is a version-1 model on raw (n, I, h) inputs: "
                              "rerun rigtool calibrate to refit it")
    if version > FORMAT_VERSION:
        raise UnreadableModel(f"{path} is format version {version}; this rigtool "
                              f"reads up to {FORMAT_VERSION}: update rigtool")
    if "gp" not in doc:
        raise UnreadableModel(f"{path}: field 'gp' is missing")
    name = doc["gp"].get("variance_file", VARIANCE_FILE)
    if name in ("", ".", "..") or Path(name).name != name:
        raise UnreadableModel(f"{path}: gp.variance_file: {show(name)} is not a file name")
    signal = _signal(doc, version, path)
    if not signal and (folder / VARIANCE_FILE).exists():
        raise UnreadableModel(f"{folder / VARIANCE_FILE} is present but {path} has no GP "
                              "signal (gp.signal false): the file belongs to another fit")
    if version >= 6 and signal and not (folder / name).exists():
        raise UnreadableModel(f"{path} has a GP signal (gp.signal true) but its posterior-"
                              f"variance file {folder / name} is missing")
    k_inv = _variance(folder / name) if signal and (folder / name).exists() else None
    try:
        return model_from_document(doc, k_inv)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as exc:
        raise UnreadableModel(f"{path}: {type(exc).__name__}: {brief(exc)}") from None


def _signal(doc: dict, version: int, path: Path) -> bool:
    """Whether the document carries GP signal terms (format 6: gp.signal; older: always),
    refusing a flag that contradicts the fields present."""
    g = doc["gp"]
    if version < 6:
        return True
    signal = g.get("signal")
    if not isinstance(signal, bool):
        raise UnreadableModel(f"{path}: gp.signal must be true or false, found {show(signal)}")
    if signal and "alpha" not in g:
        raise UnreadableModel(f"{path}: gp.signal is true but gp.alpha is missing")
    if not signal:
        present = [k for k in SIGNAL_ARRAYS if k in g]
        if present:
            raise UnreadableModel(f"{path}: gp.signal is false but gp.{present[0]} is present")
        var = g.get("signal_var")
        if isinstance(var, bool) or not isinstance(var, int | float) or var != 0:
            raise UnreadableModel(f"{path}: gp.signal is false but gp.signal_var is "
                                  f"{show(g.get('signal_var'))}, not 0")
    return signal


def _variance(path: Path) -> np.ndarray:
    """The posterior-variance matrix, its .npy header read (memory-mapped) before any copy."""
    try:
        check_regular_file(path, MAX_VARIANCE_BYTES)
        matrix = np.load(path, mmap_mode="r", allow_pickle=False)
        if matrix.ndim != 2 or matrix.dtype.kind != "f":
            raise ValueError(f"a {matrix.dtype} array of shape {matrix.shape}, not a matrix")
        out = np.array(matrix, dtype=float)
        if not (np.isfinite(out).all() and np.abs(out).max(initial=0.0) <= MAX_KERNEL_WEIGHT):
            raise ValueError(f"entries must be finite and within -{MAX_KERNEL_WEIGHT:g}.."
                             f"{MAX_KERNEL_WEIGHT:g} (the posterior variance would be NaN)")
        return out
    except (ValueError, OSError, EOFError) as exc:
        raise UnreadableModel(f"{path}: {brief(exc)}") from None


def gp_scalars(g: dict) -> dict[str, float]:
    """The gp section's levels (required) and mean term (beta and the gate: 0 when absent),
    each bounded."""
    big = MAX_MODEL_VALUE
    levels = {"y_mean": -big, "y_std": MIN_MODEL_SCALE, "signal_var": 0.0, "noise_var": 0.0}
    out = {k: float(bounded(f"gp.{k}", g[k], lo, big)) for k, lo in levels.items()}
    out.update({k: float(bounded(f"gp.{k}", g.get(k, 0.0), -big, big))
                for k in ("beta", "gate_z0", "gate_s")})
    return out


def model_from_document(doc: dict, k_inv: np.ndarray | None = None) -> ThrustModel:
    """A ThrustModel from a qctm_gp.json document (and the posterior-variance matrix, which
    a document without GP signal, format 6 "signal": false, does not use)."""
    b = doc["betm"]
    betm = Betm(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in b.items()})
    g = doc["gp"]
    signal = doc.get("format_version", 1) < 6 or g["signal"] is not False
    x_mean, x_scale, length_scales, x_train = standardisation("gp", g)
    scalars = gp_scalars(g)
    n_train = len(x_train)
    if x_train.shape != (n_train, len(FEATURES)) or n_train == 0:
        raise ValueError(f"gp.x_train is {x_train.shape}, not rows of {len(FEATURES)} inputs")
    alpha = (bounded("gp.alpha", g["alpha"], -MAX_KERNEL_WEIGHT, MAX_KERNEL_WEIGHT)
             if signal else None)
    if alpha is not None and alpha.shape != (n_train,):
        raise ValueError(f"gp.alpha has shape {alpha.shape}, the model has {n_train} "
                         "training rows")
    if not signal:
        k_inv = None
    if k_inv is not None and np.shape(k_inv) != (n_train, n_train):
        raise ValueError(f"the posterior-variance matrix is {np.shape(k_inv)}, the model has "
                         f"{n_train} training rows: it belongs to another fit")
    return ThrustModel(
        betm=betm, x_mean=x_mean, x_scale=x_scale, length_scales=length_scales,
        signal_var=scalars["signal_var"], noise_var=scalars["noise_var"],
        y_mean=scalars["y_mean"], y_std=scalars["y_std"],
        x_train=x_train, alpha=alpha, k_inv=k_inv,
        noise=None if doc.get("noise") is None else LogNoise.from_dict(doc["noise"]),
        window=int(doc.get("features", {}).get("window_blocks", 1)),
        lead=None if doc.get("features", {}).get("lead_blocks") is None
        else int(doc["features"]["lead_blocks"]),
        mean_term=GatedMean(scalars["beta"], scalars["gate_z0"], scalars["gate_s"]),
        block_s=float(doc.get("features", {}).get("block_s", 0.2)),
        bounds=Bounds.from_dict(doc.get("bounds")), domain=Domain.from_dict(doc.get("domain")),
        training_runs=_training_runs(doc.get("training_runs")),
        intervals_validated=_validated(doc.get("intervals_validated")))


def _training_runs(value: object) -> int | None:
    """The document's `training_runs`: a whole number 1..MAX_TRAINING_RUNS, or absent."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not (
            1 <= value <= MAX_TRAINING_RUNS):
        raise ValueError(f"training_runs {value!r} is not a whole number of runs within "
                         f"1..{MAX_TRAINING_RUNS}")
    return value


def _validated(value: object) -> bool | None:
    """The document's `intervals_validated`: true, false, or absent."""
    if value is None or isinstance(value, bool):
        return value
    raise ValueError(f"intervals_validated {value!r} is not true or false")
