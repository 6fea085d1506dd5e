"""The table `rigtool calibrate` prints: one row per fitted coefficient and finding, with its
95 % interval, unit and a note."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from rich.table import Table

if TYPE_CHECKING:
    from rigtool.analysis.captive import CaptiveResult
    from rigtool.analysis.dynamics import Dynamics
    from rigtool.analysis.results import CalibrationResult

SummaryRow = tuple[str, float, float, float, str, str]
NAN = math.nan


def calibration_table(cal: CalibrationResult, run_id: str) -> Table:
    """The summary rows as a table; blank where a value or interval does not apply."""
    table = Table("quantity", "value", "95 % interval", "unit", "note",
                  title=f"calibration of run {run_id} ({cal.run_name})")
    for name, value, lo, hi, unit, note in summary_rows(cal):
        interval = f"{_num(lo)} .. {_num(hi)}" if lo == lo or hi == hi else ""
        table.add_row(name, _num(value), interval, unit, note)
    return table


def _num(v: float) -> str:
    return "" if v != v else f"{v:.5g}"  # NaN -> blank


def summary_rows(cal: CalibrationResult) -> list[SummaryRow]:
    """(name, value, lo, hi, unit, note) rows; NaN where not applicable. A captive run's rows
    are its damping laws (its thruster, held at one command, has none to show)."""
    if cal.captive is not None and len({float(c) for s in cal.sections
                                        for c in s.points.command}) == 1:
        return _captive_rows(cal.captive)
    rows: list[SummaryRow] = []
    multi = len(cal.sections) > 1
    for sec in cal.sections:
        suffix = f" @ {sec.label}" if multi else ""
        for c in sec.fits.values():
            note = c.note if math.isnan(c.r2) else f"R2={c.r2:.4f}, n={c.n}"
            rows.append((c.name + suffix, c.value, c.lo, c.hi, c.unit, note))
        if sec.zero is not None and "zero_drift" not in sec.fits:
            rows.append(("zero_drift" + suffix, sec.zero.drift_n_per_s * 3600, NAN, NAN,
                         "N/h", f"sensor zero read from the {sec.zero.source}"))
        if sec.curve is not None:
            u = cal.command_unit
            rows += [("dead_zone" + suffix, NAN, lo, hi, u, "") for lo, hi in
                     sec.curve.dead_zones]
            rows += [("saturated" + suffix, NAN, lo, hi, u, "") for lo, hi in
                     sec.curve.saturated]
            rows += [("break_away" + suffix, c, NAN, NAN, u, "") for c in
                     sec.curve.break_aways]
        if sec.hysteresis is not None:
            rows.append(("hysteresis_max" + suffix, sec.hysteresis.max_abs_n, NAN, NAN, "N",
                         f"at {sec.hysteresis.at_command:g} {cal.command_unit}"))
        if sec.repeatability is not None:
            rows.append(("repeatability_max_std" + suffix, sec.repeatability.max_std_n, NAN,
                         NAN, "N", f"median {sec.repeatability.median_std_n:.4g} N"))
    if cal.drift is not None:
        s = cal.drift.slope
        rows.append((s.name, s.value, s.lo, s.hi, s.unit, f"{s.n} tares"))
    for law in cal.voltage_laws:
        suffix = "" if law.depth_m is None else f" @ {law.depth_m:g} m"
        for c in (law.k_inverse, law.k, law.b):
            rows.append((c.name + suffix, c.value, c.lo, c.hi, c.unit, c.note))
    if cal.dynamics is not None:
        rows += _dynamics_rows(cal.dynamics)
    return rows


def _captive_rows(res: CaptiveResult) -> list[SummaryRow]:
    """Each axis's law coefficients (or its refusal), its zero drift, and drag and lift per
    angle."""
    rows: list[SummaryRow] = []
    for law in res.laws:
        if law.linear is None or law.quadratic is None:
            rows.append((f"{law.force} law", NAN, NAN, NAN, "", law.refused))
            continue
        for c in (law.linear, law.quadratic):
            rows.append((c.name, c.value, c.lo, c.hi, c.unit, f"R2={c.r2:.4f}, n={c.n}"))
        if law.drift is not None:
            d = law.drift
            rows.append((d.name, d.value, d.lo, d.hi, d.unit, "zero drift (nuisance)"))
    for ld in res.lift_drag:
        coefs = (ld.drag_linear, ld.drag_quadratic, ld.lift_linear, ld.lift_quadratic)
        if ld.refused:
            rows.append((f"lift/drag @ {ld.angle_deg:g} deg", NAN, NAN, NAN, "", ld.refused))
        rows += [(f"{c.name} @ {ld.angle_deg:g} deg", c.value, c.lo, c.hi, c.unit, "")
                 for c in coefs if c is not None]
    return rows


def _dynamics_rows(d: Dynamics) -> list[SummaryRow]:
    """The selected model's parameters, or one row saying no dynamics were identified."""
    if not d.identified:
        return [("dynamics", NAN, NAN, NAN, "", f"no dynamics identified: {d.reason}")]
    m = d.model
    return [(c.name, c.value, c.lo, c.hi, c.unit, f"{m.name} model (selected by held-out steps)")
            for c in (m.tau_n_s, m.alpha, m.tau_a_s, m.gain, m.delay_s, m.reverse_ratio)
            if c is not None]
