"""Read a free-running vehicle log (CSV): time, body velocities and/or pose, thruster commands.

Columns by name: `t_s`; body velocities `u_mps v_mps w_mps p_radps q_radps r_radps`; attitude
`roll_rad pitch_rad` (and `yaw_rad`); position `x_m y_m z_m` (NED); one command column per
thruster. A log with pose but no velocities has them derived (a local polynomial's slope,
turned into body axes). A row with an empty or non-numeric cell is counted and skipped;
time that does not increase is refused, naming the line.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from rigtool.errors import UsageError
from rigtool.files import read_regular_text

MAX_LOG_BYTES = 128 << 20  # a one-hour log at 100 Hz with eight thrusters is ~60 MiB
MAX_ROWS = 400_000  # over two hours at 50 Hz; identification holds ~1 kB per row
VELOCITY_COLUMNS = ("u_mps", "v_mps", "w_mps", "p_radps", "q_radps", "r_radps")
ATTITUDE_COLUMNS = ("roll_rad", "pitch_rad", "yaw_rad")
POSITION_COLUMNS = ("x_m", "y_m", "z_m")
MIN_ROWS = 50
MAX_ANGLE_RAD = 3.5  # beyond pi, an angle column is in degrees
MAX_SPEED_MPS = 10.0  # faster than any thruster-driven vehicle: a log in cm/s or mm/s
RATE_SLACK = 3.0  # how far the attitude's own slopes may disagree with the body rates
GAP_STEPS = 5.0  # a time step this many times the median one is a gap: the log is cut there


@dataclass(frozen=True)
class VehicleLog:
    """One log's rows, checked: times increase, every value is finite."""

    source: str
    t_s: np.ndarray
    nu: np.ndarray  # N x 6 body velocities
    attitude: np.ndarray  # N x 2 roll, pitch (rad)
    commands: np.ndarray  # N x thrusters, in the order asked for
    skipped_rows: int = 0
    derived_velocities: bool = False
    notes: list[str] = field(default_factory=list)


def _header(rows: list[list[str]], path: Path) -> dict[str, int]:
    """Column name -> index; duplicate names are refused."""
    names = [c.strip() for c in rows[0]]
    dup = sorted({n for n in names if names.count(n) > 1 and n})
    if dup:
        raise UsageError(f"{path}:1: columns named twice: {', '.join(dup)}")
    return {n: i for i, n in enumerate(names) if n}


def _parse(text: str, path: Path) -> list[list[str]]:
    """Rows of cells; the first is the header."""
    try:
        rows = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise UsageError(f"{path}: not a CSV table ({exc})") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if len(rows) > MAX_ROWS + 1:
        raise UsageError(f"{path}: more than {MAX_ROWS} rows; split the log")
    if len(rows) < MIN_ROWS + 1:
        raise UsageError(f"{path}: {max(len(rows) - 1, 0)} data rows; a vehicle log needs at "
                         f"least {MIN_ROWS}")
    return rows


def _matrix(rows: list[list[str]], index: list[int]) -> tuple[np.ndarray, np.ndarray, int]:
    """The numeric cells of `index` columns, the file line of each kept row, rows skipped."""
    out, lines, skipped = [], [], 0
    for line, row in enumerate(rows[1:], start=2):
        try:
            values = [float(row[i]) for i in index]
        except (ValueError, IndexError):
            skipped += 1
            continue
        if not all(np.isfinite(values)):
            skipped += 1
            continue
        out.append(values)
        lines.append(line)
    return np.array(out, dtype=float).reshape(-1, len(index)), np.array(lines), skipped


def read_vehicle_log(path: str | Path, command_columns: list[str]) -> VehicleLog:
    """Read and check one log; `command_columns` are the thrusters' columns, in order."""
    path = Path(path)
    rows = _parse(read_regular_text(path, MAX_LOG_BYTES), path)
    cols = _header(rows, path)
    missing = [c for c in ["t_s", *command_columns] if c not in cols]
    if missing:
        raise UsageError(f"{path}:1: no column {', '.join(missing)} (the log has: "
                         f"{', '.join(list(cols)[:20])})")
    has_nu = all(c in cols for c in VELOCITY_COLUMNS)
    has_pose = all(c in cols for c in POSITION_COLUMNS + ATTITUDE_COLUMNS)
    if not has_nu and not has_pose:
        raise UsageError(f"{path}:1: neither body velocities ({' '.join(VELOCITY_COLUMNS)}) nor "
                         f"a pose ({' '.join(POSITION_COLUMNS + ATTITUDE_COLUMNS)})")
    if not all(c in cols for c in ATTITUDE_COLUMNS[:2]):
        raise UsageError(f"{path}:1: no roll_rad and pitch_rad columns: the restoring forces "
                         "need the attitude")
    names = ["t_s", *command_columns, *ATTITUDE_COLUMNS[:2]]
    names += list(VELOCITY_COLUMNS) if has_nu else list(POSITION_COLUMNS) + ["yaw_rad"]
    data, lines, skipped = _matrix(rows, [cols[n] for n in names])
    if len(data) < MIN_ROWS:
        raise UsageError(f"{path}: {len(data)} complete rows ({skipped} skipped for empty or "
                         f"non-numeric cells); a vehicle log needs at least {MIN_ROWS}")
    t = data[:, 0]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise UsageError(f"{path}:{lines[bad[0] + 1]}: t_s does not increase "
                         f"({t[bad[0]]:g} then {t[bad[0] + 1]:g})")
    k = len(command_columns)
    attitude = data[:, 1 + k:3 + k]
    _check_angles(attitude, path)
    rest = data[:, 3 + k:]
    nu = rest if has_nu else _velocities_from_pose(t, rest, attitude)
    _check_speeds(nu, path, has_nu)
    _check_rates(t, nu, attitude, path)
    notes = [] if has_nu else ["body velocities derived from the pose (local polynomial slopes)"]
    if skipped:
        notes.append(f"{skipped} rows skipped for empty or non-numeric cells")
    return VehicleLog(str(path), t - t[0], nu, attitude, data[:, 1:1 + k], skipped,
                      not has_nu, notes)


def split_at_gaps(log: VehicleLog) -> list[VehicleLog]:
    """The log cut wherever a time step exceeds GAP_STEPS median steps (a logger dropout):
    nothing is interpolated across a gap, each part starts its own time at 0."""
    dt = np.diff(log.t_s)
    cuts = np.flatnonzero(dt > GAP_STEPS * np.median(dt)) + 1
    if not cuts.size:
        return [log]
    parts = []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(log.t_s)], strict=True):
        note = (f"{log.source}: cut at a {dt[lo - 1]:.3g} s gap at t = {log.t_s[lo]:g} s"
                if lo else f"{log.source}: split at {cuts.size} time gap(s)")
        parts.append(VehicleLog(log.source, log.t_s[lo:hi] - log.t_s[lo], log.nu[lo:hi],
                                log.attitude[lo:hi], log.commands[lo:hi], 0,
                                log.derived_velocities, [note]))
    return parts


def _check_angles(attitude: np.ndarray, path: Path) -> None:
    """Refuse attitude columns that are plainly in degrees."""
    if np.abs(attitude).max() > MAX_ANGLE_RAD:
        raise UsageError(f"{path}: roll_rad/pitch_rad reach {np.abs(attitude).max():.4g}: "
                         "angles must be in radians")


def _check_speeds(nu: np.ndarray, path: Path, logged: bool) -> None:
    """Refuse linear velocities no thruster-driven vehicle reaches: a log in cm/s or mm/s
    (or positions in cm) would otherwise fit damping 100 times too small."""
    top = float(np.abs(nu[:, :3]).max())
    if top > MAX_SPEED_MPS:
        what = "u_mps/v_mps/w_mps reach" if logged else "the positions give speeds of"
        raise UsageError(f"{path}: {what} {top:.4g} m/s: velocities must be in m/s (and "
                         "positions in m)")


def _check_rates(t: np.ndarray, nu: np.ndarray, attitude: np.ndarray, path: Path) -> None:
    """Refuse body rates that do not turn the logged roll and pitch (deg/s logged as rad/s,
    or a wrong sign convention): the Euler-angle rates they give must match the angles'
    own slopes to within a factor RATE_SLACK."""
    phi, theta = attitude[:, 0], attitude[:, 1]
    p, q, r = nu[:, 3], nu[:, 4], nu[:, 5]
    predicted = np.concatenate((p + (q * np.sin(phi) + r * np.cos(phi)) * np.tan(theta),
                                q * np.cos(phi) - r * np.sin(phi)))
    measured = np.concatenate((np.gradient(phi, t), np.gradient(theta, t)))
    size = float(np.dot(predicted, predicted))
    if size == 0.0 or float(np.dot(measured, measured)) == 0.0:
        return
    slope = float(np.dot(predicted, measured)) / size
    if not 1.0 / RATE_SLACK <= slope <= RATE_SLACK:
        raise UsageError(f"{path}: p/q/r do not match how roll_rad and pitch_rad change (the "
                         f"angles turn {slope:.3g} times as fast as the rates say): rates must "
                         "be rad/s in body axes x forward, y starboard, z down")


def _velocities_from_pose(t: np.ndarray, pose: np.ndarray, attitude: np.ndarray) -> np.ndarray:
    """Body velocities from positions (NED) and Euler angles, via smoothed slopes."""
    dt = float(np.median(np.diff(t)))
    window = max(5, int(round(0.5 / dt)) | 1)
    window = min(window, len(t) if len(t) % 2 else len(t) - 1)
    yaw = np.unwrap(pose[:, 3])
    slope = savgol_filter(np.column_stack((pose[:, :3], attitude, yaw)),
                          window, 2, deriv=1, delta=dt, axis=0)
    out = np.empty((len(t), 6))
    for i, (phi, theta) in enumerate(attitude):
        cf, sf, ct, st = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
        cp, sp = np.cos(yaw[i]), np.sin(yaw[i])
        rot = np.array([[cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
                        [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
                        [-st, ct * sf, ct * cf]])
        out[i, :3] = rot.T @ slope[i, :3]
        d_phi, d_theta, d_psi = slope[i, 3:6]
        out[i, 3:] = (d_phi - st * d_psi, cf * d_theta + sf * ct * d_psi,
                      -sf * d_theta + cf * ct * d_psi)
    return out
