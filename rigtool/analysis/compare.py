"""Thruster-to-thruster comparison: overlay command curves and find per-thruster command maps.

For each thruster i and branch (forward / reverse thrust) the correction is an affine command
map c_i = a * c + b: a controller that wants the reference thrust F_ref(c) sends c_i to
thruster i. It is fitted by least squares to the exact matching commands F_i^-1(F_ref(c)) over
the shared usable range: thrust levels every thruster reaches on that branch, outside dead zones
and saturation, above `floor_frac` of the shared maximum. `a` absorbs a thrust gain (for
f ~ c^2 a gain g becomes a = 1/sqrt(g)) and `b` the dead-zone shift. A thrust-domain fit
F_ref ~ g * F_i + o is reported beside it for information.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import PchipInterpolator

from rigtool.analysis.results import CalibrationResult
from rigtool.errors import UsageError

BRANCHES = {"forward": 1, "reverse": -1}
GRID = 2001  # samples per branch used to invert a curve
REF_GRID = 401  # reference commands per branch where the match is evaluated


@dataclass
class ThrusterCurve:
    """Mean thrust (sensor zero removed) per command of one run, sorted by command."""

    run_id: str
    label: str
    command: np.ndarray
    thrust_n: np.ndarray
    dead_zones: list[tuple[float, float]] = field(default_factory=list)
    saturated: list[tuple[float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.command.size < 4:
            raise UsageError(f"run {self.run_id}: fewer than 4 commands, cannot compare")
        self.f = PchipInterpolator(self.command, self.thrust_n)

    def excluded(self, c: np.ndarray) -> np.ndarray:
        """True for commands in a dead zone or a saturated range."""
        out = np.zeros(c.shape, dtype=bool)
        for lo, hi in self.dead_zones + self.saturated:
            out |= (c >= lo) & (c <= hi)
        return out


@dataclass
class BranchCurve:
    """One thrust direction of a curve as an invertible map: |thrust| <-> command."""

    command: np.ndarray  # command grid, ordered so that magnitude rises
    magnitude: np.ndarray  # monotone |thrust| on that grid

    @property
    def span(self) -> tuple[float, float]:
        return float(self.magnitude[0]), float(self.magnitude[-1])

    def inverse(self, magnitude: np.ndarray) -> np.ndarray:
        return np.interp(magnitude, self.magnitude, self.command)


@dataclass
class Correction:
    """Per-thruster, per-branch correction and how well it makes the thrusters match."""

    run_id: str
    label: str
    branch: str
    a: float
    b: float
    command_lo: float
    command_hi: float
    thrust_gain: float
    thrust_offset_n: float
    max_dev_before: float
    max_dev_after: float
    rms_dev_after: float
    n: int

    def apply(self, command: np.ndarray) -> np.ndarray:
        return self.a * np.asarray(command, dtype=float) + self.b


@dataclass
class BranchMatch:
    """Arrays of one branch for plotting: reference commands and thrust before/after."""

    branch: str
    command: np.ndarray
    reference_n: np.ndarray
    before_n: dict[str, np.ndarray]
    after_n: dict[str, np.ndarray]
    thrust_lo_n: float
    thrust_hi_n: float


@dataclass
class CompareResult:
    """Everything `rigtool compare` found; deviations are fractions (0.02 = 2 %)."""

    command_unit: str
    reference_run: str | None
    reference_label: str
    curves: list[ThrusterCurve]
    corrections: list[Correction]
    matches: list[BranchMatch]
    spread_before: float
    spread_after: float
    floor_frac: float
    warnings: list[str] = field(default_factory=list)


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _longest(mask: np.ndarray) -> np.ndarray:
    """Only the longest contiguous run of True kept."""
    segs = _segments(mask)
    out = np.zeros(mask.shape, dtype=bool)
    if segs:
        a, b = max(segs, key=lambda s: s[1] - s[0])
        out[a:b] = True
    return out


def branch_curve(curve: ThrusterCurve, sign: int) -> BranchCurve | None:
    """The usable part of one branch (live, unsaturated, thrust of `sign`), or None."""
    c, f = curve.command, curve.thrust_n
    live = _longest(~curve.excluded(c) & (sign * f > 0))
    if live.sum() < 2:
        return None
    grid = np.linspace(c[live][0], c[live][-1], GRID)
    mag = sign * curve.f(grid)
    if mag[-1] < mag[0]:
        grid, mag = grid[::-1], mag[::-1]
    return BranchCurve(grid, np.maximum.accumulate(mag))


def _reference(curves: list[ThrusterCurve], ref: ThrusterCurve | None) -> tuple[
        np.ndarray, np.ndarray, np.ndarray]:
    """Reference commands, thrust there, and the mask of commands no curve excludes."""
    if ref is not None:
        grid = np.linspace(ref.command[0], ref.command[-1], REF_GRID * 2)
        return grid, ref.f(grid), ~ref.excluded(grid)
    lo = max(c.command[0] for c in curves)
    hi = min(c.command[-1] for c in curves)
    if hi <= lo:
        raise UsageError("the runs share no command range: nothing to compare")
    grid = np.linspace(lo, hi, REF_GRID * 2)
    ok = np.ones(grid.size, dtype=bool)
    for c in curves:
        ok &= ~c.excluded(grid)
    return grid, np.mean([c.f(grid) for c in curves], axis=0), ok


def _rel(f: np.ndarray, ref: np.ndarray) -> np.ndarray:
    return np.abs(f - ref) / np.abs(ref)


def _spread(values: list[np.ndarray]) -> float:
    stack = np.vstack(values)
    return float(np.max((stack.max(axis=0) - stack.min(axis=0)) / np.abs(stack.mean(axis=0))))


def compare_curves(curves: list[ThrusterCurve], reference: str | None = None, *,
                   command_unit: str = "", floor_frac: float = 0.1) -> CompareResult:
    """Fit per-thruster command maps that make every curve match the reference (or the mean)."""
    if len(curves) < 2:
        raise UsageError("compare needs at least two runs")
    ref = next((c for c in curves if c.run_id == reference), None) if reference else None
    if reference and ref is None:
        raise UsageError(f"reference run {reference} is not among the compared runs")
    grid, f_ref, ref_ok = _reference(curves, ref)
    corrections: list[Correction] = []
    matches: list[BranchMatch] = []
    warnings: list[str] = []
    spreads_before, spreads_after = [], []
    for name, sign in BRANCHES.items():
        branches = [branch_curve(c, sign) for c in curves]
        if any(b is None for b in branches):
            missing = [c.label for c, b in zip(curves, branches, strict=True) if b is None]
            warnings.append(f"{name} branch: no usable thrust for {', '.join(missing)}; skipped")
            continue
        hi = min(b.span[1] for b in branches)
        lo = max(max(b.span[0] for b in branches), floor_frac * hi)
        mag_ref = sign * f_ref
        use = _longest(ref_ok & (mag_ref >= lo) & (mag_ref <= hi))
        if lo >= hi or use.sum() < 3:
            warnings.append(f"{name} branch: the thrusters share no usable thrust range; skipped")
            continue
        c_ref, r = grid[use], f_ref[use]
        before, after = {}, {}
        for curve, br in zip(curves, branches, strict=True):
            target = br.inverse(sign * r)
            a, b = np.polyfit(c_ref, target, 1)
            corrected = curve.f(a * c_ref + b)
            raw = curve.f(c_ref)
            live = sign * raw > lo
            g, o = np.polyfit(raw[live], r[live], 1) if live.sum() >= 3 else (np.nan, np.nan)
            dev = _rel(corrected, r)
            corrections.append(Correction(
                curve.run_id, curve.label, name, float(a), float(b), float(c_ref.min()),
                float(c_ref.max()), float(g), float(o), float(_rel(raw, r).max()),
                float(dev.max()), float(np.sqrt(np.mean(dev ** 2))), int(use.sum())))
            before[curve.run_id], after[curve.run_id] = raw, corrected
        spreads_before.append(_spread(list(before.values())))
        spreads_after.append(_spread(list(after.values())))
        matches.append(BranchMatch(name, c_ref, r, before, after, float(lo), float(hi)))
    if not matches:
        raise UsageError("no branch with a shared usable thrust range: nothing to correct")
    return CompareResult(command_unit, ref.run_id if ref else None,
                         ref.label if ref else "the mean of the runs", curves, corrections,
                         matches, max(spreads_before), max(spreads_after), floor_frac, warnings)


def curve_from_calibration(cal: CalibrationResult, label: str | None = None) -> ThrusterCurve:
    """Per-command mean thrust of a calibration's largest depth section, with its zones."""
    sec = max(cal.sections, key=lambda s: len(s.points))
    pts = sec.points
    ok = (pts.status == "ok") & np.isfinite(pts.thrust_corrected_n)
    cmd, inv = np.unique(pts.command[ok], return_inverse=True)
    thrust = np.bincount(inv, weights=pts.thrust_corrected_n[ok]) / np.bincount(inv)
    curve = sec.curve
    name = label or cal.thruster_id or cal.run_name
    return ThrusterCurve(cal.run_id, f"{name} ({cal.run_id[-6:]})", cmd, thrust,
                         list(curve.dead_zones) if curve else [],
                         list(curve.saturated) if curve else [])
