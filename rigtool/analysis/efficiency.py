"""Efficiency of each point from its steady means: thrust per electrical watt and shaft power
over electrical power, each with its first-order standard error.

Power is V |I| averaged sample by sample (steady.py); thrust and torque are taken about their
estimated zeros. Thrust per watt is not reported where the data's own resolution (a table's
printed step) would move it by more than steady.MAX_ROUNDING (`efficiency_resolved`).
"""

from __future__ import annotations

import numpy as np

from rigtool.analysis.steady import PointTable

RAD_S_PER_RPM = 2 * np.pi / 60


def efficiency_resolved(points: PointTable) -> np.ndarray:
    """Points whose power and thrust are at or above their resolution floors."""
    ok = np.ones(len(points.step_idx), dtype=bool)
    if points.power_floor_w.size == ok.size:
        ok &= points.power.mean >= points.power_floor_w
    if points.thrust_floor_n.size == ok.size:
        ok &= np.abs(points.thrust_corrected_n) >= points.thrust_floor_n
    return ok


def efficiency_n_per_w(points: PointTable) -> np.ndarray:
    """|thrust| / electrical power (N/W); NaN where the power is not positive or unknown,
    or below the floor the data's resolution supports (`efficiency_resolved`)."""
    p = points.power.mean
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((p > 0) & efficiency_resolved(points),
                        np.abs(points.thrust_corrected_n) / p, np.nan)


def efficiency_se_n_per_w(points: PointTable) -> np.ndarray:
    """Standard error of efficiency_n_per_w (thrust and power errors combined, first order)."""
    f, p = np.abs(points.thrust_corrected_n), points.power.mean
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.hypot(points.thrust.se / f, points.power.se / p)
    return efficiency_n_per_w(points) * rel


def mech_power_w(points: PointTable) -> np.ndarray:
    """Shaft power |Q| |omega| from the point means (W); NaN without torque or speed."""
    return np.abs(points.torque_corrected_nm) * np.abs(points.speed.mean) * RAD_S_PER_RPM


def mech_power_se_w(points: PointTable) -> np.ndarray:
    """Standard error of mech_power_w (torque and speed errors combined, first order)."""
    q, n = np.abs(points.torque_corrected_nm), np.abs(points.speed.mean)
    return np.hypot(points.torque.se * n, np.nan_to_num(points.speed.se) * q) * RAD_S_PER_RPM


def overall_efficiency(points: PointTable) -> np.ndarray:
    """Shaft power over electrical power (motor and driver together), 0..1."""
    p = points.power.mean
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(p > 0, mech_power_w(points) / p, np.nan)


def overall_efficiency_se(points: PointTable) -> np.ndarray:
    """Standard error of overall_efficiency, first order."""
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.hypot(mech_power_se_w(points) / mech_power_w(points),
                       points.power.se / points.power.mean)
    return overall_efficiency(points) * rel
