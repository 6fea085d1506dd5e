"""BETM at run time: inverse-variance fusion of speed- and current-based thrust (numpy only).

f_n = C_p |n| n (C_p per direction), f_i = s C_i (|I| - I_0)^(2/3) with s the sign of the speed
(|I| - I_0 clamped at 0); both are fused with a prior N(u0, sigma0^2). The consistency test
compares d = |f_n - f_i| / sqrt(sigma_n^2 + sigma_i^2) with gamma: when d > gamma the current
estimate (the noisier one) is dropped for that sample. Fitting lives in rigtool.analysis.betm_fit.

A Betm calibrated over supply voltages carries the voltage its C_n and C_i hold at and the
exponent b of C_n(U) = k U^b; the current estimate then takes the bus voltage as an input,
with C_i(U) = C_i (U / U_cal)^(-2b/3) (C_p does not depend on U).

A thruster whose current does not follow |n|^3 (calibration.json `current_law`) has the
exponent k of I = c_n |n|^k + i_0 in `current_exponent`: f_i = s C_i (|I| - I_0)^(2/k), and
C_i(U) = C_i (U / U_cal)^(-2b/k).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass

import numpy as np

from rigtool.models import laws


@dataclass(frozen=True)
class Betm:
    """Coefficients and variances of the fused thrust estimate; all SI units (N, r/min, A)."""

    cp_fwd: float
    cp_rev: float
    c_n: float
    i_0: float
    ci_fwd: float
    ci_rev: float
    sigma_n: float  # std of the speed-based estimate's own error (N)
    sigma_i: float  # std of the current-based estimate's own error (N)
    sigma_meas: float = 0.0  # force measurement noise at the calibration's time base (N)
    u0: float = 0.0  # prior mean (N)
    sigma0: float = 1e3  # prior std (N); the default is uninformative
    gamma: float = 3.0  # consistency threshold on the normalised distance
    level_n: tuple[float, ...] = ()  # |f_n| knots (N) of the level-dependent stds below
    sigma_n_level: tuple[float, ...] = ()  # std of f_n's error at each knot (N)
    sigma_i_level: tuple[float, ...] = ()  # std of f_i's error at each knot (N)
    voltage_v: float = math.nan  # supply voltage c_n and ci_* hold at (NaN: not calibrated)
    cn_law_b: float = math.nan  # exponent b of C_n(U) = k U^b (NaN: no voltage law)
    current_exponent: float = 3.0  # k of I = c_n |n|^k + i_0 (3: the textbook law)

    def to_dict(self) -> dict:
        """The fields; the voltage pair only where set and the current exponent only where it
        is not 3, so files without them stay as before (and a reader that does not know the
        exponent refuses the file instead of using the wrong law)."""
        out = asdict(self)
        for key in ("voltage_v", "cn_law_b"):
            if math.isnan(out[key]):
                del out[key]
        if out["current_exponent"] == 3.0:
            del out["current_exponent"]
        return out

    @property
    def current_power(self) -> float:
        """The power of |I| - I_0 in the current estimate: 2/k."""
        return 2.0 / self.current_exponent

    def expected_current(self, speed_rpm: np.ndarray) -> np.ndarray:
        """I = c_n |n|^k + i_0 (A) at the given speeds."""
        return self.c_n * np.abs(np.asarray(speed_rpm, dtype=float)) ** self.current_exponent + self.i_0

    def voltage_scale(self, voltage_v: float | np.ndarray | None) -> float | np.ndarray:
        """(U / U_cal)^b, the factor on C_n at supply voltage U; 1 without a voltage law or
        without U."""
        if voltage_v is None or math.isnan(self.voltage_v) or math.isnan(self.cn_law_b):
            return 1.0
        return (np.asarray(voltage_v, dtype=float) / self.voltage_v) ** self.cn_law_b

    def at_voltage(self, voltage_v: float) -> Betm:
        """This Betm with C_n and C_i moved to supply voltage `voltage_v` (V)."""
        k = float(self.voltage_scale(voltage_v))
        if k == 1.0:
            return self
        ci = k ** -self.current_power
        return dataclasses.replace(self, c_n=self.c_n * k, ci_fwd=self.ci_fwd * ci,
                                   ci_rev=self.ci_rev * ci, voltage_v=float(voltage_v))

    def speed_estimate(self, speed_rpm: np.ndarray) -> np.ndarray:
        """f_n = C_p |n| n with the forward or reverse coefficient."""
        return laws.thrust_from_speed(speed_rpm, self.cp_fwd, self.cp_rev)

    def current_estimate(self, current_a: np.ndarray, sign: np.ndarray,
                         voltage_v: np.ndarray | None = None) -> np.ndarray:
        """f_i = sign C_i(U) (|I| - I_0)^(2/k) (k = 3 unless `current_exponent`); sign from
        the speed (or command) direction, U the bus voltage per sample (None: the
        calibration's voltage)."""
        s = np.sign(np.asarray(sign, dtype=float))
        d = laws.current_excess(current_a, self.i_0)
        scale = np.asarray(self.voltage_scale(voltage_v)) ** -self.current_power
        return s * np.where(s >= 0, self.ci_fwd, self.ci_rev) * scale * d**self.current_power

    def variances(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sigma_n^2, sigma_i^2) at thrust level f: interpolated in |f| when knots exist."""
        a = np.abs(np.asarray(f, dtype=float))
        if not self.level_n:
            return np.full(a.shape, self.sigma_n**2), np.full(a.shape, self.sigma_i**2)
        knots = np.asarray(self.level_n)
        return (np.interp(a, knots, np.asarray(self.sigma_n_level)) ** 2,
                np.interp(a, knots, np.asarray(self.sigma_i_level)) ** 2)

    def fuse(self, speed_rpm: np.ndarray, current_a: np.ndarray,
             sign: np.ndarray | None = None, voltage_v: np.ndarray | None = None) -> BetmEstimate:
        """Fused estimate, its variance and the consistency flag for every sample; pass the
        bus voltage `voltage_v` (V) where the calibration has a voltage law."""
        n = np.asarray(speed_rpm, dtype=float)
        f_n = self.speed_estimate(n)
        f_i = self.current_estimate(current_a, n if sign is None else sign, voltage_v)
        return fuse_estimates(f_n, f_i, *self.variances(f_n), self.u0, self.sigma0**2,
                              self.gamma)


@dataclass
class BetmEstimate:
    """Per-sample BETM output: fused thrust, its variance, the two inputs, and the test result."""

    thrust_n: np.ndarray
    var: np.ndarray
    f_n: np.ndarray
    f_i: np.ndarray
    distance: np.ndarray
    consistent: np.ndarray


def fuse_estimates(f_n: np.ndarray, f_i: np.ndarray, var_n: np.ndarray, var_i: np.ndarray,
                   u0: float, var0: float, gamma: float) -> BetmEstimate:
    """Inverse-variance fusion of f_n, f_i and the prior; f_i is dropped where d > gamma.

    A missing current (NaN) counts as dropped.
    """
    f_n = np.asarray(f_n, dtype=float)
    f_i = np.asarray(f_i, dtype=float)
    var_n = np.broadcast_to(np.asarray(var_n, dtype=float), f_n.shape)
    var_i = np.broadcast_to(np.asarray(var_i, dtype=float), f_n.shape)
    with np.errstate(invalid="ignore"):
        d = np.abs(f_n - f_i) / np.sqrt(var_n + var_i)
        ok = np.isfinite(f_i) & (d <= gamma)
    w_n, w_0 = 1.0 / var_n, 1.0 / var0
    w_i = np.where(ok, 1.0 / var_i, 0.0)
    num = f_n * w_n + np.where(ok, f_i, 0.0) * w_i + u0 * w_0
    den = w_n + w_i + w_0
    return BetmEstimate(num / den, 1.0 / den, f_n, f_i, d, ok)
