"""A C99 header: coefficients, dead zones, the time constants, the inverse table of every
branch (the outermost of each direction run on to the largest thrust measured), the lookup
functions with the vehicle semantics of rigtool.models.thrust_map, and a test vector."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from rigtool.artefacts.encode import c_string
from rigtool.artefacts.vehicle import ExportInput, model_text, no_dynamics

FILE = "thruster_calibration.h"
FOLLOWS = "C99 (any compiler; checked with gcc -std=c99 -Wall -Werror -pedantic)"
N_TEST = 9  # test-vector thrusts per branch
STATUS = {"OK": 0, "CLAMPED": 1, "BELOW_MIN": 2, "NAN": 3, "GAP": 4}
DYNAMICS_MACROS = {  # a key inside another key comes after it (the model text is replaced)
    "inflow_time_constant_s": "RIGTOOL_TAU_A_S", "rise_time_constant_s": "RIGTOOL_TAU_RISE_S",
    "fall_time_constant_s": "RIGTOOL_TAU_FALL_S",
    "first_order_time_constant_s": "RIGTOOL_TAU_FIRST_ORDER_S",
    "time_constant_s": "RIGTOOL_TAU_N_S",
    "inflow_gain": "RIGTOOL_INFLOW_GAIN", "command_delay_s": "RIGTOOL_DELAY_S",
    "dynamics_reverse_ratio": "RIGTOOL_DYNAMICS_REVERSE_RATIO",
    "yoerger_alpha": "RIGTOOL_YOERGER_ALPHA", "yoerger_state_unit": "RIGTOOL_YOERGER_STATE_UNIT",
    "yoerger_beta_forward": "RIGTOOL_YOERGER_BETA_FWD",
    "yoerger_beta_reverse": "RIGTOOL_YOERGER_BETA_REV",
    "first_order_error_frac": "RIGTOOL_FIRST_ORDER_ERROR_FRAC",
    "rise_fall_error_frac": "RIGTOOL_RISE_FALL_ERROR_FRAC",
    "yoerger_error_frac": "RIGTOOL_YOERGER_ERROR_FRAC"}

LOOKUP = """\
/* The command giving thrust_n (N), and in *status why (RIGTOOL_CMD_*): the neutral command
   for 0 N; linear interpolation in the first branch whose thrust range holds thrust_n; beyond
   the largest thrust measured in that direction, that direction's extreme command (CLAMPED);
   between 0 and the smallest thrust the thruster makes outside its dead band, the neutral
   command (BELOW_MIN); between two branches, the nearer branch end (GAP); NAN for NAN. */
static inline double rigtool_command_for_thrust_status(double thrust_n, int *status)
{
    double sign, near_gap = INFINITY, near_cmd, min_mag = INFINITY, max_mag = -1.0, max_cmd;
    *status = RIGTOOL_CMD_OK;
    if (thrust_n != thrust_n) { *status = RIGTOOL_CMD_NAN; return NAN; }
    if (thrust_n == 0.0) return RIGTOOL_NEUTRAL_COMMAND;
    sign = thrust_n > 0.0 ? 1.0 : -1.0;
    near_cmd = max_cmd = RIGTOOL_NEUTRAL_COMMAND;
    for (int b = 0; b < RIGTOOL_N_BRANCHES; ++b) {
        int lo = rigtool_branch_start[b], hi = rigtool_branch_start[b + 1] - 1;
        if (thrust_n >= rigtool_lut_thrust[lo] && thrust_n <= rigtool_lut_thrust[hi]) {
            while (hi - lo > 1) {
                int mid = (lo + hi) / 2;
                if (rigtool_lut_thrust[mid] <= thrust_n) lo = mid; else hi = mid;
            }
            if (hi == lo || rigtool_lut_thrust[hi] == rigtool_lut_thrust[lo])
                return rigtool_lut_command[lo];
            return rigtool_lut_command[lo] + (thrust_n - rigtool_lut_thrust[lo])
                   / (rigtool_lut_thrust[hi] - rigtool_lut_thrust[lo])
                   * (rigtool_lut_command[hi] - rigtool_lut_command[lo]);
        }
    }
    for (int b = 0; b < RIGTOOL_N_BRANCHES; ++b) {
        int ends[2];
        if (rigtool_branch_sign[b] != (int)sign) continue;
        ends[0] = rigtool_branch_start[b];
        ends[1] = rigtool_branch_start[b + 1] - 1;
        for (int e = 0; e < 2; ++e) {
            double m = sign * rigtool_lut_thrust[ends[e]];
            double gap = fabs(rigtool_lut_thrust[ends[e]] - thrust_n);
            if (gap < near_gap) { near_gap = gap; near_cmd = rigtool_lut_command[ends[e]]; }
            if (m < min_mag) min_mag = m;
            if (m > max_mag) { max_mag = m; max_cmd = rigtool_lut_command[ends[e]]; }
        }
    }
    if (max_mag < 0.0) { *status = RIGTOOL_CMD_CLAMPED; return RIGTOOL_NEUTRAL_COMMAND; }
    if (sign * thrust_n < min_mag) { *status = RIGTOOL_CMD_BELOW_MIN; return RIGTOOL_NEUTRAL_COMMAND; }
    if (sign * thrust_n > max_mag) { *status = RIGTOOL_CMD_CLAMPED; return max_cmd; }
    *status = RIGTOOL_CMD_GAP;
    return near_cmd;
}

/* The same command without the status. */
static inline double rigtool_command_for_thrust(double thrust_n)
{
    int status;
    return rigtool_command_for_thrust_status(thrust_n, &status);
}

/* The older answer, for those who want it: NAN unless the status is RIGTOOL_CMD_OK. */
static inline double rigtool_command_for_thrust_strict(double thrust_n)
{
    int status;
    double command = rigtool_command_for_thrust_status(thrust_n, &status);
    return status == RIGTOOL_CMD_OK ? command : NAN;
}
"""


def needs(x: ExportInput) -> list[str]:
    """A lookup table: a live branch on the command curve."""
    if not x.tables:
        return ["no command curve with a live branch, so there is no lookup table"]
    return []


def _c(v: float) -> str:
    return "NAN" if not math.isfinite(v) else repr(float(v))


def _c_array(kind: str, name: str, values: Sequence[float]) -> str:
    body = ", ".join(_c(v) if kind == "double" else str(int(v)) for v in values)
    return f"static const {kind} {name}[] = {{{body or ('NAN' if kind == 'double' else '0')}}};"


def test_thrusts(x: ExportInput) -> np.ndarray:
    """The test vector's thrusts: across each branch, zero, and each direction's edges (beyond
    the largest, below the smallest, a NaN is left out: C's NAN never compares equal)."""
    tables = x.map.tables
    parts = [np.linspace(f[0], f[-1], N_TEST) for _, f, _ in tables] + [np.array([0.0])]
    for direction, sign in (("forward", 1.0), ("reverse", -1.0)):
        lim = x.map.limits(direction)
        if lim is not None:
            parts.append(sign * np.array([0.5 * lim[0], 1.5 * lim[1]]))
    return np.concatenate(parts)


def render(x: ExportInput) -> str:
    """The header's text."""
    tables = x.map.tables
    starts = np.cumsum([0] + [t[1].size for t in tables])
    test_f = test_thrusts(x)
    test_c, test_s = x.map.command(test_f)
    zones = x.dead_zones
    guard = "RIGTOOL_THRUSTER_CALIBRATION_H"
    texts = {f"RIGTOOL_{k.upper()}": v for k, v in x.texts.items()}
    lines = ["/*", *(f" * {line}" for line in x.head(list(texts))), " */", "",
             f"#ifndef {guard}", f"#define {guard}", "", "#include <math.h>", "",
             *(f"#define {name} {c_string(text)}" for name, text in texts.items()),
             f"#define RIGTOOL_NEUTRAL_COMMAND {_c(x.cal.neutral_command)}",
             f"#define RIGTOOL_C_P_FWD {_c(x.coef('C_p_fwd'))} /* N/(r/min)^2: f = C_p |n| n, "
             "n > 0 */",
             f"#define RIGTOOL_C_P_REV {_c(x.coef('C_p_rev'))} /* N/(r/min)^2: n < 0 */",
             f"#define RIGTOOL_N_DEAD_ZONES {len(zones)}",
             _c_array("double", "rigtool_dead_zones", [v for z in zones for v in z])
             + " /* command pairs lo, hi; one NAN when there are none */",
             f"#define RIGTOOL_N_BRANCHES {len(tables)}",
             _c_array("int", "rigtool_branch_start", starts),
             _c_array("int", "rigtool_branch_sign",
                      [1 if d == "forward" else -1 for d, _, _ in tables])
             + " /* +1 forward, -1 reverse */",
             "#define RIGTOOL_BRANCH_DIRECTIONS "
             + c_string(", ".join(d for d, _, _ in tables)) + " /* in branch order */",
             _c_array("double", "rigtool_lut_thrust", np.concatenate([f for _, f, _ in tables]))
             + " /* N, ascending per branch */",
             _c_array("double", "rigtool_lut_command",
                      np.concatenate([c for _, _, c in tables])),
             "", *_dynamics(x), "",
             *(f"#define RIGTOOL_CMD_{k} {v}" for k, v in STATUS.items()), "",
             LOOKUP,
             "/* Test vector: rigtool_command_for_thrust_status(rigtool_test_thrust[i], &s) gives",
             "   rigtool_test_command[i] with s == rigtool_test_status[i]. */",
             f"#define RIGTOOL_N_TEST {test_f.size}",
             _c_array("double", "rigtool_test_thrust", test_f),
             _c_array("double", "rigtool_test_command", test_c),
             _c_array("int", "rigtool_test_status", test_s),
             "", f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def _dynamics(x: ExportInput) -> list[str]:
    d = x.dynamics_params()
    if d is None:
        return [f"#define RIGTOOL_HAS_DYNAMICS 0 /* {no_dynamics(x.dynamics)}: no time "
                "constants */"]
    text = model_text(d)
    for key, macro in DYNAMICS_MACROS.items():
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
    lines += [f"#define {DYNAMICS_MACROS[key]} {_c(d[key])}{note}" for key, note in (
        ("first_order_time_constant_s", " /* the best single lag */"),
        ("rise_time_constant_s", " /* NAN: not fitted */"), ("fall_time_constant_s", ""),
        ("first_order_error_frac", " /* deviations from the selected model, fraction of "
         "full scale */"), ("rise_fall_error_frac", ""), ("yoerger_error_frac", ""))
        if key in d]
    return lines
