"""Closed-form step responses of the thruster dynamics models (docs/dynamics.md).

Speed is a state x in forward thrust units: x = sqrt(C_p_fwd) n, so x|x| is the forward thrust
and thrust = c(x) x|x| with c = 1 for x >= 0 and rho = C_p_rev / C_p_fwd for x < 0 (the
direction-dependent steady map as the propeller passes zero). A level of steady thrust F has
the speed target X = sign(F) sqrt(|F| / c(F)). Between command switches:

- one-state (linear lag): x' = (X - x) / tau_n;
- rise-fall: the same lag with tau_n (the rise constant) while |x| grows, x (X - x) >= 0
  (spin-up, and from zero), and tau_fall while it shrinks (spin-down, and down to zero on
  the way through it);
- two-state ([Healey1995] axial inflow): the same x, and m' = (x - m) / tau_a, thrust
  c(x) (x|x| + g (x|x| - m|m|));
- yoerger ([Yoerger1990]): x' = alpha (X|X| - x|x|), quadratic damping, so
  small steps settle more slowly than large ones;
- healey ([Healey1995]): Yoerger's speed with Healey's inflow m' = beta (x|x| - m|m|)
  (quadratic drag on the water column) and thrust c(x) (x|x| + g |x| (x - m));
  healey-lag: the same inflow behind a first-order speed lag (a driver with a speed loop).

The speed is solved exactly between switches, and so is the inflow of the two-state model, so
those responses are evaluated on every sample without an ODE solver. Healey's inflow has no
closed form: it is stepped exactly over nodes (spacing a sixth of `grid_s` at first, wider
later) with the forcing x|x| frozen at its Simpson mean over each step, then from the last node
to each sample the same way. Parameters may be arrays of one batch dimension (B,): the response
is then (B, N), which the fits use for their finite-difference Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS = ("one-state", "two-state", "yoerger", "healey-lag", "healey", "rise-fall")
QUADRATIC_SPEED = frozenset(("yoerger", "healey"))
HEALEY = frozenset(("healey-lag", "healey"))
# Node offsets of Healey's inflow after each switch, in units of grid_s.
NODES = np.concatenate((np.arange(0, 13) / 6, [2.5, 3, 4, 5, 6, 8, 11, 16, 23, 32, 45, 64, 90,
                                               128, 180, 256, 360, 512, 1024]))


@dataclass(frozen=True)
class ModelParams:
    """Dynamics parameters of one model (scalars, or (B,) arrays for a batch)."""

    kind: str
    tau_n: np.ndarray | float = 1.0  # one-state, two-state; rise-fall: its rise constant (s)
    alpha: np.ndarray | float = 1.0  # yoerger (1/(sqrt(N) s))
    tau_a: np.ndarray | float = 1.0  # two-state (s)
    gain: np.ndarray | float = 0.0  # two-state
    delay: np.ndarray | float = 0.0  # s
    rho: np.ndarray | float = 1.0  # C_p_rev / C_p_fwd
    beta: np.ndarray | float = 1.0  # healey inflow (1/(sqrt(N) s))
    grid_s: float = 0.0  # healey node spacing base (s); 0: the speed's time constant
    tau_fall: np.ndarray | float = 1.0  # rise-fall: spin-down time constant (s)


def speed_targets(levels_n: np.ndarray, rho: np.ndarray | float) -> np.ndarray:
    """Speed target X (sqrt(N), forward units) that holds each steady thrust."""
    f = np.asarray(levels_n, dtype=float)
    c = np.where(f >= 0, 1.0, np.asarray(rho, dtype=float)[..., None] if np.ndim(rho) else rho)
    return np.sign(f) * np.sqrt(np.abs(f) / c)


def thrust_response(t_s: np.ndarray, switch_s: np.ndarray, levels_n: np.ndarray,
                    p: ModelParams) -> np.ndarray:
    """Thrust (N, without sensor zero) at `t_s` after levels of steady thrust `levels_n`
    (K,) or (B, K) commanded at `switch_s` (K,), from rest; (N,) or (B, N)."""
    batch = np.ndim(p.delay) > 0 or np.ndim(levels_n) > 1
    b = max(np.size(p.delay), np.shape(levels_n)[0] if np.ndim(levels_n) > 1 else 1)
    par = {k: np.broadcast_to(np.asarray(getattr(p, k), dtype=float), (b,))
           for k in ("tau_n", "alpha", "tau_a", "gain", "delay", "rho", "beta", "tau_fall")}
    lv = np.broadcast_to(np.asarray(levels_n, dtype=float), (b, np.shape(levels_n)[-1]))
    target = speed_targets(lv, par["rho"])
    sw = np.asarray(switch_s, dtype=float)[None, :] + par["delay"][:, None]
    t = np.asarray(t_s, dtype=float)
    if p.kind in HEALEY:
        out = _healey_thrust(p.kind, t, sw, target, par, _grid(p, par, target))
    else:
        x_at, m_at = _switch_states(p.kind, sw, target, par)
        out = _sample_thrust(p.kind, t, sw, target, x_at, m_at, par)
    return out if batch else out[0]


def _switch_states(kind: str, sw: np.ndarray, target: np.ndarray,
                   par: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """States (x, m) at every switch, from rest before the first: (B, K) each."""
    x_at, m_at = np.zeros_like(sw), np.zeros_like(sw)
    for k in range(1, sw.shape[1]):
        dt = sw[:, k] - sw[:, k - 1]
        x_at[:, k], m_at[:, k] = hop(kind, x_at[:, k - 1], m_at[:, k - 1], target[:, k - 1], dt,
                                     par["tau_n"], par["alpha"], par["tau_a"], par["tau_fall"])
    return x_at, m_at


def _sample_thrust(kind: str, t: np.ndarray, sw: np.ndarray, target: np.ndarray,
                   x_at: np.ndarray, m_at: np.ndarray, par: dict[str, np.ndarray]) -> np.ndarray:
    """Thrust on every sample for every batch member: (B, N). Members sharing a delay share
    the level index of each sample (a Jacobian's batch has at most two delays)."""
    out = np.empty((sw.shape[0], t.size))
    delays, group = np.unique(par["delay"], return_inverse=True)
    for g in range(delays.size):
        rows = np.flatnonzero(group == g)
        k = np.searchsorted(sw[rows[0]], t, side="right") - 1
        out[rows] = _rows_thrust(kind, t, k, rows, sw, target, x_at, m_at, par)
    return out


def _rows_thrust(kind: str, t: np.ndarray, k: np.ndarray, rows: np.ndarray, sw: np.ndarray,
                 target: np.ndarray, x_at: np.ndarray, m_at: np.ndarray,
                 par: dict[str, np.ndarray]) -> np.ndarray:
    """Thrust of the batch members `rows`, whose samples fall in levels `k` (-1: before)."""
    after = k >= 0
    kk = k[after]
    col = (rows, None)
    x, m = hop(kind, x_at[rows][:, kk], m_at[rows][:, kk], target[rows][:, kk],
               t[after][None, :] - sw[rows][:, kk], par["tau_n"][col], par["alpha"][col],
               par["tau_a"][col], par["tau_fall"][col])
    xx = x * np.abs(x)
    if kind == "two-state":
        xx = xx + par["gain"][col] * (xx - m * np.abs(m))
    out = np.zeros((rows.size, t.size))
    out[:, after] = np.where(x >= 0, 1.0, par["rho"][col]) * xx
    return out


def _grid(p: ModelParams, par: dict[str, np.ndarray], target: np.ndarray) -> float:
    """Node spacing base: given, or the speed's time constant (at the largest level)."""
    if p.grid_s > 0:
        return p.grid_s
    if p.kind in QUADRATIC_SPEED:
        top = max(float(np.max(np.abs(target[0]))), 1e-6)
        return 1.0 / (2.0 * float(par["alpha"][0]) * top)
    return float(par["tau_n"][0])


def _healey_thrust(kind: str, t: np.ndarray, sw: np.ndarray, target: np.ndarray,
                   par: dict[str, np.ndarray], grid: float) -> np.ndarray:
    """Thrust of the Healey models on every sample: (B, N)."""
    speed = "yoerger" if kind in QUADRATIC_SPEED else "one-state"
    x_at, _ = _switch_states(speed, sw, target, par)
    last = (float(t[-1]) if t.size else 0.0) - float(np.min(sw[:, -1])) + grid
    holds = np.append(np.diff(sw[0]), max(last, 0.0))
    offsets = [NODES[NODES * grid < h] * grid for h in np.maximum(holds, 0.0)]
    node_k = np.concatenate([np.full(o.size, k) for k, o in enumerate(offsets)])
    node_dt = np.concatenate(offsets)
    m_node = _inflow_nodes(speed, node_k, node_dt, holds, target, x_at, par)
    out = np.empty((sw.shape[0], t.size))
    delays, group = np.unique(par["delay"], return_inverse=True)
    for g in range(delays.size):
        rows = np.flatnonzero(group == g)
        node_t = sw[rows[0]][node_k] + node_dt
        i = np.searchsorted(node_t, t, side="right") - 1
        out[rows] = _healey_rows(speed, t, i, rows, node_k, node_dt, sw, target, x_at, m_node,
                                 par)
    return out


def _inflow_nodes(speed: str, node_k: np.ndarray, node_dt: np.ndarray, holds: np.ndarray,
                  target: np.ndarray, x_at: np.ndarray, par: dict[str, np.ndarray]) -> np.ndarray:
    """Inflow at every node, stepped from rest: (B, nodes). Step j runs from node j to node
    j + 1 (or to the end of its hold) under the forcing computed for all steps at once."""
    same = np.append(node_k[1:] == node_k[:-1], False)
    end = np.where(same, np.append(node_dt[1:], 0.0), holds[node_k])
    forcing = _simpson_forcing(speed, x_at[:, node_k], target[:, node_k], node_dt, end, par)
    span = end - node_dt
    m = np.zeros((x_at.shape[0], node_k.size))
    for j in range(node_k.size - 1):
        m[:, j + 1] = quadratic_hop(m[:, j], forcing[:, j], par["beta"],
                                    np.full(m.shape[0], span[j]))
    return m


def _simpson_forcing(speed: str, x0: np.ndarray, target: np.ndarray, a: np.ndarray,
                     b: np.ndarray, par: dict[str, np.ndarray]) -> np.ndarray:
    """Simpson mean of x|x| over [a, b] after the switch (speed from `x0` towards `target`)."""
    xs = [_speed_at(speed, x0, target, np.broadcast_to(tt, np.shape(x0)), par)
          for tt in (a, (a + b) / 2, b)]
    return (xs[0] * np.abs(xs[0]) + 4 * xs[1] * np.abs(xs[1]) + xs[2] * np.abs(xs[2])) / 6


def _speed_at(speed: str, x0: np.ndarray, target: np.ndarray, dt: np.ndarray,
              par: dict[str, np.ndarray]) -> np.ndarray:
    """Speed `dt` after a switch (closed form), broadcasting over batch rows."""
    col = (slice(None),) + (None,) * (np.ndim(x0) - 1)
    return hop(speed, x0, x0, target, np.broadcast_to(dt, np.shape(x0)), par["tau_n"][col],
               par["alpha"][col], par["tau_a"][col])[0]


def _healey_rows(speed: str, t: np.ndarray, i: np.ndarray, rows: np.ndarray,
                 node_k: np.ndarray, node_dt: np.ndarray, sw: np.ndarray, target: np.ndarray,
                 x_at: np.ndarray, m_node: np.ndarray, par: dict[str, np.ndarray]) -> np.ndarray:
    """Healey thrust of the batch members `rows` on samples after node `i` (-1: before)."""
    after = i >= 0
    ii = i[after]
    k = node_k[ii]
    sub = {key: v[rows] for key, v in par.items()}
    dt = t[after][None, :] - sw[rows][:, k]
    x0, tgt = x_at[rows][:, k], target[rows][:, k]
    a = np.broadcast_to(node_dt[ii][None, :], dt.shape)
    forcing = _simpson_forcing(speed, x0, tgt, a, dt, sub)
    m = quadratic_hop(m_node[rows][:, ii], forcing, sub["beta"][:, None], dt - a)
    x = _speed_at(speed, x0, tgt, dt, sub)
    xx = x * np.abs(x) + sub["gain"][:, None] * np.abs(x) * (x - m)
    out = np.zeros((rows.size, t.size))
    out[:, after] = np.where(x >= 0, 1.0, sub["rho"][:, None]) * xx
    return out


def hop(kind: str, x: np.ndarray, m: np.ndarray, target: np.ndarray, dt: np.ndarray,
        tau_n: np.ndarray, alpha: np.ndarray, tau_a: np.ndarray,
        tau_fall: np.ndarray | float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """States after `dt` (>= 0) under the speed target (exact solution)."""
    if kind == "yoerger":
        return quadratic_hop(x, target * np.abs(target), alpha, dt), m
    if kind == "one-state":
        return target + (x - target) * np.exp(-dt / tau_n), m
    if kind == "rise-fall":
        return rise_fall_hop(x, target, dt, tau_n, tau_fall), m
    return linear_hop(x, m, target, dt, tau_n, tau_a)


def rise_fall_hop(x: np.ndarray, target: np.ndarray, dt: np.ndarray, tau_rise: np.ndarray,
                  tau_fall: np.ndarray | float) -> np.ndarray:
    """x' = (X - x) / tau after dt, tau = tau_rise while |x| grows (x (X - x) >= 0), else
    tau_fall: a fall to zero first when x and X have opposite signs, then a rise."""
    x, tgt, dt, tr, tf = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in
                                                (x, target, dt, tau_rise, tau_fall)))
    falls = x * (tgt - x) < 0
    crosses = x * tgt < 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t_zero = np.where(crosses, tf * np.log(np.where(crosses, 1.0 - x / tgt, 1.0)), np.inf)
        fall = tgt + (x - tgt) * np.exp(-dt / tf)
        rise = tgt + (x - tgt) * np.exp(-dt / tr)
        after_zero = tgt * -np.expm1(-np.maximum(dt - t_zero, 0.0) / tr)
    return np.where(falls, np.where(dt < t_zero, fall, after_zero), rise)


def linear_hop(x: np.ndarray, m: np.ndarray, target: np.ndarray, dt: np.ndarray,
               tau_n: np.ndarray, tau_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x' = (X - x)/tau_n, m' = (x - m)/tau_a after dt, stable also for tau_a = tau_n."""
    e = x - target
    en = np.exp(-dt / tau_n)
    ea = np.exp(-dt / tau_a)
    d = 1.0 / tau_a - 1.0 / tau_n
    td = dt * d
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        small = np.abs(td) < 1.0
        d_safe = np.where(d == 0, 1.0, d)
        near = ea * np.where(d == 0, dt, np.expm1(np.where(small, td, 0.0)) / d_safe)
        far = (en - ea) / d_safe
        phi = np.where(small, near, far)  # (e^{-dt/tau_n} - e^{-dt/tau_a}) / d
    return target + e * en, target + (m - target) * ea + e * phi / tau_a


def quadratic_hop(x: np.ndarray, c: np.ndarray, alpha: np.ndarray,
                  dt: np.ndarray) -> np.ndarray:
    """x' = alpha (c - x|x|) after dt (c = X|X|): tanh/coth towards sqrt(c) on the target's
    side, a tangent through zero when the state starts on the other side."""
    x, c, alpha, dt = (np.array(v, dtype=float) for v in
                       np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x, c, alpha, dt))))
    sgn = np.where(x != 0, np.sign(x), np.where(c != 0, np.sign(c), 1.0))
    y0, cc = sgn * x, sgn * c  # frame where the state starts >= 0
    y = np.empty_like(y0)
    toward, free, away = cc > 0, cc == 0, cc < 0
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        y[toward] = _toward(y0[toward], np.sqrt(cc[toward]), alpha[toward], dt[toward])
        y[free] = y0[free] / (1.0 + alpha[free] * y0[free] * dt[free])
        y[away] = _through_zero(y0[away], np.sqrt(-cc[away]), alpha[away], dt[away])
    return sgn * y


def _toward(y0: np.ndarray, r: np.ndarray, alpha: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """y' = alpha (r^2 - y^2) from y0 >= 0: (y - r)/(y + r) decays as exp(-2 alpha r t)."""
    w = (y0 - r) / (y0 + r) * np.exp(-2.0 * alpha * r * dt)
    return r * (1 + w) / (1 - w)


def _through_zero(y0: np.ndarray, q: np.ndarray, alpha: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """y' = -alpha (q^2 + y|y|) from y0 >= 0: a tangent down to zero, then tanh below it."""
    t_zero = np.arctan(y0 / q) / (alpha * q)
    falling = q * np.tan(np.arctan(y0 / q) - alpha * q * np.minimum(dt, t_zero))
    crossed = -q * np.tanh(alpha * q * np.maximum(dt - t_zero, 0.0))
    return np.where(dt < t_zero, falling, crossed)
