"""The steady thruster laws, written once (numpy only) and used by the runtime models, the API,
the fits' figures and the twin ([Fossen2011], [Luo2020]; docs/references.md):

- thrust from propeller speed: f = C_p |n| n, C_p per direction (forward for n >= 0), or the
  law chosen per direction: C_p n^2 + C_l n or C n^k;
- current from speed: I = C_n |n|^k + I_0 (k = 3, or the free exponent where it replaced 3);
- thrust from current: |f| = C_i max(|I| - I_0, 0)^(2/k), C_i = C_p / C_n^(2/k).

n in r/min, f in N, I in A.
"""

from __future__ import annotations

import numpy as np

from rigtool.units import THRUST_LAWS

CURRENT_EXPONENT = 3.0  # I = C_n |n|^3 + I_0 unless the free law replaced it


def thrust_from_speed(speed_rpm: np.ndarray, cp_fwd: float, cp_rev: float) -> np.ndarray:
    """f = C_p |n| n, C_p_fwd for n >= 0 and C_p_rev below."""
    n = np.asarray(speed_rpm, dtype=float)
    return np.where(n >= 0, cp_fwd, cp_rev) * np.abs(n) * n


def thrust_law(family: str, params: dict[str, float], speed_rpm: np.ndarray) -> np.ndarray:
    """|f| at |n| by a chosen law: "quadratic" C_p n^2, "quadratic+linear" C_p n^2 + C_l n,
    "power" C n^k (rigtool.analysis.thrust_law chooses it)."""
    x = np.abs(np.asarray(speed_rpm, dtype=float))
    if family == "quadratic":
        return params["C_p"] * x**2
    if family == "quadratic+linear":
        return params["C_p"] * x**2 + params["C_l"] * x
    if family == "power":
        return params["C"] * x ** params["k"]
    raise ValueError(f"unknown thrust law {family!r}; known: {', '.join(THRUST_LAWS)}")


def current_from_speed(speed_rpm: np.ndarray, c_n: float, i_0: float,
                       k: float = CURRENT_EXPONENT) -> np.ndarray:
    """I = C_n |n|^k + I_0."""
    return c_n * np.abs(np.asarray(speed_rpm, dtype=float)) ** k + i_0


def current_excess(current_a: np.ndarray, i_0: float) -> np.ndarray:
    """max(|I| - I_0, 0): the current that makes thrust."""
    return np.maximum(np.abs(np.asarray(current_a, dtype=float)) - i_0, 0.0)


def thrust_from_current(current_a: np.ndarray, c_i: float, i_0: float,
                        k: float = CURRENT_EXPONENT) -> np.ndarray:
    """|f| = C_i max(|I| - I_0, 0)^(2/k) (the sign comes from the direction)."""
    return c_i * current_excess(current_a, i_0) ** (2 / k)


def c_i_from(cp: float, c_n: float, k: float = CURRENT_EXPONENT) -> float:
    """C_i = C_p / C_n^(2/k): thrust from current, eliminating the speed."""
    return cp / c_n ** (2 / k)
