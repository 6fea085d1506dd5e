"""Artefacts a vehicle team drops in: a C99 header with the inverse lookup table, ROS 2
parameters, gz-sim Thruster parameters, and the CSV lookup table (docs/artefacts.md).

Each is built from the deepest depth of a calibration (the thruster's own thrust; shallower
points may ventilate) and states its units and source run; the time constants come from a
step-response run (the calibrated run itself, or one given with --dynamics).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

import rigtool
from rigtool.analysis.calibrate import Calibration, DepthSection
from rigtool.analysis.dynamics import Dynamics
from rigtool.artefacts.calibration import FILES, write_artefacts
from rigtool.artefacts.encode import c_string, scalar_text, xml_text, yaml_string
from rigtool.artefacts.write import atomic_write, csv_cell
from rigtool.errors import UsageError
from rigtool.outpaths import run_folder

FORMATS = {"c-header": "thruster_calibration.h", "ros2": "thruster_params.yaml",
           "gazebo": "thruster_gazebo.sdf", "csv-lut": FILES["inverse_lut"]}
RAD_S_PER_RPM = 2.0 * math.pi / 60.0
N_TEST = 9  # test-vector thrusts per branch


@dataclass(frozen=True)
class DynamicsSource:
    """Identified thruster dynamics and the step-response run they come from."""

    run_id: str
    dynamics: Dynamics

    def params(self, cp_fwd: float = math.nan, cp_rev: float = math.nan
               ) -> dict[str, float | str]:
        """The selected model's parameters in SI units, as the artefacts name them; a yoerger
        model's alpha and beta in propeller speed (r/min) when C_p_fwd is given."""
        m = self.dynamics.model
        rho = m.reverse_ratio.value if m.reverse_ratio else math.nan
        out: dict[str, float | str] = {
            "dynamics_model": m.name, "dynamics_source_run": self.run_id,
            "time_constant_s": m.tau_n_s.value,
            "inflow_time_constant_s": m.tau_a_s.value if m.tau_a_s else math.nan,
            "inflow_gain": m.gain.value if m.gain else 0.0,
            "command_delay_s": m.delay_s.value, "dynamics_reverse_ratio": rho}
        if m.alpha is not None:
            out |= _yoerger_params(m.alpha.value, rho, cp_fwd, cp_rev)
        if m.inflow_beta is not None:
            out["healey_inflow_beta"] = _scaled_beta(m.inflow_beta.value, out, cp_fwd)
        return out


def usable(dynamics: DynamicsSource | None) -> DynamicsSource | None:
    """`dynamics` when it holds identified dynamics, else None (no export carries them)."""
    return dynamics if dynamics is not None and dynamics.dynamics.identified else None


def _no_dynamics(dynamics: DynamicsSource | None) -> str:
    """Why an artefact has no time constants."""
    if dynamics is None:
        return "no step-response run was given (--dynamics RUN)"
    return "the step-response run gave no identified dynamics (see its calibration warnings)"


def _yoerger_params(alpha: float, rho: float, cp_fwd: float, cp_rev: float) -> dict[str, float | str]:
    """Yoerger's n' = beta f_cmd - alpha n|n| for a thrust command f_cmd (N): in r/min with the
    calibration's C_p (thrust C_p n|n|), else in sqrt(N) with C_p_fwd = 1, C_p_rev = rho."""
    if math.isfinite(cp_fwd) and cp_fwd > 0:
        rev = cp_rev if math.isfinite(cp_rev) and cp_rev > 0 else cp_fwd * rho
        a = alpha * math.sqrt(cp_fwd)
        return {"yoerger_state_unit": "r/min", "yoerger_alpha": a,
                "yoerger_beta_forward": a / cp_fwd, "yoerger_beta_reverse": a / rev}
    rev = rho if math.isfinite(rho) else 1.0
    return {"yoerger_state_unit": "sqrt(N)", "yoerger_alpha": alpha,
            "yoerger_beta_forward": alpha, "yoerger_beta_reverse": alpha / rev}


def _scaled_beta(beta: float, params: dict[str, float | str], cp_fwd: float) -> float:
    """Healey's inflow beta in the units of the speed state (r/min when C_p_fwd is known)."""
    in_rpm = params.get("yoerger_state_unit") == "r/min"
    return beta * math.sqrt(cp_fwd) if in_rpm and math.isfinite(cp_fwd) and cp_fwd > 0 else beta


DYNAMICS_MODEL = ("speed s follows its steady value (s|s| = the steady thrust) with "
                  "time_constant_s; the inflow m follows s with inflow_time_constant_s; thrust = "
                  "s|s| + inflow_gain (s|s| - m|m|); a command acts command_delay_s after it is "
                  "sent (docs/dynamics.md)")
YOERGER_MODEL = ("Yoerger: state n' = yoerger_beta f_cmd - yoerger_alpha n|n| for a thrust "
                 "command f_cmd (N; beta per direction), thrust C_p n|n| (n in "
                 "yoerger_state_unit: r/min with the C_p above, or sqrt(N) with C_p = 1 forward, "
                 "dynamics_reverse_ratio reverse); time_constant_s is its time constant at the "
                 "largest thrust measured; a command acts command_delay_s after it is sent "
                 "(docs/dynamics.md)")


HEALEY_MODEL = ("; Healey inflow instead of that: m' = healey_inflow_beta (s|s| - m|m|) and "
                "thrust = C_p (s|s| + inflow_gain |s| (s - m)), s the speed state in its units "
                "above; inflow_time_constant_s is the inflow's time constant at the largest "
                "thrust measured")


def _model_text(params: dict[str, float | str]) -> str:
    """The model description of an artefact's dynamics parameters."""
    text = YOERGER_MODEL if "yoerger_alpha" in params else DYNAMICS_MODEL
    return text + HEALEY_MODEL if "healey_inflow_beta" in params else text


def write_vehicle_artefacts(cal: Calibration, out_dir: str | Path, formats: Sequence[str],
                            created_utc: str, dynamics: DynamicsSource | None = None
                            ) -> list[Path]:
    """Write the requested formats into `out_dir`/<run-id>/ and return their paths;
    `dynamics` gives the time constants (none: the artefacts say they have none)."""
    unknown = sorted(set(formats) - set(FORMATS))
    if unknown:
        raise UsageError(f"unknown export format(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(FORMATS)}")
    folder = run_folder(out_dir, cal.run_id)
    folder.mkdir(parents=True, exist_ok=True)
    sec = deepest(cal)
    paths = []
    for fmt in dict.fromkeys(formats):
        if fmt == "csv-lut":
            paths += [p for p in write_artefacts(_storable(cal), out_dir,
                                                 scalar_text(created_utc))
                      if p.name == FORMATS["csv-lut"]]
            continue
        text = {"c-header": c_header, "ros2": ros2_params, "gazebo": gazebo_sdf}[fmt](
            cal, sec, created_utc, dynamics)
        paths.append(atomic_write(folder / FORMATS[fmt], text))
    return paths


def _storable(cal: Calibration) -> Calibration:
    """`cal` with lone surrogates in the texts the CSV comment lines carry as U+FFFD."""
    return replace(cal, run_id=scalar_text(cal.run_id), command_unit=scalar_text(cal.command_unit),
                   tool_version=scalar_text(cal.tool_version))


def deepest(cal: Calibration) -> DepthSection:
    """The section the vehicle artefacts describe: the deepest (or the only) depth and, in a
    voltage sweep, the middle supply voltage (as the Python API's default)."""
    known = [s.depth_m for s in cal.sections if s.depth_m is not None]
    depth = max(known) if known else cal.sections[0].depth_m
    here = sorted((s for s in cal.sections if s.depth_m == depth),
                  key=lambda s: -math.inf if s.voltage_v is None else s.voltage_v)
    return here[(len(here) - 1) // 2]


def branches(sec: DepthSection) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(direction, thrust ascending, command) of each branch of the inverse table, in order,
    rounded as inverse_lut.csv writes them, so every artefact holds the same numbers."""
    if sec.curve is None:
        return []
    thrust, command, branch = sec.curve.lut
    thrust, command = _as_written(thrust), _as_written(command)
    out = []
    for b in np.unique(branch):
        rows = branch == b
        order = np.argsort(thrust[rows])
        out.append((sec.curve.branches[int(b)].direction, thrust[rows][order],
                    command[rows][order]))
    return out


def _as_written(values: np.ndarray) -> np.ndarray:
    return np.array([float(csv_cell(float(v))) for v in values])


def lut_command(tables: list[tuple[str, np.ndarray, np.ndarray]], neutral: float,
                thrust_n: np.ndarray) -> np.ndarray:
    """The reference evaluation the header's function reproduces: neutral for 0 N, linear
    interpolation in the first branch whose range holds the thrust, NaN outside them all."""
    f = np.asarray(thrust_n, dtype=float)
    out = np.full(f.shape, np.nan)
    out[f == 0] = neutral
    for _, lut_f, lut_c in tables:
        take = np.isnan(out) & (f >= lut_f[0]) & (f <= lut_f[-1])
        out[take] = np.interp(f[take], lut_f, lut_c)
    return out


def _texts(cal: Calibration, created: str) -> dict[str, str]:
    """The stored texts every artefact carries, by parameter name: as values, never comments."""
    return {"source_run": cal.run_id, "run_name": cal.run_name,
            "thruster_id": cal.thruster_id or "", "created_utc": created,
            "command_unit": cal.command_unit}


def _head(sec: DepthSection, names: Sequence[str]) -> list[str]:
    """An artefact's comment lines: no stored text, `names` tell where the texts are."""
    depth = "not set" if sec.depth_m is None else f"{sec.depth_m:g} m"
    if sec.voltage_v is not None:
        depth += f", supply {sec.voltage_v:g} V"
    return [f"rigtool {rigtool.__version__}: thruster calibration, depth {depth}. Generated: "
            "do not edit.",
            f"source run, run name, thruster, creation time, command unit: {', '.join(names)}.",
            "units: thrust N, command in the command unit, speed r/min (docs/artefacts.md)."]


def _c(x: float) -> str:
    return "NAN" if not math.isfinite(x) else repr(float(x))


def _c_array(name: str, values: Sequence[float]) -> str:
    body = ", ".join(_c(v) for v in values) or "NAN"
    return f"static const double {name}[] = {{{body}}};"


def c_header(cal: Calibration, sec: DepthSection, created: str,
             dynamics: DynamicsSource | None = None) -> str:
    """A C99 header: coefficients, dead zones, the time constants, the inverse table of every
    branch, a lookup function and a test vector (thrust -> command) computed by
    `lut_command`."""
    tables = branches(sec)
    if not tables:
        raise UsageError(f"run {cal.run_id}: no command curve with a live branch, so there is "
                         "no lookup table to export")
    starts = np.cumsum([0] + [t[1].size for t in tables])
    test_f = np.concatenate([np.linspace(f[0], f[-1], N_TEST) for _, f, _ in tables] +
                            [np.array([0.0])])
    test_c = lut_command(tables, cal.neutral_command, test_f)
    coef = {k: sec.fits[k].value if k in sec.fits else math.nan
            for k in ("C_p_fwd", "C_p_rev")}
    zones = list(sec.curve.dead_zones) if sec.curve else []
    guard = "RIGTOOL_THRUSTER_CALIBRATION_H"
    texts = {f"RIGTOOL_{k.upper()}": v for k, v in _texts(cal, created).items()}
    lines = ["/*"] + [f" * {line}" for line in _head(sec, list(texts))] + [" */", "",
             f"#ifndef {guard}", f"#define {guard}", "", "#include <math.h>", "",
             *(f"#define {name} {c_string(text)}" for name, text in texts.items()),
             f"#define RIGTOOL_NEUTRAL_COMMAND {_c(cal.neutral_command)}",
             f"#define RIGTOOL_C_P_FWD {_c(coef['C_p_fwd'])} /* N/(r/min)^2: f = C_p |n| n, n > 0 */",
             f"#define RIGTOOL_C_P_REV {_c(coef['C_p_rev'])} /* N/(r/min)^2: n < 0 */",
             f"#define RIGTOOL_N_DEAD_ZONES {len(zones)}",
             _c_array("rigtool_dead_zones", [v for z in zones for v in z])
             + " /* command pairs lo, hi */",
             f"#define RIGTOOL_N_BRANCHES {len(tables)}",
             "static const int rigtool_branch_start[] = {"
             + ", ".join(str(int(s)) for s in starts) + "};",
             "#define RIGTOOL_BRANCH_DIRECTIONS "
             + c_string(", ".join(d for d, _, _ in tables)) + " /* in branch order */",
             _c_array("rigtool_lut_thrust", np.concatenate([f for _, f, _ in tables]))
             + " /* N, ascending per branch */",
             _c_array("rigtool_lut_command", np.concatenate([c for _, _, c in tables])),
             "", *_c_dynamics(dynamics, sec),
             "",
             "/* The command giving thrust_n (N): the neutral command for 0 N, linear",
             "   interpolation in the first branch whose thrust range holds thrust_n, NAN",
             "   outside every branch (not achievable). */",
             "static inline double rigtool_command_for_thrust(double thrust_n)",
             "{",
             "    if (thrust_n == 0.0) return RIGTOOL_NEUTRAL_COMMAND;",
             "    for (int b = 0; b < RIGTOOL_N_BRANCHES; ++b) {",
             "        int lo = rigtool_branch_start[b], hi = rigtool_branch_start[b + 1] - 1;",
             "        if (thrust_n < rigtool_lut_thrust[lo] || thrust_n > rigtool_lut_thrust[hi])",
             "            continue;",
             "        while (hi - lo > 1) {",
             "            int mid = (lo + hi) / 2;",
             "            if (rigtool_lut_thrust[mid] <= thrust_n) lo = mid; else hi = mid;",
             "        }",
             "        if (hi == lo || rigtool_lut_thrust[hi] == rigtool_lut_thrust[lo])",
             "            return rigtool_lut_command[lo];",
             "        double w = (thrust_n - rigtool_lut_thrust[lo])",
             "                   / (rigtool_lut_thrust[hi] - rigtool_lut_thrust[lo]);",
             "        return rigtool_lut_command[lo]",
             "               + w * (rigtool_lut_command[hi] - rigtool_lut_command[lo]);",
             "    }",
             "    return NAN;",
             "}",
             "",
             "/* Test vector: rigtool_command_for_thrust(rigtool_test_thrust[i]) should give",
             "   rigtool_test_command[i]. */",
             f"#define RIGTOOL_N_TEST {test_f.size}",
             _c_array("rigtool_test_thrust", test_f),
             _c_array("rigtool_test_command", test_c),
             "", f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def _c_dynamics(dynamics: DynamicsSource | None, sec: DepthSection) -> list[str]:
    if usable(dynamics) is None:
        return [f"#define RIGTOOL_HAS_DYNAMICS 0 /* {_no_dynamics(dynamics)}: no time "
                "constants */"]
    d = dynamics.params(_coef(sec, "C_p_fwd"), _coef(sec, "C_p_rev"))
    names = {"inflow_time_constant_s": "RIGTOOL_TAU_A_S", "time_constant_s": "RIGTOOL_TAU_N_S",
             "inflow_gain": "RIGTOOL_INFLOW_GAIN", "command_delay_s": "RIGTOOL_DELAY_S",
             "dynamics_reverse_ratio": "RIGTOOL_DYNAMICS_REVERSE_RATIO",
             "yoerger_alpha": "RIGTOOL_YOERGER_ALPHA", "yoerger_state_unit":
             "RIGTOOL_YOERGER_STATE_UNIT", "yoerger_beta_forward": "RIGTOOL_YOERGER_BETA_FWD",
             "yoerger_beta_reverse": "RIGTOOL_YOERGER_BETA_REV"}
    text = _model_text(d)
    for key, macro in names.items():
        text = text.replace(key, macro)
    lines = ["/* Dynamics, " + text + ". Seconds. */",
             "#define RIGTOOL_HAS_DYNAMICS 1",
             f"#define RIGTOOL_DYNAMICS_RUN {c_string(str(d['dynamics_source_run']))}",
             f"#define RIGTOOL_DYNAMICS_MODEL {c_string(str(d['dynamics_model']))}",
             f"#define RIGTOOL_TAU_N_S {_c(d['time_constant_s'])}",
             f"#define RIGTOOL_TAU_A_S {_c(d['inflow_time_constant_s'])} /* NAN: one-state */",
             f"#define RIGTOOL_INFLOW_GAIN {_c(d['inflow_gain'])}",
             f"#define RIGTOOL_DELAY_S {_c(d['command_delay_s'])}",
             f"#define RIGTOOL_DYNAMICS_REVERSE_RATIO {_c(d['dynamics_reverse_ratio'])} "
             "/* C_p_rev / C_p_fwd seen in steps through zero; NAN: none */"]
    if "yoerger_alpha" in d:
        lines += [f"#define RIGTOOL_YOERGER_STATE_UNIT {c_string(str(d['yoerger_state_unit']))}",
                  f"#define RIGTOOL_YOERGER_ALPHA {_c(d['yoerger_alpha'])}",
                  f"#define RIGTOOL_YOERGER_BETA_FWD {_c(d['yoerger_beta_forward'])}",
                  f"#define RIGTOOL_YOERGER_BETA_REV {_c(d['yoerger_beta_reverse'])}"]
    return lines


def _first(tables: list, direction: str) -> tuple[list[float], list[float]]:
    table = next(((f, c) for d, f, c in tables if d == direction), None)
    return ([], []) if table is None else ([float(v) for v in table[0]],
                                           [float(v) for v in table[1]])


def ros2_params(cal: Calibration, sec: DepthSection, created: str,
                dynamics: DynamicsSource | None = None) -> str:
    """ROS 2 parameters (`/**: ros__parameters:` applies them to any node that loads the file):
    coefficients per direction, dead band, time constants, command range and mapping."""
    tables = branches(sec)
    fwd_f, fwd_c = _first(tables, "forward")
    rev_f, rev_c = _first(tables, "reverse")
    texts = _texts(cal, created)
    params = {
        **texts,
        "depth_m": math.nan if sec.depth_m is None else float(sec.depth_m),
        "neutral_command": float(cal.neutral_command),
        "dead_band": [float(v) for z in (sec.curve.dead_zones if sec.curve else []) for v in z],
        "thrust_coefficient_forward": _coef(sec, "C_p_fwd"),
        "thrust_coefficient_reverse": _coef(sec, "C_p_rev"),
        "thrust_coefficient_unit": "N/(r/min)^2, f = C |n| n",
        "map_forward_thrust_n": fwd_f, "map_forward_command": fwd_c,
        "map_reverse_thrust_n": rev_f, "map_reverse_command": rev_c,
        **(_ros2_dynamics(dynamics, sec)),
    }
    head = "".join(f"# {line}\n" for line in _head(sec, list(texts)))
    head += ("# map_*: thrust (N, ascending) -> command; interpolate linearly; neutral for 0 N.\n"
             "# NaN (.nan) marks a value this run could not give.\n")
    head += (f"# dynamics: {_model_text(params)}.\n" if usable(dynamics) else
             f"# dynamics_model none: {_no_dynamics(dynamics)},\n# so there are no time "
             "constants.\n")
    return head + "/**:\n  ros__parameters:\n    rigtool:\n" + "".join(
        _yaml_entry(k, v, " " * 6) + "\n" for k, v in params.items())


def _ros2_dynamics(dynamics: DynamicsSource | None, sec: DepthSection) -> dict:
    """The ROS 2 dynamics parameters (only dynamics_model none without identified ones)."""
    if usable(dynamics) is None:
        return {"dynamics_model": "none"}
    return dynamics.params(_coef(sec, "C_p_fwd"), _coef(sec, "C_p_rev"))


def _yaml_entry(key: str, value: str | float | list[float], indent: str) -> str:
    """`key: value` for a parameter; a list of numbers wraps at 100 columns, text never."""
    line = f"{indent}{key}: {_yaml_value(value)}"
    if not isinstance(value, list):
        return line
    return textwrap.fill(line, width=100, subsequent_indent=indent + "  ",
                         break_long_words=False, break_on_hyphens=False)


def _yaml_value(value: str | float | list[float]) -> str:
    """A parameter value in YAML flow style: text through yaml_string, else numbers."""
    if isinstance(value, str):
        return yaml_string(value)
    if isinstance(value, list):
        return "[" + ", ".join(_yaml_value(v) for v in value) + "]"
    return _yaml_float(float(value))


def _yaml_float(x: float) -> str:
    """`x` as PyYAML writes a float (.nan, .inf, a point before any exponent): a float again."""
    if not math.isfinite(x):
        return ".nan" if math.isnan(x) else (".inf" if x > 0 else "-.inf")
    text = repr(x)
    return text.replace("e", ".0e", 1) if "." not in text and "e" in text else text


def _coef(sec: DepthSection, name: str) -> float:
    c = sec.fits.get(name)
    return math.nan if c is None else float(c.value)


def gazebo_sdf(cal: Calibration, sec: DepthSection, created: str,
               dynamics: DynamicsSource | None = None) -> str:
    """A gz-sim Thruster system block. The plugin computes thrust = C_T rho D^4 w|w| with w the
    propeller speed in rad/s, so C_T = C_p / (rho D^4 (2 pi / 60)^2), C_p in N/(r/min)^2; it
    clamps thrust commands to the measured range. The system has no thrust lag, so the time
    constants are extra elements it ignores, for a filter on its command."""
    cp = _coef(sec, "C_p_fwd")
    rho, d = cal.water_density_kg_m3, cal.propeller_diameter_m
    if not math.isfinite(cp):
        raise UsageError(f"run {cal.run_id}: no C_p_fwd (the run has no speed feedback), so "
                         "there is no thrust coefficient for the Gazebo thruster")
    if not rho or not d:
        raise UsageError(f"run {cal.run_id}: the Gazebo thrust coefficient needs the propeller "
                         "diameter and water density: set metadata propeller_diameter_m and "
                         "water_density_kg_m3 in the protocol")
    c_t = cp / (rho * d**4 * RAD_S_PER_RPM**2)
    rev = _coef(sec, "C_p_rev")
    rev_note = ("" if not math.isfinite(rev) else
                f" Reverse: C_T = {rev / (rho * d**4 * RAD_S_PER_RPM**2):.6g} (the plugin "
                "takes one coefficient).")
    texts = {f"rigtool_{k}": v for k, v in _texts(cal, created).items()}
    comment = " ".join(_head(sec, list(texts)))
    tables = branches(sec)
    thrusts = [float(v) for _, f, _ in tables for v in (f[0], f[-1])]
    clamp = "" if not thrusts else (f"  <max_thrust_cmd>{max(thrusts):.9g}</max_thrust_cmd>\n"
                                    f"  <min_thrust_cmd>{min(thrusts):.9g}</min_thrust_cmd>\n")
    if usable(dynamics) is None:
        lag_note = (" No time constant: no step-response run was given (the dynamics option)."
                    if dynamics is None else " No time constant: the step-response run gave "
                    "no identified dynamics.")
        lag = ""
    else:
        dp = dynamics.params(cp, rev)
        lag_note = (" The rigtool_* dynamics elements are those of the model "
                    "rigtool_dynamics_model of the run rigtool_dynamics_source_run: "
                    f"{_model_text(dp)}. The Thruster system has no lag and ignores them"
                    + ("." if "yoerger_alpha" in dp else "; with use_angvel_cmd, a first-order "
                       "filter of time constant rigtool_time_constant_s on the angular-velocity "
                       "command is the one-state model."))
        texts |= {f"rigtool_{k}": str(dp[k]) for k in ("dynamics_model", "dynamics_source_run",
                                                       "yoerger_state_unit") if k in dp}
        lag = "".join(f"  <rigtool_{k}>{_xml_num(dp[k])}</rigtool_{k}>\n" for k in (
            "time_constant_s", "inflow_time_constant_s", "inflow_gain", "command_delay_s",
            "dynamics_reverse_ratio", "yoerger_alpha", "yoerger_beta_forward",
            "yoerger_beta_reverse") if k in dp)
    return (f"<!-- {comment} -->\n"
            f"<!-- thrust = C_T rho D^4 w|w|, w in rad/s; C_T from C_p_fwd = {cp:.6g} "
            f"N/(r/min)^2.{rev_note} Thrust commands are clamped to the measured range (N)."
            f"{lag_note} -->\n"
            '<plugin filename="gz-sim-thruster-system" name="gz::sim::systems::Thruster">\n'
            "  <namespace>thruster</namespace>\n"
            "  <joint_name>propeller_joint</joint_name>\n"
            f"  <thrust_coefficient>{c_t:.9g}</thrust_coefficient>\n"
            f"  <fluid_density>{rho:.9g}</fluid_density>\n"
            f"  <propeller_diameter>{d:.9g}</propeller_diameter>\n"
            f"{clamp}{lag}"
            + "".join(f"  <{tag}>{xml_text(text)}</{tag}>\n" for tag, text in texts.items())
            + "</plugin>\n")


def _xml_num(x: float | str) -> str:
    return "nan" if isinstance(x, float) and not math.isfinite(x) else f"{float(x):.9g}"
