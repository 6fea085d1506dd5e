"""What every vehicle artefact is built from (rigtool.artefacts.formats writes them): the
section (the deepest depth: the thruster's own thrust, shallower points may ventilate), its
inverse tables and thrust map, the dynamics of a step-response run (the calibrated run itself,
or one given with --dynamics), the user's options and the stored texts (docs/artefacts.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rigtool.analysis.dynamics import (
    CONSUMERS,
    QUADRATIC_SPEED,
    Dynamics,
    exported_yoerger,
    first_order_tau,
    selected_tau,
)
from rigtool.analysis.results import CalibrationResult, DepthSection
from rigtool.artefacts.write import csv_cell
from rigtool.models.thrust_map import Table, ThrustMap, thrust_map
from rigtool.sections import default_section
from rigtool.version import __version__

RAD_S_PER_RPM = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class DynamicsSource:
    """Identified thruster dynamics and the step-response run they come from."""

    run_id: str
    dynamics: Dynamics

    def params(self, cp_fwd: float = math.nan, cp_rev: float = math.nan
               ) -> dict[str, float | str]:
        """The selected model's parameters in SI units, as the artefacts name them, and the
        simpler models consumers take (rise/fall time constants, Yoerger's alpha and beta: in
        propeller speed (r/min) when C_p_fwd is given) with their deviation from it."""
        d = self.dynamics
        m = d.model
        rho = m.reverse_ratio.value if m.reverse_ratio else math.nan
        rf, yo = d.rise_fall, exported_yoerger(d)
        out: dict[str, float | str] = {
            "dynamics_model": m.name, "dynamics_source_run": self.run_id,
            "time_constant_s": selected_tau(d).value,
            "first_order_time_constant_s": first_order_tau(d).value,
            "inflow_time_constant_s": m.tau_a_s.value if m.tau_a_s else math.nan,
            "inflow_gain": m.gain.value if m.gain else 0.0,
            "command_delay_s": m.delay_s.value, "dynamics_reverse_ratio": rho,
            "rise_time_constant_s": rf.tau_n_s.value if rf else math.nan,
            "fall_time_constant_s": rf.tau_fall_s.value if rf and rf.tau_fall_s else math.nan}
        yo_rho = yo.reverse_ratio.value if yo is not None and yo.reverse_ratio else math.nan
        out |= _yoerger_params(yo.alpha.value if yo is not None and yo.alpha else math.nan,
                               yo_rho, cp_fwd, cp_rev)
        if m.inflow_beta is not None:
            out["healey_inflow_beta"] = _scaled_beta(m.inflow_beta.value, out, cp_fwd)
        scale = d.full_scale_n
        for name in CONSUMERS:
            err = d.consumer_error_n.get(name, math.nan)
            out[ERROR_KEYS[name]] = err / scale if scale and scale > 0 else math.nan
        return out


def usable(dynamics: DynamicsSource | None) -> DynamicsSource | None:
    """`dynamics` when it holds identified dynamics, else None (no export carries them)."""
    return dynamics if dynamics is not None and dynamics.dynamics.identified else None


def no_dynamics(dynamics: DynamicsSource | None) -> str:
    """Why an artefact has no time constants."""
    if dynamics is None:
        return "no step-response run was given (--dynamics RUN)"
    return "the step-response run gave no identified dynamics (see its calibration warnings)"


ERROR_KEYS = {"first-order": "first_order_error_frac", "rise-fall": "rise_fall_error_frac",
              "yoerger": "yoerger_error_frac"}


def _yoerger_params(alpha: float, rho: float, cp_fwd: float, cp_rev: float) -> dict[str, float | str]:
    """Yoerger's n' = beta f_cmd - alpha n|n| for a thrust command f_cmd (N): in r/min with the
    calibration's C_p (thrust C_p n|n|), else in sqrt(N) with C_p_fwd = 1, C_p_rev = rho; the
    C_p of each direction is alpha / beta."""
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
RISE_FALL_MODEL = ("speed s follows its steady value (s|s| = the steady thrust) with "
                   "rise_time_constant_s while |s| grows (s (S - s) >= 0, S the steady value) "
                   "and fall_time_constant_s while it shrinks; thrust = s|s|; a command acts "
                   "command_delay_s after it is sent (docs/dynamics.md)")
YOERGER_MODEL = ("Yoerger: state n' = yoerger_beta f_cmd - yoerger_alpha n|n| for a thrust "
                 "command f_cmd (N; beta per direction), thrust C_p n|n| (n in "
                 "yoerger_state_unit: r/min with the C_p above, or sqrt(N) with C_p = 1 forward, "
                 "dynamics_reverse_ratio reverse); time_constant_s is its time constant at the "
                 "largest thrust measured; a command acts command_delay_s after it is sent "
                 "(docs/dynamics.md)")
CONSUMER_MODELS = ("; for consumers with a simpler model, whatever the model above: a "
                   "first-order lag of s with first_order_time_constant_s alone; the same with "
                   "rise_time_constant_s while |s| grows and fall_time_constant_s while it "
                   "shrinks; Yoerger's n' = beta f_cmd - yoerger_alpha n|n| (beta: "
                   "yoerger_beta_forward for f_cmd >= 0, else yoerger_beta_reverse) with thrust "
                   "(yoerger_alpha / beta) n|n|, beta by the sign of n, n in yoerger_state_unit "
                   "(each with command_delay_s); first_order_error_frac, rise_fall_error_frac, "
                   "yoerger_error_frac: each one's RMS deviation from the model above over the "
                   "step run, as a fraction of full scale (adequate up to 0.02; NaN: not fitted)")


HEALEY_MODEL = ("; Healey inflow instead of that: m' = healey_inflow_beta (s|s| - m|m|) and "
                "thrust = C_p (s|s| + inflow_gain |s| (s - m)), s the speed state in its units "
                "above; inflow_time_constant_s is the inflow's time constant at the largest "
                "thrust measured")


def model_text(params: dict[str, float | str]) -> str:
    """The model description of an artefact's dynamics parameters: the selected model's
    (`dynamics_model` decides), then the simpler models' when they are there."""
    model = params.get("dynamics_model")
    text = (YOERGER_MODEL if model in QUADRATIC_SPEED else RISE_FALL_MODEL
            if model == "rise-fall" else DYNAMICS_MODEL)
    if "healey_inflow_beta" in params:
        text += HEALEY_MODEL
    return text + CONSUMER_MODELS if "rise_time_constant_s" in params else text


@dataclass(frozen=True)
class ExportOptions:
    """What a consumer needs that no run holds: names in the vehicle's model (joint, link,
    namespace, propeller mesh and material) and the thruster's index among the vehicle's
    thrusters (1-based)."""

    joint: str | None = None
    link: str | None = None
    namespace: str | None = None
    index: int | None = None
    mesh: str | None = None  # the propeller's mesh file (Stonefish)
    material: str | None = None  # the propeller's material (Stonefish)


@dataclass(frozen=True)
class ExportInput:
    """Everything an artefact is made of: the calibration, the section it describes, the
    creation time, the dynamics (None: none identified or given) and the options."""

    cal: CalibrationResult
    sec: DepthSection
    created: str
    dynamics: DynamicsSource | None
    options: ExportOptions

    @cached_property
    def tables(self) -> list[Table]:
        """The inverse table of each branch, as inverse_lut.csv writes it."""
        return branches(self.sec)

    @cached_property
    def map(self) -> ThrustMap:
        """Thrust -> command with the vehicle semantics (rigtool.models.thrust_map)."""
        curve = self.sec.curve
        if curve is None:
            return ThrustMap(float(self.cal.neutral_command), ())
        return thrust_map(self.tables, self.cal.neutral_command, curve.command,
                          _as_written(curve.thrust_fit_n))

    def coef(self, name: str) -> float:
        """A coefficient of the section (NaN where it was not fitted)."""
        c = self.sec.fits.get(name)
        return math.nan if c is None else float(c.value)

    @property
    def dead_zones(self) -> list[tuple[float, float]]:
        """The section's dead zones (command lo, hi)."""
        return [] if self.sec.curve is None else [tuple(z) for z in self.sec.curve.dead_zones]

    @property
    def texts(self) -> dict[str, str]:
        """The stored texts every artefact carries, by parameter name: as values, never
        comments (each format encodes them for its grammar)."""
        return {"source_run": self.cal.run_id, "run_name": self.cal.run_name,
                "thruster_id": self.cal.thruster_id or "", "created_utc": self.created,
                "command_unit": self.cal.command_unit}

    def head(self, names: Sequence[str]) -> list[str]:
        """An artefact's comment lines: no stored text, `names` tell where the texts are."""
        sec = self.sec
        depth = "not set" if sec.depth_m is None else f"{sec.depth_m:g} m"
        if sec.voltage_v is not None:
            depth += f", supply {sec.voltage_v:g} V"
        return [f"rigtool {__version__}: thruster calibration, depth {depth}. Generated: "
                "make it again with rigtool export-cal rather than edit it.",
                f"source run, run name, thruster, creation time, command unit: "
                f"{', '.join(names)}.",
                "units: thrust N, command in the command unit, speed r/min (docs/artefacts.md)."
                + self.law_note]

    @property
    def law_note(self) -> str:
        """How far the one coefficient C_p |n| n is from the law chosen per direction, for
        the formats that take one coefficient (empty without a thrust law)."""
        parts = [f"{100 * law['quadratic_max_miss_frac']:.1f} % {word}"
                 for key, word in (("fwd", "forward"), ("rev", "reverse"))
                 if (law := self.sec.thrust_law.get(key)) is not None]
        if not parts:
            return ""
        return (" C_p |n| n misses the thrust law chosen on held-out points by up to "
                f"{', '.join(parts)} of full-scale thrust from 10 to 100 % speed "
                "(calibration.json thrust_law).")

    def dynamics_params(self) -> dict[str, float | str] | None:
        """The identified dynamics' parameters (None: none to carry)."""
        if usable(self.dynamics) is None:
            return None
        return self.dynamics.params(self.coef("C_p_fwd"), self.coef("C_p_rev"))


def deepest(cal: CalibrationResult) -> DepthSection:
    """The section the vehicle artefacts describe: the default section (rigtool.sections), as
    the Python API's."""
    return cal.sections[default_section([s.depth_m for s in cal.sections],
                                        [s.voltage_v for s in cal.sections])]


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


