"""`rigtool calibrate` analysis: a stored run -> a CalibrationResult (one section per depth)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from rigtool.analysis.curves import CURVE_UNITS, CommandCurve, command_curve
from rigtool.analysis.dataset import ACCURACY_KEYS, RunData, Tares, load_run
from rigtool.analysis.depth_fits import (
    STOPPED_FRAC,
    ModelFits,
    candidate_points,
    fit_models,
    speed_sign,
)
from rigtool.analysis.drift_design import (
    MIN_REPEATED,
    DriftDesign,
    drift_design,
    neutral_zero,
    reads_zero,
    repeated_apart,
    row_noise,
    zero_read_apart,
)
from rigtool.analysis.dynamics import Dynamics, StepSeries, identify, no_dynamics_reason
from rigtool.analysis.efficiency import overall_efficiency
from rigtool.analysis.fits import (
    SECONDS_PER_HOUR,
    Z95,
    Coefficient,
    ZeroLine,
    occupied_starts,
    session_index,
    session_line,
    with_bound,
)
from rigtool.analysis.point_pass import SectionSamples, SpreadPass, fill_spreads, point_pass
from rigtool.analysis.quality import (
    drift_over_sweep,
    hysteresis,
    repeatability,
    tare_drift,
)
from rigtool.analysis.results import (
    CalibrationParams,
    CalibrationResult,
    DepthSection,
    TareDrift,
    VoltageLaw,
)
from rigtool.analysis.steady import PointTable
from rigtool.analysis.thrust_law import signed_law
from rigtool.analysis.voltage import fit_voltage_law, voltage_point
from rigtool.analysis.zero_search import ZeroPoints, fit_zero_line, section_anchors
from rigtool.progress_hook import ProgressHook, counted, no_progress
from rigtool.store import Store
from rigtool.version import __version__

NAN = math.nan
# One coefficient per fit is checked for quality (the others share its R2 and n).
CHECKED_FITS = ("C_p_fwd", "C_p_rev", "C_n", "k_free", "C_i_fwd_direct", "C_i_rev_direct")




def calibrate_run(store: Store, run_id: str, params: CalibrationParams | None = None,
                  progress: ProgressHook = no_progress) -> CalibrationResult:
    """Load `run_id` from the store and analyse it."""
    return calibrate(load_run(store, run_id), params, progress)


def calibrate(run: RunData, params: CalibrationParams | None = None,
              progress: ProgressHook = no_progress) -> CalibrationResult:
    """Analyse a loaded run: steady windows, then per depth the curve, fits and quality
    (each section, and a step run's dynamics candidates, reported to `progress`)."""
    p = params or CalibrationParams()
    windows, table = point_pass(run, p.settling)
    spreads = SpreadPass(run, windows)
    drift = run_tare_drift(run.tares, run.session_starts_s)
    warnings = _run_warnings(run, table, drift, p)
    sections = []
    for rows in counted(_groups(run.steps), "fits per depth and supply voltage", progress):
        sec = _section(run, table.take(rows), spreads.section(rows), drift, p)
        volts = run.steps.voltage_v[rows[0]] if run.steps.voltage_v is not None else NAN
        if math.isfinite(volts):
            sec.voltage_v = float(volts)
            sec.bus_v = _bus_voltage(sec.points)
        sections.append(sec)
    computed = spreads.run_pass()
    for sec in sections:
        fill_spreads(sec.fits, computed)
    for sec in sections:
        prefix = f"{sec.label}: " if len(sections) > 1 else ""
        warnings += [prefix + w for w in sec.warnings]
    laws = _voltage_laws(sections)
    for law in laws:
        prefix = "" if law.depth_m is None else f"{law.depth_m:g} m: "
        warnings += [prefix + w for w in law.warnings]
    dynamics, notes = _dynamics(run, progress) if run.step_response else (None, [])
    warnings += notes
    return CalibrationResult(
        run_id=run.run_id, run_name=run.name, run_status=run.status,
        command_unit=run.command_unit, neutral_command=run.neutral_command,
        thruster_id=run.thruster_id, propeller_diameter_m=run.propeller_diameter_m,
        water_density_kg_m3=run.water_density_kg_m3, tool_version=__version__,
        params=p, sections=sections, drift=drift, warnings=warnings, voltage_laws=laws,
        dynamics=dynamics,
    )


def mark_ventilated(cal: CalibrationResult, events: list[dict]) -> list[str]:
    """Flag as unsteady every point whose steady window overlaps a ventilation event the run
    itself detected (stored events: step_idx, t_start_s, t_end_s), and say so: such a point's
    mean mixes clean and ventilated thrust. Returns the warnings (none without such a point)."""
    spans: dict[int, list[tuple[float, float]]] = {}
    for e in events:
        spans.setdefault(int(e["step_idx"]), []).append((float(e["t_start_s"]),
                                                         float(e["t_end_s"])))
    marked = []
    for sec in cal.sections:
        pts = sec.points
        start = pts.window_start_s
        end = start + 2.0 * (pts.t_mid_s - start)  # the window is symmetric about its mean time
        hit = np.array([any(a < e and b > s for a, b in spans.get(int(i), ()))
                        for i, s, e in zip(pts.step_idx, start, end, strict=True)], dtype=bool)
        if hit.any():
            pts.unsteady = pts.unsteady | hit
            marked.append((sec.label, int(hit.sum())))
    if not marked:
        return []
    where = ", ".join(f"{n} at {label}" for label, n in marked)
    return [f"{sum(n for _, n in marked)} point(s) ({where}) have steady windows that overlap "
            "ventilation events this run detected: their means mix clean and ventilated thrust "
            "(marked unsteady in points.csv)"]


def _dynamics(run: RunData, progress: ProgressHook) -> tuple[Dynamics | None, list[str]]:
    """Identify the dynamics of a step-response run from its points in time order; the
    warnings say why when there are none."""
    ok = np.flatnonzero(run.steps.status == "ok")
    t_s, thrust_n = [], []
    for block in run.source.blocks(("t_s", "thrust_n")):
        keep = np.isin(block.first_row + block.samples.point, ok)
        t_s.append(block.samples.t_s[keep])
        thrust_n.append(block.samples.thrust_n[keep])
    series = StepSeries(np.concatenate(t_s), np.concatenate(thrust_n),
                        run.steps.t_acquire_s[ok], run.steps.command[ok], run.neutral_command)
    dynamics = identify(series, progress=progress)
    if dynamics is not None:
        return dynamics, dynamics.warnings
    reason = no_dynamics_reason(series) or "no model could be fitted to the steps"
    return None, [f"dynamics: no dynamics identified: {reason}"]


def _groups(steps) -> list[np.ndarray]:
    """Row indices of the points of each (depth, supply voltage), by depth then voltage;
    a depth or voltage not set is its own group."""
    def key(values: np.ndarray | None) -> np.ndarray:
        if values is None:
            return np.full(len(steps), np.inf)
        return np.where(np.isfinite(values), np.round(values, 6), np.inf)

    keys = np.column_stack([key(steps.depth_m), key(steps.voltage_v)])
    if not len(keys):
        return []
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    return [np.flatnonzero(inverse == g) for g in range(inverse.max() + 1)]


def _bus_voltage(points: PointTable) -> float:
    """Mean bus voltage over a section's points that entered the fits (all points if none)."""
    v = points.voltage.mean
    pick = points.used_in_fits & np.isfinite(v)
    if not pick.any():
        pick = np.isfinite(v)
    return float(np.mean(v[pick])) if pick.any() else NAN


def _voltage_laws(sections: list[DepthSection]) -> list[VoltageLaw]:
    """A C_n(U) law per depth swept at two or more supply voltages."""
    laws = []
    depths = sorted({s.depth_m for s in sections if s.voltage_v is not None},
                    key=lambda d: -math.inf if d is None else d)
    for depth in depths:
        mine = sorted((s for s in sections if s.depth_m == depth and s.voltage_v is not None),
                      key=lambda s: s.voltage_v)
        points = [voltage_point(s.voltage_v, s.bus_v, s.fits) for s in mine]
        law = fit_voltage_law(depth, points)
        if law is not None:
            laws.append(law)
    return laws


def _section(run: RunData, points: PointTable, samples: SectionSamples,
             drift: TareDrift | None, p: CalibrationParams) -> DepthSection:
    """Fits first (they find the sensor zero when speed is measured), then the command curve
    relative to that zero; fits are redone if the curve puts some of their points in a dead
    zone. The per-sample spreads are placeholders until the second pass."""
    ok = points.status == "ok"
    usable = candidate_points(points, p.fit) & np.isfinite(points.speed.mean)
    direction = speed_sign(points, run.neutral_command, usable)
    points.speed_sign = direction.sign
    shallow = bool(np.isfinite(points.depth_m[0]) and points.depth_m[0] < p.deep_depth_m)
    accuracy = _sensor_share(run.sensor_accuracy, points.thrust.mean[ok])
    design, design_zero = _drift_design(run, points, ok)
    fixed_zero = None if shallow or design.estimable else design_zero

    def make_curve(zero: ZeroLine | None, law: Callable | None = None) -> CommandCurve | None:
        if run.command_unit not in CURVE_UNITS:
            return None
        t = points.thrust
        return command_curve(
            points.command[ok], points.t_mid_s[ok], t.mean[ok], t.se[ok], t.min[ok], t.max[ok],
            points.speed_signed_rpm[ok], points.current.mean[ok], command_unit=run.command_unit,
            neutral_command=run.neutral_command, zero=zero,
            zero_scatter_n=drift.zero_scatter_n if drift else None,
            speed_se=points.speed.se[ok], params=p.curve, tare_t_s=run.tares.t_s,
            tare_drift=_drift_per_s(drift, _tare_sessions(run)),
            sessions=run.session_starts_s, drifts=design.estimable,
            sweep=None if run.step_response else points.direction[ok],
            zero_at_neutral=neutral_ends, law=law)

    # The neutral command visited at times a quarter of the sweep apart (a ramp's neutral
    # ends) reads the zero line on its own where no command is measured again: the points
    # between, read once each as the thrust rises, would otherwise set a drift as they fit.
    at_neutral = ok & (points.command == run.neutral_command)
    neutral_ends = (zero_read_apart(points.t_mid_s[ok], at_neutral[ok])
                    and repeated_apart(points.t_mid_s[ok], points.command[ok],
                                       at_neutral[ok]) < MIN_REPEATED)
    if neutral_ends and points.speed.measured and not shallow:
        fixed_zero = _neutral_line(run, points, at_neutral) or fixed_zero
    if not points.speed.measured:
        # Without feedback the dead commands found first read the zero otherwise.
        design = DriftDesign(True, "")
        first = make_curve(None)
        if first is not None:
            dead = at_neutral if neutral_ends else first.is_dead(points.command)
            design, design_zero = _drift_design(run, points, ok, dead)
            fixed_zero = None if shallow or design.estimable else design_zero
    if shallow:
        # Points near the surface may be ventilating: the zero comes from dead points or tares.
        curve = make_curve(None)
        fixed_zero = (curve.zero if curve is not None and curve.zero is not None
                      else tare_zero(run.tares, drift, points.t_mid_s, run.session_starts_s))
        if curve is not None and curve.zero is None:
            curve = make_curve(fixed_zero)

    def fit() -> ModelFits:
        samples.clear()
        return fit_models(points, samples, diameter_m=run.propeller_diameter_m,
                          density_kg_m3=run.water_density_kg_m3, params=p.fit, zero=fixed_zero,
                          direction=direction, sessions=run.session_starts_s,
                          drift=design.estimable)

    models = _with_sensor_bound(fit(), accuracy.get("thrust_share") or 0.0)
    if not shallow:
        curve = make_curve(models.zero, _table_law(points, models, p))
    if curve is not None:
        points.dead = curve.is_dead(points.command)
        if (points.dead & models.used).any():
            models = _with_sensor_bound(fit(), accuracy.get("thrust_share") or 0.0)
    zero = fixed_zero or models.zero or (curve.zero if curve else None)
    return _finish_section(run, points, ok, models, curve, zero, design, accuracy, shallow, p)


def _table_law(points: PointTable, models: ModelFits, p: CalibrationParams) -> Callable | None:
    """The fitted thrust law as the command curve's shape where most points that entered the
    fits are single readings (a table's rows): one row's noise would otherwise pass straight
    into the curve and the inverse table (curves.command_curve `law`). None elsewhere."""
    used = models.used
    se = points.thrust.se
    once = ~(np.isfinite(se) & (se > 0)) | (points.n_window < p.fit.min_window)
    if not used.any() or 2 * int((once & used).sum()) < used.sum():
        return None
    return signed_law(models.thrust_law)


def _finish_section(run: RunData, points: PointTable, ok: np.ndarray, models: ModelFits,
                    curve: CommandCurve | None, zero: ZeroLine | None, design: DriftDesign,
                    accuracy: dict, shallow: bool, p: CalibrationParams) -> DepthSection:
    """The section from its fits, curve and zero: the points relative to that zero, quality
    (hysteresis, repeatability) and the warnings."""
    points.used_in_fits = models.used
    if zero is not None:
        points.thrust_zero_n = np.nan_to_num(zero.at(points.t_mid_s))
    if models.torque_zero is not None:
        points.torque_zero_nm = np.nan_to_num(models.torque_zero.at(points.t_mid_s))
        above = int(np.sum(overall_efficiency(points)[models.used] > 1.0))
        if above:
            models.warnings.append(
                f"shaft power exceeds electrical power at {above} point(s) (overall efficiency "
                "> 1): check the torque channel and mount transform, and the current and "
                "voltage scaling")
    f = points.thrust_corrected_n
    # Hysteresis only from sweeps built for it: a step run's up/down labels are its steps'.
    hyst = None if run.step_response else hysteresis(points.command[ok], points.direction[ok],
                                                      f[ok], points.thrust.se[ok])
    rep = repeatability(points.command[ok], points.direction[ok], points.repeat[ok], f[ok])
    depth = float(points.depth_m[0]) if np.isfinite(points.depth_m[0]) else None
    warnings = _section_warnings(points, models.coefficients, curve, zero, p) + models.warnings
    if not design.estimable and not shallow:  # shallow: the zero is the tares' as ever
        warnings.append(_design_warning(design, zero))
    if curve is not None:
        warnings += curve.warnings
    if zero is not None and zero.source.startswith("assumed"):
        warnings.append("no tare and no dead points at this depth: the sensor zero is assumed "
                        "to be 0 (points here may ventilate, so none is fitted through them)")
    if shallow and models.coefficients:
        warnings.append(f"shallower than {p.deep_depth_m:g} m: the propeller may ventilate, so "
                        "these coefficients include any thrust loss; the thruster's own "
                        "coefficients come from a deep run")
    return DepthSection(depth, points, models.coefficients, curve, zero, hyst, rep, warnings,
                        models.speed_sign, drift_design=_design_text(design),
                        thrust_law=models.thrust_law, sensor_accuracy=accuracy)


SENSOR_MEASURED = ("C_p_", "K_T_", "C_i_", "C_q_", "K_Q_")  # coefficients read off the sensor


def _with_sensor_bound(models: ModelFits, share: float) -> ModelFits:
    """The fits with the declared sensor accuracy (`share` of the thrusts) added as a bound
    to the interval of every coefficient measured with the sensor (fits.with_bound)."""
    if share > 0:
        models.coefficients = {k: with_bound(c, share) if k.startswith(SENSOR_MEASURED) else c
                               for k, c in models.coefficients.items()}
    return models


def _neutral_line(run: RunData, points: PointTable, at_neutral: np.ndarray) -> ZeroLine | None:
    """The zero line through the points at the neutral command and the tare that zeroes them
    (offset, and a drift where significant: zero_search.fit_zero_line)."""
    t = points.t_mid_s
    se = points.thrust.se
    noise = row_noise(t[at_neutral], points.command[at_neutral], points.thrust.mean[at_neutral])
    se = np.where(np.isfinite(se) & (se > 0), se, noise or np.nanstd(points.thrust.mean[at_neutral]))
    pts = ZeroPoints(points.command[at_neutral], t[at_neutral], points.thrust.mean[at_neutral],
                     se[at_neutral])
    line = fit_zero_line(pts, section_anchors(run.tares.t_s, t[at_neutral]))
    return None if line is None else dataclasses.replace(line, source="neutral command")


def _sensor_share(declared: dict[str, float | None] | None, thrust_n: np.ndarray
                  ) -> dict[str, float | None]:
    """The declared accuracy with `thrust_share`: its errors in quadrature (% of full scale)
    as a share of the largest thrust here (the full scale itself when none is declared)."""
    if not declared:
        return {}
    f = np.abs(thrust_n[np.isfinite(thrust_n)])
    top = float(f.max()) if f.size else 0.0
    pct = math.sqrt(sum((declared[k] or 0.0) ** 2 for k in ACCURACY_KEYS))
    full = declared.get("full_scale_n") or top
    share = pct / 100.0 * full / top if top > 0 else 0.0
    return {**declared, "thrust_share": share}


def _drift_design(run: RunData, points: PointTable, ok: np.ndarray,
                  dead: np.ndarray | None = None) -> tuple[DriftDesign, ZeroLine | None]:
    """Whether this section's design separates a zero drift from the law, and the zero to use
    where it does not: the neutral rows' mean (the points that read the zero: `dead`, else
    stopped or at the neutral command), else 0 at the tare before the points (None: neither,
    the fits then take one constant offset)."""
    t = points.t_mid_s
    ok = ok & np.isfinite(t) & np.isfinite(points.thrust.mean)
    speed = points.speed.mean if points.speed.measured else np.full(len(points), np.nan)
    zero_rows = ok & (reads_zero(points.command, speed, run.neutral_command, STOPPED_FRAC)
                      if dead is None else dead)
    tares = run.tares.t_s[np.isfinite(run.tares.t_s)]
    anchors = section_anchors(tares, t[ok], None, run.session_starts_s)
    if ok.any():
        tares = np.concatenate([anchors.t_s, tares[(tares >= t[ok].min()) & (tares <= t[ok].max())]])
    design = drift_design(t[ok], points.command[ok], zero_rows[ok], tares)
    if ok.any() and occupied_starts(t[ok], run.session_starts_s):
        return design, None  # each session keeps its own offset, fitted with the law
    zero = neutral_zero(t[zero_rows], points.thrust.mean[zero_rows], points.thrust.se[zero_rows],
                        row_noise(t[ok], points.command[ok], points.thrust.mean[ok]))
    if zero is None and anchors.t_s.size:
        zero = ZeroLine(0.0, 0.0, float(anchors.t_s[-1]), "tare", ((0.0, 0.0), (0.0, 0.0)))
    return design, zero


def _design_text(design: DriftDesign) -> str:
    """The design judgement as calibration.json records it."""
    return ("estimated: " if design.estimable else "not estimable: ") + design.reason


def _design_warning(design: DriftDesign, zero: ZeroLine | None) -> str:
    """Where the design cannot separate a drift: what the zero is instead, and from where."""
    if zero is None:
        held = "no sensor zero could be read"
    elif zero.source == "neutral rows":
        held = (f"the zero is the mean of the neutral rows ({zero.offset_n:.4g} N) and no "
                "measured thrust is moved by a drift")
    elif zero.source == "model fit":
        held = ("with no neutral row, the zero is one constant fitted with the law, and no "
                "measured thrust is moved by a drift")
    else:
        held = f"the zero is constant, from the {zero.source}, and no drift is removed"
    return f"zero drift not estimable: {design.reason}; {held}"


def _drift_per_s(drift: TareDrift | None, sessions: int = 1) -> tuple[float, float] | None:
    """The tares' drift and its standard error in N/s (None without an interval: < 3 tares);
    `sessions`: how many sessions the tares fall in (one offset each)."""
    if drift is None or not math.isfinite(drift.slope.lo):
        return None
    from scipy import special

    t = special.stdtrit(max(drift.slope.n - sessions - 1, 1), 0.975)
    se = (drift.slope.hi - drift.slope.lo) / (2 * t)
    return drift.slope.value / SECONDS_PER_HOUR, se / SECONDS_PER_HOUR


def tare_zero(tares: Tares, drift: TareDrift | None, t_s: np.ndarray,
              sessions: tuple[float, ...] = ()) -> ZeroLine:
    """The zero the tares give: 0 at the last tare before the points, drifting at the rate
    the tare biases show (0 with fewer than two tares). Used where points may ventilate.
    In a resumed run (`sessions`) each session's zero is 0 at its own tare (a session
    without one continues the line of the session before)."""
    first = float(np.nanmin(t_s)) if np.isfinite(t_s).any() else 0.0
    before = tares.t_s[tares.t_s <= first]
    if not tares.t_s.size:
        return ZeroLine(0.0, 0.0, first, "assumed (no tare, no dead points)")
    t0 = float(before.max()) if before.size else float(tares.t_s.min())
    slope = drift.slope.value / SECONDS_PER_HOUR if drift is not None else 0.0
    var = drift.zero_scatter_n**2 if drift is not None else 0.0
    starts = occupied_starts(t_s[np.isfinite(t_s)], sessions)
    if not starts:
        return ZeroLine(0.0, slope, t0, "tares", ((var, 0.0), (0.0, 0.0)))
    offsets = [0.0]
    for start in starts:
        mine = t_s[session_index(t_s, starts) == starts.index(start) + 1]
        own = tares.t_s[(tares.t_s > start) & (tares.t_s <= np.nanmin(mine))]
        offsets.append(-slope * (float(own.max()) - t0) if own.size else offsets[-1])
    cov = np.diag([var] * len(offsets) + [0.0])
    return session_line(np.array(offsets), slope, t0, "tares", cov, starts)


def _tare_sessions(run: RunData) -> int:
    """How many sessions of a resumed run hold tares (1 for a run never resumed)."""
    t = run.tares.t_s[np.isfinite(run.tares.t_s)]
    return max(int(np.unique(session_index(t, run.session_starts_s)).size), 1)


def run_tare_drift(tares: Tares, sessions: tuple[float, ...] = ()) -> TareDrift | None:
    """The tares' drift; in a resumed run, from the tares within each session (the sensor is
    opened and tared again at a resume: the bias may start over), one rate for all. Without
    a session of two tares, the trend across the sessions is kept to show, with no interval
    (so it neither warns nor bounds the zero's drift)."""
    ok = np.isfinite(tares.t_s)
    k = session_index(tares.t_s[ok], sessions)
    plain = tare_drift(tares.t_s, tares.thrust_bias_n)
    if tares.thrust_bias_n is None or np.unique(k).size < 2:
        return plain
    within = _session_tare_drift(tares.t_s[ok], tares.thrust_bias_n[ok], k)
    if within is not None or plain is None:
        return within
    return dataclasses.replace(plain, slope=dataclasses.replace(
        plain.slope, lo=NAN, hi=NAN, r2=NAN,
        note=plain.slope.note + "; across the sessions of a resumed run (no interval)"))


def _session_tare_drift(t_s: np.ndarray, bias: np.ndarray, session: np.ndarray
                        ) -> TareDrift | None:
    """Linear trend (N/h, 95 % interval) of the tare bias with an offset per session (None
    without a session of two tares at different times)."""
    from scipy import special

    ok = np.isfinite(bias)
    order = np.argsort(t_s[ok], kind="stable")
    t, b, k = t_s[ok][order], bias[ok][order], session[ok][order]
    hours = (t - t[0]) / SECONDS_PER_HOUR if t.size else t
    groups, inv = np.unique(k, return_inverse=True)
    count = np.bincount(inv)
    mean_h, mean_b = (np.bincount(inv, weights=v) / count for v in (hours, b))
    dx, dy = hours - mean_h[inv], b - mean_b[inv]
    sxx = float(dx @ dx)
    if not sxx > 0:
        return None
    rate = float(dx @ dy) / sxx
    resid = dy - rate * dx
    dof = t.size - groups.size - 1
    lo = hi = r2 = NAN
    if dof > 0:
        hw = special.stdtrit(dof, 0.975) * math.sqrt(float(resid @ resid) / dof / sxx)
        lo, hi = rate - hw, rate + hw
        syy = float(dy @ dy)
        r2 = 1.0 - float(resid @ resid) / syy if syy > 0 else NAN
    slope = Coefficient("tare_drift", rate, float(lo), float(hi), "N/h", int(t.size), float(r2),
                        float(np.sqrt(np.mean(resid**2))), "N",
                        f"thrust-channel tare bias vs time, linear trend; an offset for each "
                        f"of {groups.size} sessions (run resumed)")
    offset = mean_b - rate * mean_h
    aligned = b - offset[inv] + offset[0]
    same = k[1:] == k[:-1]
    steps = np.diff(aligned)[same]
    scatter = float(np.sqrt(np.mean(steps**2))) if steps.size else 0.0
    return TareDrift(t, aligned - aligned[0], slope, scatter)


def _run_warnings(run: RunData, table: PointTable, drift: TareDrift | None,
                  p: CalibrationParams) -> list[str]:
    out = []
    if run.status != "completed":
        out.append(f"run status is '{run.status}': only the points recorded are analysed")
    bad = int(np.sum(table.status != "ok"))
    if bad:
        out.append(f"{bad} point(s) with status other than 'ok' are excluded")
    unsettled = int(np.sum(~table.settled))
    if unsettled:
        out.append(f"{unsettled} point(s) were marked not settled by the engine")
    unsteady = int(np.sum(table.unsteady))
    if unsteady:
        out.append(f"{unsteady} point(s) have excursions inside their steady window "
                   "(transient longer than the window cap, or ventilation)")
    moved = None if drift is None else drift_over_sweep(
        drift.slope.value, (drift.slope.lo, drift.slope.hi), *_span_and_noise(table),
        p.drift_warn_noise_ratio)
    if moved:
        out.append(f"tare drift: the tares show the sensor zero moving {moved}")
    return out


def _span_and_noise(points: PointTable) -> tuple[float, float]:
    """The time the ok points span (s), and the thrust noise: their smallest per-point standard
    deviation, the sensor's own where the propeller adds least; for a table of one reading
    per row, the rows' own scatter about a smooth curve (drift_design.row_noise)."""
    ok = (points.status == "ok") & np.isfinite(points.t_mid_s)
    spread = points.thrust.std[ok]
    spread = spread[np.isfinite(spread) & (spread > 0)]
    span = float(np.ptp(points.t_mid_s[ok])) if ok.any() else 0.0
    if spread.size:
        return span, float(spread.min())
    rows = row_noise(points.t_mid_s[ok], points.command[ok], points.thrust.mean[ok])
    return span, rows if rows > 0 else NAN


def _zero_drift_interval(zero: ZeroLine) -> tuple[float, float]:
    """95 % interval (N/h) of a zero line's drift; NaN where the line carries no variance for
    it (a zero taken from the tares: the tare drift warning speaks for it)."""
    var = zero.cov[1][1] if zero.cov is not None else 0.0
    if not var > 0:
        return NAN, NAN
    rate, half = zero.drift_n_per_s, Z95 * math.sqrt(var)
    return (rate - half) * SECONDS_PER_HOUR, (rate + half) * SECONDS_PER_HOUR


def _section_warnings(points: PointTable, fits: dict[str, Coefficient],
                      curve: CommandCurve | None, zero: ZeroLine | None,
                      p: CalibrationParams) -> list[str]:
    out = []
    moved = None if zero is None else drift_over_sweep(
        zero.drift_n_per_s * SECONDS_PER_HOUR, _zero_drift_interval(zero),
        *_span_and_noise(points), p.drift_warn_noise_ratio)
    if moved:
        out.append(f"sensor zero drifts {moved} (from the {zero.source}; removed from the "
                   "results)")
    if not points.speed.measured and curve is None:
        out.append("no speed feedback and no command curve: nothing to fit")
    elif points.speed.measured and not fits:
        out.append("no fit: too few points with significant propeller speed")
    for c in fits.values():
        if c.name not in CHECKED_FITS:
            continue
        if not math.isnan(c.r2) and c.r2 < p.min_r2:
            out.append(f"poor fit: {c.name} R2 = {c.r2:.3f} < {p.min_r2:g}")
        if c.n < p.min_points:
            out.append(f"few points: {c.name} from {c.n} point(s)")
    if curve is not None and not curve.branches:
        out.append("command curve: no live command (thrust never distinguishable from zero)")
    return out
