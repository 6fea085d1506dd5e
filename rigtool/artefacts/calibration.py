"""Calibration artefacts: calibration.json + points/command_curve/inverse_lut CSVs (docs/artefacts.md).

Output is deterministic: sorted JSON keys, floats rounded to 10 significant digits in JSON and
written with `%.9g` in CSV, no timestamp except the `created_utc` passed in. A rerun replaces
the files (each one written to a temporary name, then renamed).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigtool.analysis.dynamics import (
    CONSUMER_LIMIT,
    MAX_MODEL_ERROR,
    Dynamics,
    DynamicsModel,
    consumer_adequate,
    exported_yoerger,
    first_order_tau,
    selected_tau,
)
from rigtool.analysis.efficiency import (
    efficiency_n_per_w,
    efficiency_resolved,
    efficiency_se_n_per_w,
    mech_power_se_w,
    mech_power_w,
    overall_efficiency,
    overall_efficiency_se,
)
from rigtool.analysis.fits import Coefficient, ZeroLine
from rigtool.analysis.results import CalibrationResult, DepthSection, VoltageLaw
from rigtool.artefacts.captive import (
    CAPTIVE_COLUMNS,
    CAPTIVE_DOC,
    CAPTIVE_FILE,
    captive_doc,
    captive_rows,
)
from rigtool.artefacts.write import (
    MISSING,
    atomic_write,
    columns_path,
    columns_text,
    csv_cell,
    csv_text,
    json_clean,
    json_text,
)
from rigtool.ids import utc_now
from rigtool.outpaths import run_folder

GRAMS_PER_NEWTON = 1000.0 / 9.80665  # grams-force per newton
FORMAT = "rigtool-calibration"
FORMAT_VERSION = 1
COMMAND_UNIT = "<command unit>"


@dataclass(frozen=True)
class CalibrationFile:
    """One file of a calibration folder: its name, when it is written, how it is rendered
    (from the calibration and the creation time) and its line in docs/artefacts.md."""

    key: str
    name: str
    written: Callable[[CalibrationResult], bool]
    render: Callable[[CalibrationResult, str], str]
    doc: str
    listed: bool = True  # named in calibration.json `files` (captive.csv is in `captive`)


def _always(cal: CalibrationResult) -> bool:
    return True


def write_artefacts(cal: CalibrationResult, out_dir: str | Path,
                    created_utc: str | None = None) -> list[Path]:
    """Write the artefacts of `cal` into `out_dir`/<run-id>/ and return the file paths; a
    file this calibration does not write is removed (an earlier calibration's is wrong now).

    `created_utc` (ISO-8601) is the only timestamp written; pass the same value to get
    byte-identical files on a rerun. It defaults to now.
    """
    created = created_utc or utc_now()
    target = run_folder(out_dir, cal.run_id)
    target.mkdir(parents=True, exist_ok=True)
    paths = []
    for file in CALIBRATION_FILES:
        if file.written(cal):
            paths.append(atomic_write(target / file.name, file.render(cal, created)))
        else:
            (target / file.name).unlink(missing_ok=True)
    return paths


def _csv_head(cal: CalibrationResult, created: str) -> list[str]:
    return [f"rigtool {cal.tool_version} calibration of run {cal.run_id}, created {created}",
            f"command unit: {cal.command_unit}; missing values are written as {MISSING}"]


def lut_text(cal: CalibrationResult) -> str:
    """inverse_lut.csv: the inverse lookup table of every section (its columns are documented
    in docs/artefacts.md and in the calibration folder's inverse_lut.columns.csv)."""
    return csv_text(_units(LUT_COLUMNS, cal), lut_rows(cal))


def calibration_document(cal: CalibrationResult, created_utc: str) -> dict:
    """The content of calibration.json as JSON-safe Python data (also usable as a store summary)."""
    all_points = [s.points for s in cal.sections]
    start = np.concatenate([p.window_start_s for p in all_points])
    kept = np.concatenate([p.kept_fraction for p in all_points])
    return json_clean({
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "tool_version": cal.tool_version,
        "created_utc": created_utc,
        "source": {
            "run_id": cal.run_id,
            "run_name": cal.run_name,
            "run_status": cal.run_status,
            "command_unit": cal.command_unit,
            "neutral_command": cal.neutral_command,
            "thruster_id": cal.thruster_id,
            "propeller_diameter_m": cal.propeller_diameter_m,
            "water_density_kg_m3": cal.water_density_kg_m3,
        },
        "files": {f.key: f.name for f in CALIBRATION_FILES
                  if f.listed and f.key != "calibration" and f.written(cal)},
        "analysis": dataclasses.asdict(cal.params),
        "steady_window": {
            "method": "block-mean settling criterion (see analysis.settling)",
            "n_points": int(start.size),
            "n_points_unsteady": int(sum(int(p.unsteady.sum()) for p in all_points)),
            "window_start_s": _spread(start),
            "kept_fraction": _spread(kept),
            "se_method": "max(AR(1) effective-sample-size SE, batch-means SE)",
        },
        "depths": [_section_doc(s) for s in cal.sections],
        "voltage_laws": [_voltage_law_doc(law) for law in cal.voltage_laws],
        "dynamics": None if cal.dynamics is None else _dynamics_doc(cal.dynamics),
        "tare_drift": None if cal.drift is None else {
            "slope": _coef_doc(cal.drift.slope),
            "n_tares": int(cal.drift.t_s.size),
            "zero_scatter_n": cal.drift.zero_scatter_n,
            "max_abs_bias_n": float(np.max(np.abs(cal.drift.bias_n))),
        },
        "warnings": list(cal.warnings),
        **({} if cal.captive is None else {"captive": captive_doc(cal.captive, _coef_doc)}),
    })


def _spread(values: np.ndarray) -> dict:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return {"min": None, "median": None, "max": None}
    return {"min": float(v.min()), "median": float(np.median(v)), "max": float(v.max())}


def _coef_doc(c: Coefficient) -> dict:
    stat_lo, stat_hi = c.statistical
    return {"value": c.value, "lo": c.lo, "hi": c.hi, "stat_lo": stat_lo, "stat_hi": stat_hi,
            "systematic": c.systematic, "unit": c.unit, "n": c.n, "r2": c.r2, "rms": c.rms,
            "rms_unit": c.rms_unit, "note": c.note}


def _efficiency_doc(sec: DepthSection) -> dict | None:
    """Best thrust per electrical watt among the live points at or above the resolution
    floor (None without power)."""
    p = sec.points
    live = (p.status == "ok") & ~p.dead
    eff = np.where(live, efficiency_n_per_w(p), np.nan)
    if not np.isfinite(eff).any():
        return None
    i = int(np.nanargmax(eff))
    below = live & (p.power.mean > 0) & ~efficiency_resolved(p)
    floor = p.power_floor_w[i] if p.power_floor_w.size == len(p) else 0.0
    return {"max_n_per_w": float(eff[i]), "max_g_per_w": float(eff[i]) * GRAMS_PER_NEWTON,
            "se_n_per_w": float(efficiency_se_n_per_w(p)[i]), "at_command": float(p.command[i]),
            "at_thrust_n": float(p.thrust_corrected_n[i]), "power_w": float(p.power.mean[i]),
            "n_points": int(np.isfinite(eff).sum()),
            "power": "mean over the steady window of V * |I| sample by sample",
            "power_floor_w": float(floor), "n_below_floor": int(below.sum()),
            "floor": "no efficiency where half a printed step of current, voltage or thrust "
                     "moves it by more than 5 % (points.csv: nan)",
            "overall": _overall_doc(p)}


def _overall_doc(p) -> dict | None:
    """Best shaft power over electrical power among the live points (None without torque)."""
    eta = np.where((p.status == "ok") & ~p.dead, overall_efficiency(p), np.nan)
    if not np.isfinite(eta).any():
        return None
    i = int(np.nanargmax(eta))
    return {"max": float(eta[i]), "se": float(overall_efficiency_se(p)[i]),
            "at_command": float(p.command[i]), "mech_power_w": float(mech_power_w(p)[i]),
            "power_w": float(p.power.mean[i]),
            "definition": "|Q| omega / (V |I|): shaft power over electrical power"}


def _section_doc(sec: DepthSection) -> dict:
    curve = None
    if sec.curve is not None:
        curve = {
            "dead_floor_n": sec.curve.floor_n,
            "dead_zones": [list(r) for r in sec.curve.dead_zones],
            "start_stop": {side: {"stop": stop, "start": start}
                           for side, (stop, start) in sec.curve.start_stop.items()} or None,
            "saturated": [list(r) for r in sec.curve.saturated],
            "break_aways": list(sec.curve.break_aways),
            "branches": [{
                "index": i,
                "direction": b.direction,
                "command_lo": b.command_lo,
                "command_hi": b.command_hi,
                "slope_sign": b.slope_sign,
                "inverted": bool(b.inverted),
                "saturated": None if b.saturated is None else list(b.saturated),
                "usable": None if b.usable is None else list(b.usable),
                "break_aways": list(b.break_aways),
                "lut_thrust_min_n": float(b.lut_thrust_n.min()) if b.lut_thrust_n.size else None,
                "lut_thrust_max_n": float(b.lut_thrust_n.max()) if b.lut_thrust_n.size else None,
            } for i, b in enumerate(sec.curve.branches)],
        }
    h, r, z = sec.hysteresis, sec.repeatability, sec.zero
    return {
        "depth_m": sec.depth_m,
        "supply_voltage_v": sec.voltage_v,
        "bus_voltage_mean_v": sec.bus_v,
        "zero": None if z is None else _zero_doc(z, sec.drift_design),
        "n_points": len(sec.points),
        "n_points_used_in_fits": int(sec.points.used_in_fits.sum()),
        "speed_sign": sec.speed_sign,
        "coefficients": {name: _coef_doc(c) for name, c in sec.fits.items()},
        "current_law": _current_law_doc(sec.fits),
        "thrust_law": sec.thrust_law or None,
        "sensor_accuracy": sec.sensor_accuracy or None,
        "command_curve": curve,
        "hysteresis": None if h is None else {
            "max_abs_n": h.max_abs_n, "at_command": h.at_command, "n_commands": int(h.command.size)},
        "efficiency": _efficiency_doc(sec),
        "repeatability": None if r is None else {
            "max_std_n": r.max_std_n, "median_std_n": r.median_std_n,
            "n_groups": int(r.command.size)},
        "warnings": list(sec.warnings),
    }


def _zero_doc(z: ZeroLine, design: str = "") -> dict:
    """The zero entry: offset at t_ref and drift, and whether the design let a drift be
    estimated (`drift_design`); a resumed run's later sessions (each tared again) add
    `sessions`, the time each begins and its own offset at t_ref."""
    doc = {"source": z.source, "offset_n": z.offset_n,
           "drift_n_per_h": z.drift_n_per_s * 3600.0, "t_ref_s": z.t_ref_s}
    if design:
        doc["drift_design"] = design
    if z.session_starts_s:
        doc["sessions"] = [{"start_s": start, "offset_n": offset} for start, offset in
                           zip((None, *z.session_starts_s), z.offsets.tolist(), strict=True)]
    return doc


def _current_law_doc(fits: dict[str, Coefficient]) -> dict | None:
    """The current law the current-based thrust (C_i, sigma_i) uses (None without one)."""
    if "C_n" not in fits:
        return None
    if "current_exponent" in fits:
        return {"exponent": fits["current_exponent"].value, "coefficient": "C_free",
                "idle_current": "I_0_free", "law": "I = C_free |n|^k + I_0_free",
                "thrust_from_current": "f = C_i (I - I_0_free)^(2/k), k = exponent",
                "why": "the free exponent k_free excludes 3 (see warnings)"}
    return {"exponent": 3.0, "coefficient": "C_n", "idle_current": "I_0",
            "law": "I = C_n |n|^3 + I_0", "thrust_from_current": "f = C_i (I - I_0)^(2/3)",
            "why": "textbook law; the free exponent k_free does not exclude 3"}


def _model_doc(m: DynamicsModel) -> dict:
    optional = {"tau_a": m.tau_a_s, "g": m.gain, "alpha": m.alpha, "beta": m.inflow_beta,
                "rho": m.reverse_ratio, "tau_fall": m.tau_fall_s,
                "fall_minus_rise": m.fall_minus_rise}
    return {"tau_n": _coef_doc(m.tau_n_s), "delay": _coef_doc(m.delay_s),
            **{k: None if c is None else _coef_doc(c) for k, c in optional.items()},
            "rms_n": m.rms_n, "bic": m.bic, "aic": m.aic, "n_samples": m.n_samples,
            "heldout_rms_n": m.heldout_rms_n, "heldout_noise_n": m.heldout_noise_n,
            "model_error_n": m.model_error_n()}


def _dynamics_doc(d: Dynamics) -> dict:
    m = d.model
    return {
        "model": "x' = (X - x) / tau_n (one-state, two-state, healey-lag; rise-fall: tau_n "
                 "while |x| grows, x (X - x) >= 0, tau_fall while it shrinks) or x' = alpha "
                 "(X|X| - x|x|) (yoerger, healey); two-state: m' = (x - m) / tau_a and thrust c (x|x| + "
                 "g (x|x| - m|m|)); healey, healey-lag: m' = beta (x|x| - m|m|) and thrust c "
                 "(x|x| + g |x| (x - m)); else thrust c x|x|; x in sqrt(N), X|X| the steady "
                 "thrust of the command (divided by rho in reverse), c = 1 for x >= 0 and rho = "
                 "C_p_rev / C_p_fwd below; the command acts `delay` s after it is sent "
                 "(docs/dynamics.md)",
        "selected": d.selected,
        "selected_by": "held-out steps (two-state, healey-lag, healey also by BIC and their "
                       "gain; rise-fall by BIC and rise and fall constants that differ)",
        "identified": d.identified,
        "reason": d.reason,
        "models": {name: None if mm is None else _model_doc(mm) for name, mm in d.slots()},
        "adequacy": {"heldout_rms_n": m.heldout_rms_n, "noise_rms_n": m.heldout_noise_n,
                     "model_error_n": m.model_error_n(), "full_scale_n": d.full_scale_n,
                     "model_error_frac": m.model_error_n() / d.full_scale_n
                     if d.full_scale_n else None, "limit_frac": MAX_MODEL_ERROR},
        "time_constant_s": selected_tau(d).value if d.identified else None,
        "first_order_time_constant_s": first_order_tau(d).value if d.identified else None,
        "rise_time_constant_s": d.rise_fall.tau_n_s.value
        if d.identified and d.rise_fall is not None else None,
        "fall_time_constant_s": d.rise_fall.tau_fall_s.value
        if d.identified and d.rise_fall is not None and d.rise_fall.tau_fall_s else None,
        "consumers": _consumers_doc(d),
        "zero_n": d.zero_n,
        "levels": [{"command": c, "thrust_n": f} for c, f in sorted(d.levels.items())],
        "steps": [{"command_from": s.command_from, "command_to": s.command_to,
                   "thrust_from_n": s.thrust_from_n, "thrust_to_n": s.thrust_to_n,
                   "direction": s.direction, "t10_s": s.t10_s,
                   "rise_s": s.rise_s if s.settled else None,
                   "settling_s": s.settling_s, "settled": s.settled, "window_s": s.window_s,
                   "overshoot_frac": s.overshoot_frac if s.settled else None}
                  for s in d.steps],
        "warnings": list(d.warnings),
    }


def _consumer_fit(d: Dynamics, name: str, m: DynamicsModel | None) -> dict:
    """A simpler model's fit quality and its deviation from the selected model."""
    err = d.consumer_error_n.get(name, math.nan)
    scale = d.full_scale_n
    return {"from_model": None if m is None else m.name,
            "heldout_rms_n": None if m is None else m.heldout_rms_n,
            "model_error_n": None if m is None else m.model_error_n(),
            "error_n": err, "error_frac": err / scale if scale else None,
            "adequate": consumer_adequate(d, name)}


def _consumers_doc(d: Dynamics) -> dict:
    """The simpler models exported for consumers that take only them."""
    m = d.model
    rf, yo = d.rise_fall, exported_yoerger(d)
    out: dict = {
        "limit_frac": CONSUMER_LIMIT,
        "note": "each simpler model as exported (with the selected model's delay), its RMS "
                "deviation from the selected model over the step run (error_n, error_frac of "
                "full scale) and whether that is within limit_frac (adequate; never when no "
                "dynamics are identified); heldout_rms_n and model_error_n are its own fit's",
        "first-order": {"equation": "x' = (X - x) / tau, thrust c x|x|", "tau":
                        _coef_doc(first_order_tau(d)), "delay_s": m.delay_s.value,
                        **_consumer_fit(d, "first-order", d.one_state)},
        "rise-fall": None, "yoerger": None}
    if rf is not None and rf.tau_fall_s is not None and rf.fall_minus_rise is not None:
        out["rise-fall"] = {
            "equation": "x' = (X - x) / tau_rise while |x| grows (x (X - x) >= 0), "
                        "(X - x) / tau_fall while it shrinks; thrust c x|x|",
            "tau_rise": _coef_doc(rf.tau_n_s), "tau_fall": _coef_doc(rf.tau_fall_s),
            "fall_minus_rise": _coef_doc(rf.fall_minus_rise), "differ": rf.rise_fall_differ(),
            "delay_s": m.delay_s.value, **_consumer_fit(d, "rise-fall", rf)}
    if yo is not None and yo.alpha is not None:
        out["yoerger"] = {
            "equation": "x' = beta f_cmd - alpha x|x|, beta = alpha forward and alpha / rho in "
                        "reverse, thrust c x|x|; x in sqrt(N), f_cmd the commanded steady "
                        "thrust (N)",
            "alpha": _coef_doc(yo.alpha), "rho": None if yo.reverse_ratio is None else
            _coef_doc(yo.reverse_ratio), "beta_forward": _coef_doc(yo.alpha),
            "beta_reverse": _coef_doc(_beta_reverse(yo)), "delay_s": m.delay_s.value,
            **_consumer_fit(d, "yoerger", yo)}
    return out


def _beta_reverse(m: DynamicsModel) -> Coefficient:
    """alpha / rho with its interval from the two relative half-widths in quadrature."""
    a, r = m.alpha, m.reverse_ratio
    if r is None:
        return a
    value = a.value / r.value

    def rel(c: Coefficient) -> float:
        return (c.hi - c.lo) / (2 * c.value) if c.value else math.inf

    hw = value * math.hypot(rel(a), rel(r))
    return dataclasses.replace(a, name="beta_reverse", value=value, lo=value - hw, hi=value + hw,
                               note="Yoerger beta in reverse: alpha / rho")


def _voltage_law_doc(law: VoltageLaw) -> dict:
    return {
        "depth_m": law.depth_m,
        "law": "C_n(U) = k * U**b, U the supply voltage set (V), fitted to the cubic-law C_n "
               "of each voltage; C_i(U) = C_p / C_n(U)**(2/3). Each voltage's C_i is that of "
               "its own current law (current_exponent; 3 unless its depth says otherwise)",
        "k": _coef_doc(law.k), "b": _coef_doc(law.b), "k_inverse": _coef_doc(law.k_inverse),
        "cp_fwd_reduced_chi2": law.cp_chi2_red, "cp_consistent": law.cp_consistent,
        "voltages": [{
            "supply_voltage_v": v.voltage_v, "bus_voltage_mean_v": v.bus_v,
            **{name: None if c is None else _coef_doc(c) for name, c in (
                ("C_p_fwd", v.cp_fwd), ("C_p_rev", v.cp_rev), ("C_n", v.cn),
                ("C_i_fwd", v.ci_fwd), ("C_i_rev", v.ci_rev))},
            "current_exponent": v.current_exponent,
        } for v in law.points],
        "warnings": list(law.warnings),
    }


# -- CSV --------------------------------------------------------------------------------------

POINT_COLUMNS = (
    ("depth_m", "m", "depth of the propeller centre (nan: not set)"),
    ("step_idx", "", "step index in the run plan"),
    ("command", COMMAND_UNIT, "command in the actuator's unit"),
    ("repeat", "", "repeat number"),
    ("direction", "", "sweep direction: up | down"),
    ("status", "", "step status as recorded (only 'ok' points are analysed)"),
    ("n_samples", "", "samples acquired"),
    ("n_window", "", "samples in the steady window"),
    ("window_start_s", "s", "steady window start, after the first acquired sample"),
    ("t_mid_s", "s", "mean sample time of the window, run clock"),
    ("unsteady", "0/1", "1 if an excursion remains inside the window (e.g. ventilation)"),
    ("dead", "0/1", "1 if the command lies in a dead zone"),
    ("used_in_fits", "0/1", "1 if the point entered the speed/current model fits"),
    *((f"{ch}_{stat}_{u}", unit, f"{label} {text} over the steady window")
      for ch, u, unit, label in (("thrust", "n", "N", "thrust"),
                                 ("speed", "rpm", "r/min", "propeller speed"),
                                 ("current", "a", "A", "motor current"))
      for stat, text in (("mean", "mean"), ("std", "standard deviation"),
                         ("se", "standard error of the mean (autocorrelation-aware)"),
                         ("min", "minimum"), ("max", "maximum"))),
    ("thrust_peak_n", "N", "extreme on the side of the mean: max if mean >= 0 else min"),
    ("thrust_zero_n", "N", "estimated sensor zero (offset + drift) at t_mid_s; "
     "thrust_mean_n - thrust_zero_n is the thruster's thrust"),
    *((f"{ch}_{stat}_{u}", unit, f"{label} {text} over the steady window")
      for ch, u, unit, label in (("voltage", "v", "V", "bus voltage"),
                                 ("power", "w", "W", "electrical power V |I|, sample by sample,"))
      for stat, text in (("mean", "mean"), ("std", "standard deviation"),
                         ("se", "standard error of the mean"), ("min", "minimum"),
                         ("max", "maximum"))),
    ("efficiency_n_per_w", "N/W", "|thrust_mean_n - thrust_zero_n| / power_mean_w; nan below "
     "the power floor the data's resolution supports"),
    ("efficiency_se_n_per_w", "N/W", "standard error of efficiency_n_per_w"),
    ("efficiency_g_per_w", "g/W", "efficiency in grams-force per watt (manufacturer tables)"),
    ("voltage_set_v", "V", "supply voltage set for the point (nan: not swept)"),
    *((f"torque_{stat}_nm", "N m", f"torque about the thrust axis, {text} over the steady "
       "window (six-axis sensors)")
      for stat, text in (("mean", "mean"), ("std", "standard deviation"),
                         ("se", "standard error of the mean"), ("min", "minimum"),
                         ("max", "maximum"))),
    ("torque_zero_nm", "N m", "estimated torque zero at t_mid_s (fitted with C_q)"),
    ("mech_power_w", "W", "shaft power |torque_mean_nm - torque_zero_nm| * |speed| * 2 pi / 60"),
    ("mech_power_se_w", "W", "standard error of mech_power_w"),
    ("overall_efficiency", "1", "mech_power_w / power_mean_w (motor and driver together)"),
    ("overall_efficiency_se", "1", "standard error of overall_efficiency"),
)
CURVE_COLUMNS = (
    ("depth_m", "m", "depth (nan: not set)"),
    ("command", COMMAND_UNIT, "command"),
    ("n_points", "", "points pooled at this command (repeats and directions)"),
    ("state", "", "dead | live | saturated"),
    ("branch", "", "branch index (see calibration.json command_curve.branches), -1 if dead"),
    ("thrust_mean_n", "N", "mean of the point means, relative to the sensor zero"),
    ("thrust_se_n", "N", "standard error of that mean"),
    ("thrust_min_n", "N", "smallest sample over the points' windows"),
    ("thrust_max_n", "N", "largest sample over the points' windows"),
    ("thrust_fit_n", "N", "monotone (isotonic) fit of the branch; 0 in dead zones"),
    ("speed_mean_rpm", "r/min", "mean propeller speed (nan: not measured)"),
    ("current_mean_a", "A", "mean motor current (nan: not measured)"),
    ("voltage_set_v", "V", "supply voltage set (nan: not swept)"),
)
LUT_COLUMNS = (
    ("depth_m", "m", "depth (nan: not set)"),
    ("branch", "", "branch index (see calibration.json)"),
    ("direction", "", "forward (thrust > 0) | reverse (thrust < 0)"),
    ("thrust_n", "N", "thrust; strictly increasing within a (depth, branch)"),
    ("command", COMMAND_UNIT, "command giving that thrust; interpolate linearly"),
    ("voltage_set_v", "V", "supply voltage set (nan: not swept)"),
)
VOLTAGE_COLUMNS = (
    ("depth_m", "m", "depth (nan: not set)"),
    ("voltage_set_v", "V", "supply voltage set"),
    ("bus_voltage_mean_v", "V", "mean bus voltage measured over the fitted points"),
    *((f"{name}{part}", unit, f"{name} {text}")
      for name, unit in (("C_p_fwd", "N/(r/min)^2"), ("C_p_rev", "N/(r/min)^2"),
                         ("C_n", "A/(r/min)^3"), ("C_i_fwd", "N/A^(2/k)"),
                         ("C_i_rev", "N/A^(2/k)"))
      for part, text in (("", "fitted at this voltage"), ("_lo", "95 % interval, low end"),
                         ("_hi", "95 % interval, high end"))),
    ("C_n_law", "A/(r/min)^3", "C_n from the fitted law k U^b at this voltage"),
    ("current_exponent", "1", "k of the current law C_i uses at this voltage: f = C_i (I - "
     "I_0)^(2/k); 3 unless the free exponent excludes it"),
)
VOLTAGE_DOC = ["one row per (depth, supply voltage): the coefficients at that voltage;",
               "calibration.json voltage_laws holds the fitted C_n(U) = k U^b"]
POINTS_DOC = ["one row per recorded point (step); statistics over its steady window"]
CURVE_DOC = ["one row per distinct command: thrust vs command with dead/saturated states;",
             "thrust values are relative to the estimated sensor zero (calibration.json zero)"]
LUT_DOC = ["inverse lookup command(thrust) over each branch's usable range (no dead zone,",
           "no saturated range); rows sorted by depth, voltage, branch, thrust; interpolate",
           "linearly between rows of the same depth, voltage and branch, clamp outside",
           "(docs/artefacts.md)"]


def _units(columns: Sequence[tuple[str, str, str]], cal: CalibrationResult) -> list[tuple[str, str, str]]:
    return [(name, cal.command_unit if unit == COMMAND_UNIT else unit, text)
            for name, unit, text in columns]


def _depth(sec: DepthSection) -> float:
    return math.nan if sec.depth_m is None else sec.depth_m


def _volts(sec: DepthSection) -> float:
    return math.nan if sec.voltage_v is None else sec.voltage_v


def _point_rows(cal: CalibrationResult) -> Iterable[list[object]]:
    for sec in cal.sections:
        p = sec.points
        for i in range(len(p)):
            row: list[object] = [
                _depth(sec), p.step_idx[i], float(p.command[i]), p.repeat[i], p.direction[i],
                p.status[i], p.n_samples[i], p.n_window[i], float(p.window_start_s[i]),
                float(p.t_mid_s[i]), bool(p.unsteady[i]), bool(p.dead[i]),
                bool(p.used_in_fits[i])]
            for ch in (p.thrust, p.speed, p.current):
                row += [float(ch.mean[i]), float(ch.std[i]), float(ch.se[i]), float(ch.min[i]),
                        float(ch.max[i])]
            row += [float(p.thrust.peak[i]), float(p.thrust_zero_n[i])]
            for ch in (p.voltage, p.power):
                row += [float(ch.mean[i]), float(ch.std[i]), float(ch.se[i]), float(ch.min[i]),
                        float(ch.max[i])]
            eff = float(efficiency_n_per_w(p)[i])
            row += [eff, float(efficiency_se_n_per_w(p)[i]), eff * GRAMS_PER_NEWTON, _volts(sec)]
            q = p.torque
            row += [float(q.mean[i]), float(q.std[i]), float(q.se[i]), float(q.min[i]),
                    float(q.max[i]), float(p.torque_zero_nm[i]), float(mech_power_w(p)[i]),
                    float(mech_power_se_w(p)[i]), float(overall_efficiency(p)[i]),
                    float(overall_efficiency_se(p)[i])]
            yield row


def curve_rows(cal: CalibrationResult) -> Iterable[list[object]]:
    for sec in cal.sections:
        c = sec.curve
        if c is None:
            continue
        for i in range(c.command.size):
            yield [_depth(sec), float(c.command[i]), c.n_points[i], c.state[i], c.branch[i],
                   float(c.thrust_mean_n[i]), float(c.thrust_se_n[i]), float(c.thrust_min_n[i]),
                   float(c.thrust_max_n[i]), float(c.thrust_fit_n[i]), float(c.speed_mean_rpm[i]),
                   float(c.current_mean_a[i]), _volts(sec)]


def lut_rows(cal: CalibrationResult) -> Iterable[list[object]]:
    for sec in cal.sections:
        if sec.curve is None:
            continue
        thrust, command, branch = sec.curve.lut
        for f, c, b in zip(thrust, command, branch, strict=True):
            yield [_depth(sec), b, sec.curve.branches[b].direction, float(f), float(c),
                   _volts(sec)]


def voltage_rows(cal: CalibrationResult) -> Iterable[list[object]]:
    for law in cal.voltage_laws:
        for v in law.points:
            row: list[object] = [math.nan if law.depth_m is None else law.depth_m, v.voltage_v,
                                 v.bus_v]
            for c in (v.cp_fwd, v.cp_rev, v.cn, v.ci_fwd, v.ci_rev):
                row += [math.nan] * 3 if c is None else [c.value, c.lo, c.hi]
            row += [float(law.cn_at(v.voltage_v)), v.current_exponent]
            yield row


# -- manufacturer-style performance table -----------------------------------------------------

def performance_rows(cal: CalibrationResult) -> list[list[float]]:
    """One row per (depth, command) over the 'ok' points: the means of their steady-window
    means, thrust relative to the sensor zero; per supply voltage too in a voltage sweep.
    Columns: performance_header."""
    swept = _voltage_swept(cal)
    rows = []
    for sec in cal.sections:
        p = sec.points
        ok = p.status == "ok"
        f = p.thrust_corrected_n
        for command in np.unique(p.command[ok]):
            m = ok & (p.command == command)

            def mean(x: np.ndarray, m: np.ndarray = m) -> float:
                v = x[m & np.isfinite(x)]
                return float(v.mean()) if v.size else math.nan

            thrust, power = mean(f), mean(p.power.mean)
            resolved = power > 0 and bool(np.all(efficiency_resolved(p)[m]))
            g_per_w = abs(thrust) / power * GRAMS_PER_NEWTON if resolved else math.nan
            row = [_depth(sec), float(command), mean(p.speed.mean), mean(p.current.mean),
                   mean(p.voltage.mean), power, thrust, thrust / 9.80665, g_per_w]
            if swept:
                row.insert(1, _volts(sec))
            rows.append(row)
    return rows


def performance_header(command_unit: str, voltage_swept: bool = False) -> list[str]:
    """Headers with unit suffixes, in the Tyto/manufacturer style `rigtool import` reads;
    `Supply Voltage (V)` (the voltage set) only for a voltage sweep."""
    supply = ["Supply Voltage (V)"] if voltage_swept else []
    return ["Depth (m)", *supply, csv_cell(f"ESC ({command_unit})"), "Motor Optical Speed (RPM)",
            "Current (A)", "Voltage (V)", "Electrical Power (W)", "Thrust (N)", "Force (kgf)",
            "Efficiency (g/W)"]


def _voltage_swept(cal: CalibrationResult) -> bool:
    return any(sec.voltage_v is not None for sec in cal.sections)


def performance_text(cal: CalibrationResult) -> str:
    """performance.csv: a plain table (no comment lines) that spreadsheets and `rigtool
    import` read as they are (docs/artefacts.md)."""
    lines = [",".join(performance_header(cal.command_unit, _voltage_swept(cal)))]
    # a value that cannot be measured is an empty cell, as in a stand's own table
    lines += [",".join("" if isinstance(v, float) and math.isnan(v) else csv_cell(v)
                       for v in row) for row in performance_rows(cal)]
    return "\n".join(lines) + "\n"


def _table(columns: Sequence[tuple[str, str, str]],
           rows: Callable[[CalibrationResult], Iterable[list[object]]]
           ) -> Callable[[CalibrationResult, str], str]:
    """A renderer of a plain CSV table: the header row, then `rows`."""
    return lambda cal, created: csv_text(_units(columns, cal), rows(cal))


def _tables(key: str, name: str, written: Callable[[CalibrationResult], bool],
            head_doc: list[str], columns: Sequence[tuple[str, str, str]],
            rows: Callable[[CalibrationResult], Iterable[list[object]]], doc: str,
            listed: bool = True) -> tuple[CalibrationFile, CalibrationFile]:
    """A CSV table and its sidecar (`<name>.columns.csv`: the notes and each column's unit
    and meaning), written together."""
    def sidecar(cal: CalibrationResult, created: str) -> str:
        return columns_text(_csv_head(cal, created) + head_doc, _units(columns, cal))

    side = columns_path(Path(name)).name
    return (CalibrationFile(key, name, written, _table(columns, rows), doc, listed),
            CalibrationFile(f"{key}_columns", side, written, sidecar,
                            f"the notes and the columns' units and meanings of {name}",
                            listed=False))


# Every file of a calibration folder, in the order written: the one declaration that
# write_artefacts, calibration.json `files`, the docs and the goldens read.
CALIBRATION_FILES: tuple[CalibrationFile, ...] = (
    CalibrationFile("calibration", "calibration.json", _always,
                    lambda cal, created: json_text(calibration_document(cal, created)),
                    "every coefficient with its 95 % interval, unit and fit quality; dead zones, "
                    "saturated ranges, break-aways, branches; the analysis parameters; warnings"),
    *_tables("points", "points.csv", _always, POINTS_DOC, POINT_COLUMNS, _point_rows,
             "one row per recorded point: steady-window statistics of thrust, speed, current"),
    *_tables("command_curve", "command_curve.csv", _always, CURVE_DOC, CURVE_COLUMNS,
             curve_rows, "one row per distinct command: thrust vs command, state (dead / live "
             "/ saturated), monotone fit"),
    *_tables("inverse_lut", "inverse_lut.csv", _always, LUT_DOC, LUT_COLUMNS, lut_rows,
             "inverse lookup table command(thrust) for vehicle controllers"),
    CalibrationFile("performance", "performance.csv", _always,
                    lambda cal, created: performance_text(cal),
                    "manufacturer-style table, one row per command: speed, current, voltage, "
                    "electrical power, thrust (N and kgf), efficiency (g/W)"),
    *_tables("voltage", "voltage.csv", lambda cal: bool(cal.voltage_laws), VOLTAGE_DOC,
             VOLTAGE_COLUMNS, voltage_rows, "only for a run with a supply-voltage axis: the "
             "coefficients at each voltage and the fitted C_n(U)"),
    *_tables("captive", CAPTIVE_FILE, lambda cal: cal.captive is not None, CAPTIVE_DOC,
             CAPTIVE_COLUMNS, lambda cal: captive_rows(cal.captive), "only for a captive run: "
             "one row per point, the held vehicle's forces and moments at each flow speed and "
             "angle", listed=False),
)
FILES = {f.key: f.name for f in CALIBRATION_FILES}
