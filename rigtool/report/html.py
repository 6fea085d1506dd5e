"""Build the self-contained HTML report of one run: metadata, warnings, coefficients, figures."""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import jinja2
import numpy as np
from markupsafe import Markup

from rigtool.analysis.dynamics import Dynamics
from rigtool.analysis.efficiency import efficiency_n_per_w
from rigtool.analysis.fits import Coefficient
from rigtool.analysis.results import CalibrationResult, DepthSection, VoltageLaw
from rigtool.analysis.steady import PointTable
from rigtool.artefacts.write import atomic_write
from rigtool.ids import utc_now
from rigtool.outpaths import REPORT_FILE
from rigtool.report import figures as fg
from rigtool.report import step_text
from rigtool.run_warnings import run_warnings
from rigtool.store import Store
from rigtool.units import unit_label
from rigtool.version import __version__

VENTILATION_KIND = "sim.ventilation"
IMAGE_FORMATS = ("svg", "png")


@dataclass
class FigureItem:
    """One figure slot: an embedded image, or (uri None) a one-line note why it is omitted."""

    kind: str
    fig_id: str
    title: str
    caption: str
    uri: str | None = None
    small: bool = False


@dataclass
class SectionView:
    """What the template shows for one depth."""

    label: str
    heading: str
    coefficients: list[Coefficient]
    features: list[tuple[str, str, str]]
    no_fit_reason: str = ""
    figures: list[FigureItem] = field(default_factory=list)


def write_report(store: Store, run_id: str, out_dir: Path,
                 calibration: CalibrationResult | None = None, *, image_format: str = "svg",
                 cavitation: object | None = None, extra_warnings: Sequence[str] = ()) -> Path:
    """Write `out_dir`/report.html for `run_id` from its calibration results (None: the run has
    no points) and return the path."""
    text = render_report(store, run_id, calibration, image_format=image_format,
                         cavitation=cavitation, extra_warnings=extra_warnings)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return atomic_write(out / REPORT_FILE, text)


def render_report(store: Store, run_id: str, calibration: CalibrationResult | None = None, *,
                  image_format: str = "svg", cavitation: object | None = None,
                  extra_warnings: Sequence[str] = ()) -> str:
    """The report of `run_id` as one HTML string; `extra_warnings` (e.g. the quasi-cavitation
    stage's) join the run's own in the warnings list."""
    if image_format not in IMAGE_FORMATS:
        raise ValueError(f"image_format must be one of {IMAGE_FORMATS}, not {image_format!r}")
    run = store.run(run_id)
    steps = store.steps(run_id)
    events = store.events(run_id)
    cal = calibration
    unit = unit_label(run["command_unit"])
    sections: list[SectionView] = []
    drift: FigureItem | None = None
    voltages: list[VoltageView] = []
    dynamics: DynamicsView | None = None
    with fg.style():
        if cal is not None:
            step_ids = {int(s["idx"]): int(s["id"]) for s in steps}
            vent = [e for e in events if e["kind"] == VENTILATION_KIND]
            multi = len(cal.sections) > 1
            for i, sec in enumerate(cal.sections):
                suffix = f"-{i + 1}" if multi else ""
                view = _section(sec, cal, unit, suffix, image_format)
                view.figures.append(_time_series(store, sec, step_ids, vent, unit,
                                                 suffix, image_format))
                sections.append(view)
            drift = _drift_figure(cal, events, image_format, imported=_imported(run))
            voltages = [_voltage_view(law, cal, i, image_format)
                        for i, law in enumerate(cal.voltage_laws)]
            dynamics = _dynamics_view(store, run_id, cal, image_format)
    cav = None
    if cavitation is not None:
        from rigtool.report.cavitation import cavitation_view

        cav = cavitation_view(cavitation, image_format)
    from rigtool.report.captive import captive_view

    with fg.style():
        captive = captive_view(None if cal is None else cal.captive, image_format)
    return _template().render(cav=cav, captive=captive,
        run=run, meta=_meta_rows(run, steps, cal), protocol=_flatten(run.get("protocol") or {}),
        warnings=run_warnings(run, events, cal, extra_warnings), events=_event_counts(events),
        cal=cal, sections=sections, drift=drift, voltages=voltages, dynamics=dynamics, unit=unit,
        generated=utc_now(),
        version=__version__)


def _template() -> jinja2.Template:
    env = jinja2.Environment(loader=jinja2.PackageLoader("rigtool.report", "templates"),
                             autoescape=True, trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    env.filters["num"] = fmt_num
    env.filters["unit"] = fmt_unit
    env.filters["interval"] = fmt_interval
    env.filters["stat_interval"] = fmt_stat_interval
    env.filters["r2"] = fmt_r2
    env.filters["settling_text"] = step_text.settling_text
    env.filters["measured_text"] = step_text.measured_text
    env.filters["end_text"] = step_text.end_text
    return env.get_template("report.html")


def fmt_num(value: object, digits: int = 5) -> Markup:
    """A number for a table: `digits` significant figures, powers of ten as superscripts."""
    if value is None:
        return Markup("–")
    x = float(value)  # type: ignore[arg-type]
    if not math.isfinite(x):
        return Markup("–")
    if x == 0 or 1e-3 <= abs(x) < 1e5:
        return Markup.escape(f"{x:.{digits}g}".replace("-", "−"))
    mant, exp = f"{x:.{digits - 1}e}".split("e")
    return Markup(f"{mant.replace('-', '−')}×10<sup>{int(exp)}</sup>".replace("<sup>-", "<sup>−"))


def fmt_interval(c: Coefficient) -> Markup:
    """`lo … hi` of a coefficient on two lines, or a dash when it has no interval."""
    if not (math.isfinite(c.lo) and math.isfinite(c.hi)):
        return Markup("–")
    return Markup("{} …<br>{}").format(fmt_num(c.lo), fmt_num(c.hi))


def fmt_stat_interval(c: Coefficient) -> Markup:
    """The statistical interval alone, when a systematic allowance widened the full one."""
    if not c.systematic:
        return Markup("same")
    lo, hi = c.statistical
    return Markup("{} …<br>{}").format(fmt_num(lo), fmt_num(hi))


def fmt_r2(value: float) -> str:
    """R² with four decimals (so 0.99996 does not print as 1), a dash when undefined."""
    return f"{value:.4f}" if math.isfinite(value) else "–"


def fmt_unit(unit: str) -> Markup:
    """A unit with `^2`, `^(2/3)`, `^k` written as superscripts."""
    text = str(Markup.escape(unit))
    return Markup(re.sub(r"\^\(([^)]*)\)|\^(\w+)",
                         lambda m: f"<sup>{m.group(1) or m.group(2)}</sup>", text))


# -- metadata, warnings, events -----------------------------------------------------------------

def _meta_rows(run: dict, steps: list[dict], cal: CalibrationResult | None) -> list[tuple[str, str]]:
    protocol = run.get("protocol") or {}
    meta = {**(protocol.get("metadata") or {}), **(run.get("metadata") or {})}
    rig = run.get("rig") or {}
    resolved = rig.get("resolved") or {}
    rig_text = rig.get("name") or "?"
    if resolved.get("kind") == "simulator":
        rig_text += f" (simulator profile {resolved.get('profile')})"
    command = protocol.get("command") or {}
    plan = run.get("plan") or steps
    commands = sorted({float(s["command"]) for s in plan if s.get("command") is not None})
    unit = unit_label(run["command_unit"])
    depths = sorted({s["depth_m"] for s in plan if s.get("depth_m") is not None})
    status = run["status"] + (f": {run['stop_reason']}" if run.get("stop_reason") else "")
    rows = [
        ("run id", run["id"]), ("name", run["name"]),
        ("description", protocol.get("description") or ""), ("status", status),
        ("created (UTC)", run["created_utc"]), ("finished (UTC)", run.get("finished_utc") or "–"),
        ("run time (rig clock)", _duration(max((s["t_end_s"] for s in steps), default=0.0))),
        ("host", run["host"]), ("tool version (run)", run["tool_version"]),
        ("seed", "–" if run.get("seed") is None else str(run["seed"])), ("rig", rig_text),
        ("protocol file", run.get("protocol_path") or "–"),
    ]
    for key in ("thruster_id", "propeller", "operator", "notes", "propeller_diameter_m",
                "water_density_kg_m3"):
        if meta.get(key) is not None:
            rows.append((key.replace("_", " "), str(meta[key])))
    rows += [(f"extra: {k}", str(v)) for k, v in (meta.get("extra") or {}).items()]
    rows += [
        ("command unit", f"{run['command_unit']} ({unit})"),
        ("commands", f"{len(commands)} values, {commands[0]:g} .. {commands[-1]:g} {unit}, "
                     f"order {command.get('order', '?')}, {command.get('repeats', 1)} repeat(s)"
         if commands else "–"),
        ("depths", ", ".join(f"{d:g} m" for d in depths) or "not set"),
        *_voltage_rows(protocol.get("voltage") or {}, plan),
        ("points", f"{len(steps)} recorded of {run['n_planned']} planned"),
        ("samples", f"{sum(int(s['n']) for s in steps):,}"),
    ]
    if cal is not None:
        rows.append(("analysed with", f"rigtool {cal.tool_version}"))
    return rows


def _voltage_rows(axis: dict, plan: list[dict]) -> list[tuple[str, str]]:
    """The supply voltages of a run with a voltage axis, in the order visited, and how they
    were set and held; none for a run without one."""
    volts = list(dict.fromkeys(float(s["voltage_v"]) for s in plan
                               if s.get("voltage_v") is not None))
    volts = volts or [float(v) for v in axis.get("values") or []]
    if not volts:
        return []
    mode = axis.get("mode", "?")
    how = {"preset": "set by the rig's supply", "manual": "set by the operator"}.get(mode, "")
    held = (f", each held within {100 * float(axis['tolerance_frac']):g} %"
            if axis.get("tolerance_frac") is not None else "")
    return [("supply voltages", f"{', '.join(f'{v:g}' for v in volts)} V, order "
             f"{axis.get('order', '?')}; mode {mode}" + (f" ({how})" if how else "") + held)]


def _duration(seconds: float) -> str:
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h} h {m:02d} min" if h else f"{m} min {s:02d} s"


def _flatten(obj: object, prefix: str = "") -> list[tuple[str, str]]:
    """Nested protocol data as (dotted key, value) rows; empty values left out."""
    if isinstance(obj, dict):
        rows: list[tuple[str, str]] = []
        for k, v in obj.items():
            rows += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
        return rows
    if obj is None or obj == [] or obj == "":
        return []
    if isinstance(obj, list):
        return [(prefix, ", ".join(str(v) for v in obj))]
    return [(prefix, str(obj))]


def _event_counts(events: list[dict]) -> list[tuple[str, int]]:
    return sorted(Counter(e["kind"] for e in events).items())


# -- per-depth sections -------------------------------------------------------------------------

def _section(sec: DepthSection, cal: CalibrationResult, unit: str, suffix: str,
             fmt: str) -> SectionView:
    heading = "Results" if not suffix else f"Depth {sec.label}"
    view = SectionView(sec.label, heading, list(sec.fits.values()), _features(sec, unit),
                       _no_fit_reason(sec))
    at = "" if not suffix else f" at {sec.label}"
    view.figures += _curve_figures(sec, cal, unit, suffix, at, fmt)
    view.figures += _speed_figures(sec, cal, suffix, at, fmt)
    view.figures.append(_hysteresis_figure(sec, unit, suffix, at, fmt))
    p = sec.points
    if (p.status == "ok").any():
        view.figures.append(FigureItem(
            "spread", f"fig-spread{suffix}", f"Per-point spread{at}",
            "Thrust standard deviation and |max − mean| per point over its steady window "
            f"(N) vs command ({unit}).", fg.encode(fg.spread(p, unit), fmt)))
    view.figures.append(_efficiency_figure(sec, suffix, at, fmt))
    return view


def _efficiency_figure(sec: DepthSection, suffix: str, at: str, fmt: str) -> FigureItem:
    base = ("efficiency", f"fig-efficiency{suffix}", f"Efficiency and electrical power{at}")
    p = sec.points
    if not (np.isfinite(efficiency_n_per_w(p)) & (p.status == "ok") & ~p.dead).any():
        return FigureItem(*base, "No efficiency figure: the run recorded no bus voltage and "
                          "current (electrical power V·|I| needs both).")
    return FigureItem(*base, "Thrust per electrical watt (g/W; bars: 95 % intervals) and "
                      "electrical power V·|I| averaged sample by sample (W), both vs |thrust| "
                      "(N), live points only.", fg.encode(fg.efficiency(p), fmt))


def _no_fit_reason(sec: DepthSection) -> str:
    if not sec.points.speed.measured:
        what = "the command curve below is" if sec.curve is not None else "there is no"
        return (f"No speed or current model: the run has no propeller speed feedback, so "
                f"{what} the calibration.")
    return "No model coefficients: too few usable points (see the warnings)."


def _features(sec: DepthSection, unit: str) -> list[tuple[str, str, str]]:
    """(quantity, value, note) rows: curve features, hysteresis, repeatability, point counts."""
    p = sec.points
    rows = [("points", f"{len(p)}", f"{int(p.used_in_fits.sum())} used in fits, "
             f"{int(np.sum(p.status != 'ok'))} not ok, {int(p.unsteady.sum())} unsteady, "
             f"{int(p.dead.sum())} in dead zones")]
    c = sec.curve
    if c is not None:
        rows += [("dead zone", f"{lo:g} .. {hi:g} {unit}", "") for lo, hi in c.dead_zones]
        for i, b in enumerate(c.branches):
            parts = [f"commands {b.command_lo:g} .. {b.command_hi:g} {unit}"]
            if b.usable:
                parts.append(f"usable {b.usable[0]:g} .. {b.usable[1]:g}")
            if b.saturated:
                parts.append(f"saturated {b.saturated[0]:g} .. {b.saturated[1]:g}")
            if b.lut_thrust_n.size:
                parts.append(f"thrust {b.lut_thrust_n.min():.3g} .. {b.lut_thrust_n.max():.3g} N")
            note = "inverted: |thrust| grows towards neutral" if b.inverted else ""
            rows.append((f"branch {i} ({b.direction})", "; ".join(parts), note))
        rows += [("break-away", f"{x:g} {unit}", "thrust jumps here") for x in c.break_aways]
    if sec.hysteresis is not None:
        h = sec.hysteresis
        rows.append(("hysteresis max |up − down|", f"{h.max_abs_n:.3g} N",
                     f"at {h.at_command:g} {unit}"))
    if sec.repeatability is not None:
        r = sec.repeatability
        rows.append(("repeatability max std", f"{r.max_std_n:.3g} N",
                     f"median {r.median_std_n:.3g} N over {r.command.size} command(s)"))
    return rows


def _curve_figures(sec: DepthSection, cal: CalibrationResult, unit: str, suffix: str, at: str,
                   fmt: str) -> list[FigureItem]:
    c = sec.curve
    if c is None:
        return [FigureItem("command-curve", f"fig-command-curve{suffix}", "Command curve",
                           f"No command curve: commands in {cal.command_unit} are closed-loop "
                           "set-points, not a drive signal.")]
    out = [FigureItem(
        "command-curve", f"fig-command-curve{suffix}", f"Command curve{at}",
        f"Thrust (N) vs command ({unit}): per-command mean of the steady windows, sample "
        "min..max band, monotone fit per branch, dead zones shaded grey, saturated ranges "
        "hatched, break-aways dashed.", fg.encode(fg.command_curve(c, unit), fmt))]
    if any(b.lut_thrust_n.size for b in c.branches):
        out.append(FigureItem(
            "inverse-map", f"fig-inverse-map{suffix}", f"Inverse map{at}",
            f"Command ({unit}) vs wanted thrust (N) over each branch's usable range "
            "(inverse_lut.csv).", fg.encode(fg.inverse_map(c, unit), fmt), small=True))
    else:
        out.append(FigureItem("inverse-map", f"fig-inverse-map{suffix}", "Inverse map",
                              "No inverse map: no live command range."))
    return out


def _speed_figures(sec: DepthSection, cal: CalibrationResult, suffix: str, at: str,
                   fmt: str) -> list[FigureItem]:
    p, fits = sec.points, sec.fits
    ts = ("thrust-speed", f"fig-thrust-speed{suffix}", f"Thrust vs propeller speed{at}")
    cs = ("current-speed", f"fig-current-speed{suffix}", f"Current vs propeller speed{at}")
    if not p.speed.measured:
        why = (f"No propeller speed feedback in this run (command unit {cal.command_unit}): "
               "no thrust-vs-speed or current-vs-speed figure.")
        return [FigureItem(*ts, why)]
    out = []
    if "C_p_fwd" in fits or "C_p_rev" in fits:
        zero = f" (from the {sec.zero.source})" if sec.zero is not None else ""
        out.append(FigureItem(*ts, "Thrust (N) vs propeller speed (r/min), points with 95 % "
                              "error bars and the forward/reverse C_p |n| n model; below, the "
                              "residuals thrust − zero − C_p |n| n (N). Thrust is shown after "
                              f"removing the estimated sensor zero and its drift{zero}, as the "
                              f"fit saw it.{_design_text(sec)}{_law_text(sec)}"
                              f"{_accuracy_text(sec)}",
                              fg.encode(fg.thrust_speed(p, fits), fmt)))
    else:
        out.append(FigureItem(*ts, "No thrust-vs-speed fit: too few points with significant "
                              "propeller speed."))
    if not p.current.measured:
        out.append(FigureItem(*cs, "No motor current feedback: no current-vs-speed figure."))
    elif "C_n" in fits and "I_0" in fits:
        out.append(FigureItem(*cs, "Motor current (A) vs propeller speed (r/min) with the "
                              "I = C_n |n|³ + I_0 fit.", fg.encode(fg.current_speed(p, fits), fmt)))
    else:
        out.append(FigureItem(*cs, "No current fit: too few points with current feedback."))
    return out


def _design_text(sec: DepthSection) -> str:
    """The sentence on whether the sweep's design let a zero drift be estimated."""
    return f" Zero drift {sec.drift_design}." if sec.drift_design else ""


def _accuracy_text(sec: DepthSection) -> str:
    """The sentence on the sensor accuracy declared and what it adds to the intervals."""
    a = sec.sensor_accuracy
    if not a:
        return ""
    full = f"{a['full_scale_n']:g} N" if a.get("full_scale_n") else "the largest thrust"
    return (f" Force sensor accuracy declared: nonlinearity {a['nonlinearity_pct_fs']:g} %, "
            f"hysteresis {a['hysteresis_pct_fs']:g} %, crosstalk {a['crosstalk_pct_fs']:g} % "
            f"of full scale ({full}): ±{100 * a['thrust_share']:.2g} % of the largest thrust, "
            "in the systematic part of every thrust coefficient's interval.")


def _law_text(sec: DepthSection) -> str:
    """The sentences on the thrust law chosen per direction and how far C_p |n| n misses it."""
    out = []
    for key, word in (("fwd", "Forward"), ("rev", "Reverse")):
        law = sec.thrust_law.get(key)
        if law is None:
            continue
        params = ", ".join(f"{k} = {v:.4g}" for k, v in law["params"].items())
        verdict = ("adequate" if law["quadratic_adequate"] else "inadequate: use the chosen law")
        out.append(f" {word} thrust law chosen on held-out points: {law['formula']} ({params}); "
                   f"C_p |n| n misses it by up to {100 * law['quadratic_max_miss_frac']:.1f} % "
                   f"of full scale between 10 and 100 % speed ({verdict}).")
    return "".join(out)


def _hysteresis_figure(sec: DepthSection, unit: str, suffix: str, at: str,
                       fmt: str) -> FigureItem:
    base = ("hysteresis", f"fig-hysteresis{suffix}", f"Hysteresis{at}")
    if sec.hysteresis is None:
        return FigureItem(*base, "No hysteresis figure: the run does not visit the same "
                          "commands sweeping both up and down.")
    return FigureItem(*base, f"Up-sweep minus down-sweep mean thrust (N) vs command ({unit}), "
                      "95 % error bars.", fg.encode(fg.hysteresis(sec.hysteresis, unit), fmt))


@dataclass
class VoltageView:
    """The supply-voltage section of one depth: per-voltage coefficients, law, figure."""

    heading: str
    rows: list[tuple[float, float, Coefficient | None, Coefficient | None, Coefficient | None]]
    law: list[Coefficient]
    cp_note: str
    figure: FigureItem


def _voltage_view(law: VoltageLaw, cal: CalibrationResult, i: int, fmt: str) -> VoltageView:
    at = "" if law.depth_m is None else f" at {law.depth_m:g} m"
    mine = [(s.voltage_v, s.points) for s in cal.sections
            if s.depth_m == law.depth_m and s.voltage_v is not None]
    cp_note = (f"C_p_fwd is consistent across the voltages (reduced χ² {law.cp_chi2_red:.2f})"
               if law.cp_consistent else
               f"C_p_fwd differs between voltages beyond its intervals (reduced χ² "
               f"{law.cp_chi2_red:.2f}): it should not depend on U")
    figure = FigureItem(
        "voltage", f"fig-voltage-{i + 1}", f"Supply voltage{at}",
        "Left: C_n at each supply voltage (bars: 95 % intervals) with the fitted law "
        "C_n(U) = k U^b (b = −1 expected). Right: current (A) vs thrust (N) per voltage, live "
        "points, thrust relative to the sensor zero.",
        fg.encode(fg.voltage_law(law, mine), fmt))
    rows = [(v.voltage_v, v.bus_v, v.cp_fwd, v.cn, v.ci_fwd) for v in law.points]
    return VoltageView(f"Supply voltage{at}", rows, [law.k_inverse, law.k, law.b], cp_note,
                       figure)


@dataclass
class DynamicsView:
    """The dynamics section: the candidates' parameters, the selection, its adequacy and the
    step timings."""

    selected: str
    models: list[tuple[str, list[Coefficient], float, float, float]]  # name, params, RMS, BIC,
    steps: list  # held-out RMS
    figure: FigureItem
    verdict: str = ""  # identified or not, and the adequacy


def _dynamics_view(store: Store, run_id: str, cal: CalibrationResult, fmt: str) -> DynamicsView | None:
    from rigtool.analysis.dynamics import StepSeries

    d = cal.dynamics
    if d is None:
        return None
    ok = [s for s in store.steps(run_id) if s["status"] == "ok"]
    data = store.samples(run_id, ("t_s", "thrust_n"))
    series = StepSeries(data["t_s"], data["thrust_n"],
                        np.array([s["t_acquire_s"] for s in ok], dtype=float),
                        np.array([s["command"] for s in ok], dtype=float), cal.neutral_command)
    models = d.candidates
    fitted = {m.name: d.fitted(series, m) for m in models}
    figure = FigureItem(
        "dynamics", "fig-dynamics", "Step responses",
        "Measured thrust (N) through the command steps (dotted lines) with the fitted "
        f"candidate models; the {d.selected} model predicts held-out steps best.",
        fg.encode(fg.step_responses(series.t_s, series.thrust_n, fitted, series.switch_s), fmt))
    rows = [(m.name, [c for c in (m.tau_n_s, m.alpha, m.tau_a_s, m.gain, m.delay_s,
                                  m.reverse_ratio) if c is not None],
             m.rms_n, m.bic, m.heldout_rms_n) for m in models]
    return DynamicsView(d.selected, rows, d.steps, figure, _dynamics_verdict(d))


def _dynamics_verdict(d: Dynamics) -> str:
    """One sentence: the selected model's adequacy, and whether dynamics were identified."""
    m = d.model
    scale = d.full_scale_n
    share = (f" ({100 * m.model_error_n() / scale:.2f} % of the full scale {scale:.4g} N)"
             if math.isfinite(scale) and scale > 0 else "")
    adequacy = (f"Held-out steps: RMS error {m.heldout_rms_n:.3g} N, of which sensor noise "
                f"{m.heldout_noise_n:.3g} N; model error {m.model_error_n():.3g} N{share}.")
    if d.identified:
        return f"{adequacy} The {m.name} model is exported."
    return f"{adequacy} No dynamics identified: {d.reason}. No export carries time constants."


def _imported(run: dict) -> bool:
    """Whether the run came from `rigtool import` (no protocol ran it: no tares, no timing)."""
    rig = run.get("rig")
    return isinstance(rig, dict) and (rig.get("resolved") or {}).get("kind") == "import"


def _drift_figure(cal: CalibrationResult, events: list[dict], fmt: str, *,
                  imported: bool = False) -> FigureItem:
    """The tare drift figure, or why there is none (with the protocol setting that gives one
    to a sweep; an imported run records no tares, so nothing is suggested)."""
    base = ("tare-drift", "fig-tare-drift", "Tare drift")
    if cal.drift is None and imported:
        return FigureItem(*base, "No tare drift figure: an imported run records no tares.")
    if cal.drift is None:
        n = sum(1 for e in events if e["kind"] == "tare")
        return FigureItem(*base, f"{n} tare(s) recorded: a drift figure needs at least two "
                          "(protocol timing.tare: per_depth with several depths, or per_point).")
    return FigureItem(*base, "Bias on the thrust channel at each tare, relative to the first "
                      "(N), vs time, with its linear trend (N/h).",
                      fg.encode(fg.tare_drift(cal.drift), fmt))


# -- time series of chosen points ---------------------------------------------------------------

def chosen_points(points: PointTable) -> list[tuple[int, str]]:
    """(row, why) of up to three points: highest forward, highest reverse, and a mid thrust."""
    f = points.thrust.mean
    ok = (points.status == "ok") & np.isfinite(f) & (points.n_samples > 0)
    picks: list[tuple[int, str]] = []
    if (ok & (f > 0)).any():
        picks.append((int(np.nanargmax(np.where(ok, f, np.nan))), "highest forward thrust"))
    if (ok & (f < 0)).any():
        picks.append((int(np.nanargmin(np.where(ok, f, np.nan))), "highest reverse thrust"))
    live = ok & ~points.dead
    live[[i for i, _ in picks]] = False
    if live.any() and picks:
        target = 0.5 * max(abs(float(f[i])) for i, _ in picks)
        i = int(np.nanargmin(np.where(live, np.abs(np.abs(f) - target), np.nan)))
        picks.append((i, "mid thrust"))
    return picks


def _step_trace(store: Store, step_id: int) -> tuple[np.ndarray, np.ndarray]:
    data = store.step_samples(step_id, ("t_s", "thrust_n"))
    return data["t_s"], data["thrust_n"]


def _time_series(store: Store, sec: DepthSection, step_ids: dict[int, int],
                 vent: list[dict], unit: str, suffix: str, fmt: str) -> FigureItem:
    base = ("time-series", f"fig-time-series{suffix}",
            "Time series of chosen points" + (f" at {sec.label}" if suffix else ""))
    p = sec.points
    traces = []
    for row, why in chosen_points(p):
        t, y = _step_trace(store, step_ids[int(p.step_idx[row])])
        keep = np.isfinite(y)
        t, y = t[keep], y[keep]
        if t.size < 2:
            continue
        t0 = float(t[0])
        spans = [(max(float(e["t_s"]) - t0, 0.0),
                  min(float(e["t_s"]) + _vent_length(e) - t0, float(t[-1] - t0)))
                 for e in vent if e.get("t_s") is not None]
        label = (f"point {int(p.step_idx[row])}: {p.command[row]:g} {unit}, "
                 f"{p.direction[row]}, {why}")
        traces.append(fg.Trace(label, t - t0, y, float(p.window_start_s[row]),
                               float(p.thrust.mean[row]), [s for s in spans if s[1] > s[0]]))
    if not traces:
        return FigureItem(*base, "No point with recorded thrust samples to show.")
    return FigureItem(*base, "Thrust (N) vs time (s) within the chosen points; the steady "
                      "window used for the statistics is shaded green.",
                      fg.encode(fg.time_series(traces), fmt))


def _vent_length(event: dict) -> float:
    d = event.get("detail") or {}
    try:
        return float(d["t_end_s"]) - float(d["t_start_s"])
    except (KeyError, TypeError, ValueError):
        return 0.0

