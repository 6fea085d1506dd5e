"""Thrust -> command as a vehicle needs it (numpy only): every finite thrust gets a command.

Inside a branch of the inverse table: linear interpolation; each direction's outermost table runs
on to the largest thrust measured. Beyond that: the extreme command (`CLAMPED`). Between zero and the
smallest thrust the thruster makes outside its dead band: the neutral command (`BELOW_MIN`).
Between two branches of one direction: the nearer branch end (`GAP`). NaN only for NaN in.
`strict=True` keeps the older answer, NaN outside every branch. The C header's
`rigtool_command_for_thrust_status` is the same function (docs/artefacts.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

OK, CLAMPED, BELOW_MIN, NAN_INPUT, GAP = 0, 1, 2, 3, 4
STATUS_KEYS = {OK: "ok", CLAMPED: "clamped", BELOW_MIN: "below_min", NAN_INPUT: "nan",
               GAP: "gap"}
Table = tuple[str, np.ndarray, np.ndarray]  # (direction, thrust ascending, command)


@dataclass(frozen=True)
class ThrustMap:
    """One section's inverse tables, each direction's outermost one extended to the largest
    thrust measured (a saturated range the table leaves out), and the neutral command."""

    neutral: float
    tables: tuple[Table, ...]

    def command(self, thrust_n: object, strict: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(command, status) for each thrust (N), in the shape of `thrust_n`; status codes as
        the module says."""
        shape = np.shape(thrust_n)
        f = np.atleast_1d(np.asarray(thrust_n, dtype=float)).ravel()
        out = np.full(f.shape, np.nan)
        status = np.full(f.shape, OK, dtype=int)
        out[f == 0] = self.neutral
        for _, lut_f, lut_c in self.tables:
            take = np.isnan(out) & (f >= lut_f[0]) & (f <= lut_f[-1])
            out[take] = np.interp(f[take], lut_f, lut_c)
        status[np.isnan(f)] = NAN_INPUT
        for direction, sign in (("forward", 1.0), ("reverse", -1.0)):
            self._fill(out, status, f, direction, sign)
        if strict:
            out[status != OK] = np.nan
        return out.reshape(shape), status.reshape(shape)

    def _fill(self, out: np.ndarray, status: np.ndarray, f: np.ndarray, direction: str,
              sign: float) -> None:
        """Commands for the thrusts of one sign that no table holds."""
        todo = np.isnan(out) & ~np.isnan(f) & (sign * f > 0)
        if not todo.any():
            return
        mags = sign * f[todo]
        ends = np.array([(sign * t[i], c[i]) for d, t, c in self.tables
                         if d == direction and t.size for i in (0, -1)]).reshape(-1, 2)
        if not ends.size:
            out[todo], status[todo] = self.neutral, CLAMPED
            return
        cmd = ends[np.abs(ends[:, 0][None, :] - mags[:, None]).argmin(axis=1), 1]
        code = np.full(mags.shape, GAP)
        below, beyond = mags < ends[:, 0].min(), mags > ends[:, 0].max()
        cmd[below], code[below] = self.neutral, BELOW_MIN
        cmd[beyond], code[beyond] = ends[int(ends[:, 0].argmax()), 1], CLAMPED
        out[todo], status[todo] = cmd, code

    def limits(self, direction: str) -> tuple[float, float] | None:
        """(smallest, largest) thrust magnitude (N) the tables give in `direction`."""
        mags = [abs(float(v)) for d, t, _ in self.tables if d == direction and t.size
                for v in (t[0], t[-1])]
        return (min(mags), max(mags)) if mags else None


def thrust_map(tables: Sequence[Table], neutral: float, command: np.ndarray,
               thrust_fit_n: np.ndarray) -> ThrustMap:
    """The map of `tables` with each direction's outermost table run on over the command
    curve (`command`, `thrust_fit_n`) to the largest thrust fitted, where that lies beyond it
    (a saturated range the table leaves out): the curve's points beyond the table's end, by
    distance from its last command, each kept where it gives more thrust than all before, so
    the table stays monotone."""
    c, f = np.asarray(command, dtype=float), np.asarray(thrust_fit_n, dtype=float)
    ok = np.isfinite(c) & np.isfinite(f)
    out = [(d, np.asarray(t, dtype=float), np.asarray(k, dtype=float)) for d, t, k in tables]
    for direction, sign in (("forward", 1.0), ("reverse", -1.0)):
        mine = [i for i, (d, t, _) in enumerate(out) if d == direction and t.size]
        if not mine:
            continue
        i = max(mine, key=lambda j: np.abs(out[j][1]).max())
        d, t, k = out[i]
        end = -1 if sign > 0 else 0
        beyond = ok & (sign * f > abs(t[end]) + 1e-9)
        if not beyond.any():
            continue
        order = np.argsort(np.abs(c[beyond] - k[end]), kind="stable")
        mags, cmds = sign * f[beyond][order], c[beyond][order]
        keep = mags > np.maximum.accumulate(np.concatenate([[abs(t[end])], mags]))[:-1]
        mags, cmds = mags[keep], cmds[keep]
        if sign > 0:
            out[i] = (d, np.concatenate([t, mags]), np.concatenate([k, cmds]))
        else:
            out[i] = (d, np.concatenate([-mags[::-1], t]), np.concatenate([cmds[::-1], k]))
    return ThrustMap(float(neutral), tuple(out))
