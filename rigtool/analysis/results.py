"""What a calibration contains: the result types of `rigtool calibrate` and of its
quasi-cavitation stage, and the parameters stored with them (docs/artefacts.md).

The analysis modules compute these; artefacts/, report/ and the stored state read them.
Stored blobs name them by tags (artefacts/state_types.py), not by this module.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from rigtool.analysis.captive import CaptiveResult
from rigtool.analysis.curves import CommandCurve, CurveParams
from rigtool.analysis.depth_fits import FitParams
from rigtool.analysis.dynamics import Dynamics
from rigtool.analysis.events import EventParams, MatchResult
from rigtool.analysis.fits import Coefficient, ZeroLine
from rigtool.analysis.gp import ExactGp, GpParams
from rigtool.analysis.steady import PointTable, SettlingCriterion
from rigtool.analysis.trainset import TrainingSet
from rigtool.models import laws
from rigtool.models.betm import Betm
from rigtool.models.domain import DEFAULT_SHORTFALL, Bounds, Domain

NAN = math.nan
DEEP_DEPTH_M = 0.6  # shallower than this, ventilation is possible ([Luo2020], docs/references.md)


@dataclass(frozen=True)
class CalibrationParams:
    """Every threshold the analysis uses; all of it is written to calibration.json."""

    settling: SettlingCriterion = field(default_factory=SettlingCriterion)
    curve: CurveParams = field(default_factory=CurveParams)
    fit: FitParams = field(default_factory=FitParams)
    min_r2: float = 0.98
    min_points: int = 5
    drift_warn_n_per_h: float = 0.1  # unused (kept: stored calibrations name it)
    # a drift is warned about when its interval excludes zero and it moves the zero over the
    # sweep by more than this many times the thrust noise
    drift_warn_noise_ratio: float = 1.0
    deep_depth_m: float = DEEP_DEPTH_M  # shallower points may ventilate: no zero fitted there


@dataclass
class Hysteresis:
    """Up-sweep minus down-sweep thrust at commands visited in both directions (N)."""

    command: np.ndarray
    up_n: np.ndarray
    down_n: np.ndarray
    diff_n: np.ndarray
    diff_se_n: np.ndarray

    @property
    def max_abs_n(self) -> float:
        return float(np.max(np.abs(self.diff_n)))

    @property
    def at_command(self) -> float:
        return float(self.command[np.argmax(np.abs(self.diff_n))])


@dataclass
class Repeatability:
    """Standard deviation (N) of the point means across repeats, per (command, direction)."""

    command: np.ndarray
    direction: np.ndarray
    n_repeats: np.ndarray
    std_n: np.ndarray

    @property
    def max_std_n(self) -> float:
        return float(np.max(self.std_n))

    @property
    def median_std_n(self) -> float:
        return float(np.median(self.std_n))


@dataclass
class TareDrift:
    """Thrust-channel tare bias vs time, relative to the first tare, and its linear trend."""

    t_s: np.ndarray
    bias_n: np.ndarray
    slope: Coefficient
    zero_scatter_n: float


@dataclass
class VoltagePoint:
    """The coefficients of one supply voltage at one depth."""

    voltage_v: float  # the supply voltage set
    bus_v: float  # mean bus voltage measured over the fitted points (NaN: not recorded)
    cp_fwd: Coefficient | None
    cp_rev: Coefficient | None
    cn: Coefficient | None
    ci_fwd: Coefficient | None
    ci_rev: Coefficient | None
    current_exponent: float = 3.0  # k of the current law ci_* hold for: f = C_i (I - I_0)^(2/k)


@dataclass
class VoltageLaw:
    """C_n(U) = k U^b across the voltages of one depth, and whether C_p holds across them."""

    depth_m: float | None
    points: list[VoltagePoint]
    k: Coefficient  # A/(r/min)^3 V^-b
    b: Coefficient  # exponent (1)
    k_inverse: Coefficient  # k of the physical law C_n = k / U (b fixed at -1), A V/(r/min)^3
    cp_chi2_red: float  # reduced chi-square of the C_p_fwd values about their weighted mean
    cp_consistent: bool  # C_p_fwd agrees across voltages within its intervals
    warnings: list[str]

    def cn_at(self, voltage_v: float | np.ndarray) -> float | np.ndarray:
        """C_n at supply voltage U from the fitted power law."""
        return self.k.value * np.asarray(voltage_v, dtype=float) ** self.b.value

    def ci_at(self, voltage_v: float | np.ndarray, cp: float) -> float | np.ndarray:
        """C_i = C_p / C_n(U)^(2/3) at supply voltage U."""
        return laws.c_i_from(cp, self.cn_at(voltage_v))


@dataclass
class DepthSection:
    """Results for the points at one depth (depth_m is None when the run sets no depth).

    `zero` is the thrust zero (offset + drift since the tare) found by the model fit or, without
    speed feedback, from the dead points; curve, hysteresis and repeatability are relative to it.
    """

    depth_m: float | None
    points: PointTable
    fits: dict[str, Coefficient]
    curve: CommandCurve | None
    zero: ZeroLine | None
    hysteresis: Hysteresis | None
    repeatability: Repeatability | None
    warnings: list[str]
    speed_sign: str = "measured"  # or "inferred from command" / "inferred from thrust"
    voltage_v: float | None = None  # supply voltage set for these points (None: not swept)
    bus_v: float = NAN  # mean bus voltage measured over them (NaN: not recorded)
    # Whether the sweep's design separates a zero drift from the law, and why (drift_design.py;
    # empty in calibrations stored before it was judged).
    drift_design: str = ""
    # Per direction ("fwd", "rev"), the thrust-speed law chosen (thrust_law.py; empty before).
    thrust_law: dict[str, dict] = field(default_factory=dict)
    # The declared sensor accuracy and `thrust_share`, the systematic share of the thrusts it
    # adds to the thrust coefficients' intervals (empty: none declared).
    sensor_accuracy: dict[str, float | None] = field(default_factory=dict)

    @property
    def label(self) -> str:
        depth = "no depth" if self.depth_m is None else f"{self.depth_m:g} m"
        return depth if self.voltage_v is None else f"{depth}, {self.voltage_v:g} V"


@dataclass
class CalibrationResult:
    """Everything `rigtool calibrate` found in one run; arrays are ready to plot."""

    run_id: str
    run_name: str
    run_status: str
    command_unit: str
    neutral_command: float
    thruster_id: str | None
    propeller_diameter_m: float | None
    water_density_kg_m3: float | None
    tool_version: str
    params: CalibrationParams
    sections: list[DepthSection]
    drift: TareDrift | None
    warnings: list[str]
    voltage_laws: list[VoltageLaw] = field(default_factory=list)  # per depth, voltage sweeps
    dynamics: Dynamics | None = None  # step-response runs
    captive: CaptiveResult | None = None  # captive runs: the held vehicle's damping laws


@dataclass(frozen=True)
class CavitationParams:
    """Every option of the quasi-cavitation analysis (written to cavitation.json)."""

    detect_block_s: float = 0.1
    train_block_s: float = 0.2
    budget: int = 2000
    gamma: float = 3.0
    edge_s: float = 0.5
    shortfall_window_s: float = 1.0  # averaging window of the current shortfall
    causal: bool = False  # window of past blocks only (a controller's view); else centred
    shortfall_range: tuple[float, float] = DEFAULT_SHORTFALL  # else a current fault
    events: EventParams = field(default_factory=EventParams)
    gp: GpParams = field(default_factory=GpParams)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def window_blocks(self) -> int:
        """Shortfall averaging window in train blocks (>= 1)."""
        return max(1, int(round(self.shortfall_window_s / self.train_block_s)))

    @property
    def lead_blocks(self) -> int:
        """Blocks the shortfall window reaches ahead: 0 when causal, else half the window."""
        return 0 if self.causal else self.window_blocks // 2


@dataclass
class EstimatorErrors:
    """Error summary of one thrust estimator against zero-corrected measured thrust."""

    name: str
    n: int
    max_abs_n: float
    p95_abs_n: float
    rms_n: float
    within_1n: float

    @classmethod
    def of(cls, name: str, err: np.ndarray) -> EstimatorErrors:
        e = np.abs(err[np.isfinite(err)])
        return cls(name, int(e.size), float(e.max()), float(np.quantile(e, 0.95)),
                   float(np.sqrt(np.mean(e**2))), float(np.mean(e <= 1.0)))


@dataclass
class ClassErrors:
    """Prediction errors of one class of blocks (during/outside events, edges, steps)."""

    name: str
    n: int
    p95_abs_n: float
    max_abs_n: float
    rms_n: float
    coverage95: float
    max_at: str


@dataclass
class Evaluation:
    """Errors by class, overall coverage, event matching against truth, and where from."""

    source: str
    classes: list[ClassErrors]
    coverage95: float
    matching: MatchResult | None
    truth_source: str


@dataclass
class CavitationResult:
    """Everything `calibrate_cavitation` found; arrays are ready to plot and export."""

    run_id: str
    base_run_id: str
    params: CavitationParams
    betm: Betm
    deep_errors: list[EstimatorErrors]
    deep_errors_samples: list[EstimatorErrors]
    events: list[dict]
    event_table: list[dict]
    training: TrainingSet
    n_blocks_total: int
    gp: ExactGp
    evaluation: Evaluation
    series: dict[str, np.ndarray]
    warnings: list[str] = field(default_factory=list)
    bounds: Bounds = field(default_factory=Bounds)
    domain: Domain | None = None
    interval_check: dict | None = None  # held-out check and scale of the 95 % intervals
    floor: dict | None = None  # how well speed and current can predict the thrust at all
