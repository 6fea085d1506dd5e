"""Quasi-cavitation calibration of a shallow run: BETM, events, GP training set, QCTM-GP, evaluation.

BETM coefficients come from a deep, full-range base run (`--base`, or the most recent
completed run of the same thruster whose depths are all >= 0.6 m; chosen in
cavitation_runs.py, which holds the stage's store reads). Evaluation against the twin's
truth is in cavitation_truth.py. All analysis works on
short block means (see blocks.py): events on `detect_block_s`, the GP on `train_block_s`.
The in-run evaluation is a 2-fold split by point (alternate (depth, command) combinations are
held out whole: blocks within a point, and within one ventilation event, are autocorrelated),
with the main fit's hyperparameters; held-out runs use `evaluate_on_run`. The exported
intervals are checked and scaled on held-out runs (one training run: held-out blocks of it),
and a floor is stated: how well speed and current can predict the thrust at all
(`check_intervals`, `stated_floor`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from rigtool.analysis.betm_fit import (
    Betm,
    betm_from_section,
    compare_estimators,
    deep_section,
    level_variances,
    voltage_law_b,
)
from rigtool.analysis.blocks import Blocks, block_means, classify, in_intervals
from rigtool.analysis.calibrate import calibrate
from rigtool.analysis.cavitation_runs import cavitation_stage
from rigtool.analysis.cavitation_truth import evaluate
from rigtool.analysis.dataset import RunData, load_run
from rigtool.analysis.events import (
    Event,
    detect_events,
    relative_drop,
)
from rigtool.analysis.gp import (
    SHIFT_RANGE,
    ExactGp,
    calibrate_gate,
    fit_exact,
    fit_hetero,
    shift_noise,
    variance_parts,
)
from rigtool.analysis.qctm_export import fit_limits, model_document
from rigtool.analysis.results import (
    CavitationParams,
    CavitationResult,
    EstimatorErrors,
    Evaluation,
)
from rigtool.analysis.trainset import (
    MAD_TO_SD,
    TrainingSet,
    huber_weights,
    strata_keys,
    stratified_pick,
)
from rigtool.errors import UsageError
from rigtool.models import Z95, ThrustModel, gp_features, model_from_document
from rigtool.models.qctm import shortfall
from rigtool.progress_hook import ProgressHook, counted, no_progress
from rigtool.store import Store

EVENT_KIND = "ventilation"
CAVITATION_STAGES = ("BETM", "events and training blocks", "GP fit and interval check",
                     "2-fold evaluation")  # reported as done/total to the progress hook
# (speed, current, depth, segment) of consecutive blocks -> (thrust, lo95, hi95)
Predictor = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                     tuple[np.ndarray, np.ndarray, np.ndarray]]


IN_SAMPLE_NOTE = ("partly in-sample: each fold is refitted on the other fold's points, but the "
                  "hyperparameters, noise model and mean term come from the fit on all points; "
                  "held-out runs (benchmarks/bench_cavitation.py) give the honest figures")

def build_betm(base: RunData, params: CavitationParams) -> tuple[Betm, list[EstimatorErrors],
                                                                  list[EstimatorErrors]]:
    """BETM from the base run; deep-point errors of the three estimators on held-out points.

    Level variances are estimated on even points and errors measured on odd points; the
    returned Betm uses the variances of all points at `train_block_s`.
    """
    cal = calibrate(base)
    sec = deep_section(cal)
    betm0 = betm_from_section(sec, gamma=params.gamma, cn_law_b=voltage_law_b(cal, sec))
    errors = []
    final = betm0
    for block_s in (params.train_block_s, 0.0):
        b = block_means(base, block_s)
        f = b.thrust_n - (sec.zero.at(b.t_s) if sec.zero else 0.0)
        ok = (np.abs(b.speed_rpm) > 50) & np.isfinite(f)
        even, odd = ok & (b.point % 2 == 0), ok & (b.point % 2 == 1)
        half = level_variances(betm0, f[even], b.speed_rpm[even], b.current_a[even])
        errors.append(compare_estimators(half, f[odd], b.speed_rpm[odd], b.current_a[odd]))
        if block_s == params.train_block_s:
            final = level_variances(betm0, f[ok], b.speed_rpm[ok], b.current_a[ok])
    return final, errors[0], errors[1]


def find_events(run: RunData, betm: Betm, params: CavitationParams) -> tuple[list[Event], Blocks]:
    """Detected ventilation events of a run (on `detect_block_s` blocks) and those blocks."""
    b = block_means(run, params.detect_block_s)
    est = betm.fuse(b.speed_rpm, b.current_a)
    drop = relative_drop(b.thrust_n, est.thrust_n, params.events.min_thrust_n)
    i_hat = betm.c_n * np.abs(b.speed_rpm) ** 3 + betm.i_0
    with np.errstate(invalid="ignore", divide="ignore"):
        deficit = 1.0 - np.abs(b.current_a) / i_hat
    return detect_events(b.t_s, drop, b.point, params.events, deficit), b


def event_records(run: RunData, events: list[Event]) -> list[dict]:
    """Event details as stored (kind "ventilation")."""
    out = []
    for e in events:
        p = e.segment
        out.append({
            "t_start_s": e.t_start_s, "t_end_s": e.t_end_s, "duration_s": e.duration_s,
            "depth_m": float(run.steps.depth_m[p]), "command": float(run.steps.command[p]),
            "step_idx": int(run.steps.idx[p]), "mean_drop_frac": e.mean_drop,
            "peak_drop_frac": e.peak_drop, "current_deficit_frac": e.current_deficit,
            "current_supports": e.current_supports, "open_start": e.open_start,
            "open_end": e.open_end})
    return out


def event_table(run: RunData, blocks: Blocks, records: list[dict]) -> list[dict]:
    """Per (depth, command): observed time, events per minute, mean duration, time ventilated."""
    rows = []
    for p in range(len(run.steps)):
        sel = blocks.point == p
        if not sel.any():
            continue
        seconds = float(blocks.t1_s[sel].max() - blocks.t0_s[sel].min())
        mine = [r for r in records if r["step_idx"] == int(run.steps.idx[p])]
        dur = [r["duration_s"] for r in mine]
        rows.append({"depth_m": float(run.steps.depth_m[p]), "command": float(run.steps.command[p]),
                     "observed_s": seconds, "n_events": len(mine),
                     "rate_per_min": 60.0 * len(mine) / seconds if seconds > 0 else math.nan,
                     "mean_duration_s": float(np.mean(dur)) if dur else math.nan,
                     "ventilated_frac": float(np.sum(dur)) / seconds if seconds > 0 else math.nan})
    return rows


def training_blocks(run: RunData, betm: Betm, events: list[Event],
                    params: CavitationParams) -> tuple[TrainingSet, float]:
    """Every train-size block of the run as a weighted (x, y) set; returns the Huber scale."""
    b = block_means(run, params.train_block_s)
    ok = np.isfinite(b.thrust_n) & np.isfinite(b.speed_rpm) & np.isfinite(b.current_a)
    b = b.take(np.flatnonzero(ok))
    s = shortfall(betm, b.speed_rpm, b.current_a)
    valid = (s >= params.shortfall_range[0]) & (s <= params.shortfall_range[1])
    xf = gp_features(betm, b.speed_rpm, b.current_a, b.depth_m, b.point, params.window_blocks,
                     params.lead_blocks, valid)
    b, xf = b.take(np.flatnonzero(valid)), xf[valid]  # current faults are not training data
    f_betm = betm.fuse(b.speed_rpm, b.current_a).thrust_n
    y = b.thrust_n - f_betm
    vent = in_intervals(b.t_s, [(e.t_start_s, e.t_end_s) for e in events])
    w, scale = huber_weights(y, b.point)
    ts = TrainingSet(
        x=np.column_stack([b.speed_rpm, b.current_a, b.depth_m]), xf=xf, y=y, w=w, t_s=b.t_s,
        command=b.command, ventilated=vent, thrust_n=b.thrust_n, betm_n=f_betm,
        run_id=np.full(len(b), run.run_id), provenance={"run_ids": [run.run_id]})
    ts.block_class = classify(b, [(e.t_start_s, e.t_end_s) for e in events], params.edge_s)
    ts.provenance["fold"] = point_folds(b.depth_m, b.command, b.t_in_point_s).tolist()
    ts.provenance["point"] = b.point.tolist()
    ts.provenance["t_in_point_s"] = b.t_in_point_s.tolist()
    return ts, scale


def fit_gp(training: TrainingSet, params: CavitationParams, reuse: ExactGp | None = None) -> ExactGp:
    """fit_hetero on a training set: error groups by point, folds by `training_folds`;
    `reuse`: a fit whose kernel hyperparameters are kept (the refits of `crossfit`)."""
    points = np.unique(np.column_stack([training.run_id.astype(str),
                                        np.round(training.x[:, 2], 3).astype(str),
                                        training.command.astype(str)]),
                       axis=0, return_inverse=True)[1]
    return fit_hetero(training.xf, training.y, training.w, training_folds(training),
                      params.gp, np.ravel(points), reuse=reuse)


def training_folds(training: TrainingSet) -> np.ndarray:
    """Fold 0/1 per row: whole runs, alternating, when the set holds several runs; else the
    checkerboard of points (`point_folds`).

    A model must hold on runs it never saw. Held-out points of a run share that run's
    events and tares with the points left in, so a point-fold check rewarded a GP that
    learnt them: it chose a full GP signal that doubled the event error on new runs, where
    the mean term alone held (docs/cavitation.md)."""
    _, run = np.unique(training.run_id.astype(str), return_inverse=True)
    run = np.ravel(run)
    if run.size and run.max() >= 1:
        return run % 2
    return point_folds(training.x[:, 2], training.command)


def point_folds(depth_m: np.ndarray, command: np.ndarray,
                t_in_point_s: np.ndarray | None = None) -> np.ndarray:
    """Fold 0/1 per row: a checkerboard over (depth, command) combinations.

    With a single combination and `t_in_point_s` given, each point is split into its first
    and second half instead (the only split left; neighbouring blocks leak across it).
    """
    _, d = np.unique(np.round(np.asarray(depth_m, float), 3), return_inverse=True)
    _, c = np.unique(np.asarray(command, float), return_inverse=True)
    fold = (np.ravel(d) + np.ravel(c)) % 2
    if t_in_point_s is not None and np.unique(fold).size < 2:
        t = np.asarray(t_in_point_s, float)
        fold = (t > 0.5 * t.max()).astype(int) if t.size else fold
    return fold


def select(ts: TrainingSet, budget: int) -> TrainingSet:
    """Stratified selection of at most `budget` rows (see trainset.py)."""
    keys = strata_keys(ts.x[:, 2], ts.command, ts.ventilated)
    picked = ts.take(stratified_pick(keys, budget))
    picked.provenance = {k: v for k, v in ts.provenance.items()
                         if k in ("run_ids", "block_s", "huber_scale_n")}
    return picked


# --- held-out interval check and the floor (docs/cavitation.md, "Intervals and floor") ---
TARGET_P95_N = {"event": 3.5, "outside": 1.0}  # accuracy targets: [Luo2020], and outside events
CHECK_CLASSES = ("event", "outside")
CHECK_LEVEL = 0.95
# Target of the held-out check outside events, below CHECK_LEVEL by the check's measured
# pessimism there: on the cal-dev twin trainings (24: stock and weak, one and two runs) new
# runs' outside coverage exceeded the check's by a median of 1.8 points (21 of 24 above),
# so a check at 95 % left new runs at 96-98 % (docs/cavitation.md). During events the gap
# had no consistent sign (median 0.0 points for the gated blocks), so events stay at 95 %.
OUTSIDE_CHECK_LEVEL = 0.935
BLOCK_FOLDS = 4  # folds of a single training run
MIN_FOLD_ROWS = 50  # a fold model needs this many training rows
MIN_CLASS_ROWS = 30  # held-out blocks a class needs for an interval scale of its own
CHECK_FLOOR = 0.90  # held-out coverage after scaling below this: the check missed, say so
MIN_CHECK_EVENTS = 10  # held-out ventilation events below which the event scale is rough
MIN_QUIET_ROWS = 5  # quiet blocks of a point that give its noise (floor)


def check_folds(ts: TrainingSet) -> tuple[np.ndarray, str]:
    """Fold per row of the held-out interval check and its kind: each run its own fold with
    several runs ("run"), else `block_folds` of the one run ("block")."""
    _, run = np.unique(ts.run_id.astype(str), return_inverse=True)
    run = np.ravel(run)
    if run.size and run.max() >= 1:
        return run, "run"
    return block_folds(ts), "block"


def block_folds(ts: TrainingSet, k: int = BLOCK_FOLDS) -> np.ndarray:
    """Folds of one run: every (depth, command) combination's blocks cut into k contiguous
    time slices, slice j of combination c in fold (j + c) mod k. The cuts are moved from
    equal times to the nearest block outside the detected events (`_quiet_cuts`), so that
    an event is held out whole. Each fold model has seen every combination, as a model of
    the whole run has when it meets a new run (holding out whole points left a fold without
    any ventilating blocks at 40 % command, and its intervals there 7 times too narrow)."""
    _, d = np.unique(np.round(ts.x[:, 2], 3), return_inverse=True)
    _, c = np.unique(ts.command, return_inverse=True)
    combo = np.ravel(d) * (int(np.max(c, initial=0)) + 1) + np.ravel(c)
    fold = np.zeros(len(ts), int)
    for j, key in enumerate(np.unique(combo)):
        at = np.flatnonzero(combo == key)
        at = at[np.argsort(ts.t_s[at], kind="stable")]
        slices = np.searchsorted(_quiet_cuts(ts.t_s[at], ts.ventilated[at], k),
                                 np.arange(at.size), side="right")
        fold[at] = (slices + j) % k
    return fold


def _quiet_cuts(t: np.ndarray, vent: np.ndarray, k: int) -> np.ndarray:
    """k - 1 cut indices into time-sorted blocks: the first block of each slice, at equal
    times, each moved to the nearest block outside an event when there is one."""
    quiet = np.flatnonzero(~np.asarray(vent, bool))
    cuts = []
    for i in range(1, k):
        want = int(np.searchsorted(t, t[0] + (t[-1] - t[0]) * i / k))
        cuts.append(int(quiet[np.argmin(np.abs(quiet - want))]) if quiet.size else want)
    return np.sort(np.asarray(cuts, int))


def crossfit(pool: TrainingSet, gp: ExactGp, params: CavitationParams,
             fold: np.ndarray, progress: ProgressHook = no_progress) -> np.ndarray:
    """`variance_parts` x rows of `pool`: each fold predicted by a model fitted
    as the main one (selection, mean term, noise model; `gp`'s kernel hyperparameters) on the
    other folds alone; NaN where a fold model has too few rows. Each fold's GP fit is
    reported to `progress`."""
    out = np.full((3, len(pool)), np.nan)
    for k in counted(np.unique(fold), "GP fits of the interval-check folds", progress):
        test = fold == k
        train = select(pool.take(np.flatnonzero(~test)), params.budget)
        if len(train) >= MIN_FOLD_ROWS:
            out[:, test] = variance_parts(fit_gp(train, params, reuse=gp), pool.xf[test])
    return out


def check_intervals(pool: TrainingSet, gp: ExactGp, params: CavitationParams,
                    progress: ProgressHook = no_progress) -> dict:
    """Check the 95 % intervals on held-out folds (`check_folds`) and scale them: the noise
    model's quiet and ventilating levels are shifted until CHECK_LEVEL (95 %) of the held-out
    blocks during events and OUTSIDE_CHECK_LEVEL of those outside events are covered (classes
    by the detected events; `calibrate_gate`). Sets gp.noise; returns the figures for
    cavitation.json."""
    fold, kind = check_folds(pool)
    mean, post, noise = crossfit(pool, gp, params, fold, progress)
    resid = pool.y - mean
    cls = pool.block_class if pool.block_class is not None else np.full(len(pool), "outside")
    groups = {c: np.isfinite(resid) & (cls == c) for c in CHECK_CLASSES}
    n, z = pool.xf[:, 0], pool.xf[:, 1]
    shift = calibrate_gate(resid, post, noise, z, groups["event"], groups["outside"],
                           gp.noise.gate_z0, gp.noise.gate_s, CHECK_LEVEL, OUTSIDE_CHECK_LEVEL,
                           speed_rpm=n, speed_level=np.abs(pool.command),
                           loss_cap_n=ventilation_loss_cap(pool))
    before = resid**2 <= Z95**2 * (post + noise)
    loss = -resid * np.where(np.sign(n) >= 0, 1.0, -1.0)  # > 0: measured below the estimate
    half = Z95 * np.sqrt(post + noise * shift.factor(z))
    after = (-loss <= half) & (loss <= half + shift.missed(n, z))
    gp.noise = shift_noise(gp.noise, shift)
    n_folds = int(np.unique(fold).size)
    return {"kind": kind, "folds": n_folds, "level": CHECK_LEVEL,
            "check_levels": {"event": CHECK_LEVEL, "outside": OUTSIDE_CHECK_LEVEL},
            "method": (f"each of the {n_folds} training runs held out in turn" if kind == "run"
                       else f"{n_folds} folds of blocks of the one training run held out in turn"),
            "n_events": n_events(pool.take(np.flatnonzero(np.isfinite(resid)))),
            "log_var_shift": {"outside": shift.d_quiet, "event": shift.d_event},
            "sd_factor": {"outside": math.exp(shift.d_quiet / 2),
                          "event": math.exp(shift.d_event / 2)},
            "missed_lower": {"speed_rpm": list(shift.missed_speed_rpm or ()),
                             "lower_n": list(shift.missed_lower_n or ()),
                             "basis": MISSED_BASIS},
            "classes": {c: _class_check(resid[g], before[g], after[g])
                        for c, g in groups.items()}}


def ventilation_loss_cap(pool: TrainingSet) -> np.ndarray:
    """The loss (N) ventilation can cause at each row: the quiet thrust (BETM) times the 95 %
    quantile of the share of it lost during the detected events (NaN without events)."""
    base = np.abs(np.asarray(pool.betm_n, float))
    share = (base - np.abs(np.asarray(pool.thrust_n, float))) / np.maximum(base, 1e-9)
    ev = (pool.block_class == "event") if pool.block_class is not None else pool.ventilated
    ev = np.asarray(ev, bool) & np.isfinite(share) & (base > 0)
    if not ev.any():
        return np.full(len(pool), np.nan)
    return base * float(np.clip(np.quantile(share[ev], 0.95), 0.0, 1.0))


MISSED_BASIS = ("loss-side widening of the interval per speed level, times 1 - gate(z): an upper "
                "bound (90 % confidence) on the 95 % quantile of what the held-out event blocks "
                "whose shortfall the gate calls quiet need (ventilation the current misses, "
                "which only ever lowers the thrust); where a level has too few of them to tell, "
                "at least the loss ventilation can cause there (quiet thrust x the detected "
                "events' 95 % loss share)")


def _class_check(resid: np.ndarray, before: np.ndarray, after: np.ndarray) -> dict:
    """Held-out blocks, coverage before and after the scale, p95 |error| of one class."""
    n = int(resid.size)
    return {"n_blocks": n, "coverage_before": float(np.mean(before)) if n else math.nan,
            "coverage": float(np.mean(after)) if n else math.nan,
            "p95_abs_n": float(np.quantile(np.abs(resid), 0.95)) if n else math.nan}


def n_events(ts: TrainingSet) -> int:
    """Detected ventilation events in a set: runs of ventilated blocks within each point."""
    key = np.char.add(ts.run_id.astype(str), np.char.add(np.round(ts.x[:, 2], 3).astype(str),
                                                         ts.command.astype(str)))
    count = 0
    for k in np.unique(key):
        v = ts.ventilated[key == k][np.argsort(ts.t_s[key == k])].astype(int)
        count += int(np.sum(np.diff(np.r_[0, v]) == 1))
    return count


FLOOR_RESAMPLES = 200  # bootstrap draws of the floor's groups (seeded: calibrate is repeatable)
FLOOR_RANGE = (0.05, 0.95)  # the floor's stated range: these quantiles of the draws


def stated_floor(pool: TrainingSet, gp: ExactGp, check: dict) -> dict:
    """How well speed and current can predict this thruster's thrust at all, per class, next
    to the held-out p95 of the model and the target (see `floor_groups`), with the floor's
    range over the training's groups (points, and their depths during events) resampled: a
    floor from one run's ten events can be off by a factor of three, and the verdict says
    "out of reach" only when the whole range is above the target."""
    groups = floor_groups(pool, gp.mean_term.beta)
    rng = np.random.default_rng(0)
    classes = {}
    for c in CHECK_CLASSES:
        sd, rows = groups[c]
        floor, held = mixture_p95(np.repeat(sd, rows)), check["classes"][c]["p95_abs_n"]
        low, high = floor_range(sd, rows, rng)
        classes[c] = {"floor_p95_n": floor, "floor_range_n": [low, high],
                      "floor_groups": int(sd.size), "heldout_p95_n": held,
                      "target_p95_n": TARGET_P95_N[c],
                      "verdict": floor_verdict((low, floor, high), held, TARGET_P95_N[c])}
    return {"basis": FLOOR_BASIS, "classes": classes}


def floor_range(sd: np.ndarray, rows: np.ndarray, rng: np.random.Generator
                ) -> tuple[float, float]:
    """FLOOR_RANGE quantiles of the floor with its groups (an sd and a row count each) drawn
    with replacement, FLOOR_RESAMPLES times (NaN, NaN with fewer than two groups)."""
    if sd.size < 2:
        return math.nan, math.nan
    pick = rng.integers(0, sd.size, (FLOOR_RESAMPLES, sd.size))
    low, high = np.quantile(weighted_p95(sd[pick], rows[pick].astype(float)), FLOOR_RANGE)
    return float(low), float(high)


FLOOR_BASIS = ("lower bound of the p95 |error| of any estimator from these block means of speed "
               "and current: quiet blocks of each point (repeated conditions) give the thrust "
               "noise and the noise of the current-implied loss z; during events the best "
               "linear estimator that knew the spread of each point's losses still has the "
               "error of z times beta (shrunk towards that spread) plus the thrust noise")


OUT_OF_REACH = "target out of reach from speed and current"


def floor_verdict(floor: tuple[float, float, float], held: float, target: float) -> str:
    """One phrase from the floor (low, estimate, high) and the held-out p95: is the target out
    of reach, met, or reachable but missed, or can the training not tell?"""
    low, estimate, high = floor
    if not math.isfinite(estimate):
        return "not enough data to state a floor"
    if estimate > target and not low <= target:  # the whole range (or a lone group) above
        return OUT_OF_REACH
    if math.isfinite(held) and held <= target:
        return "target met on held-out data"
    if high > target:
        return ("the floor's range spans the target (the training cannot tell whether it is "
                "reachable); this model misses it on held-out data")
    return "floor below the target (not ruled out); this model misses it on held-out data"


def floor_groups(pool: TrainingSet, beta: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per class, the error sd no estimator from these signals beats, by group, (sd, blocks)
    of each: thrust noise of a point's quiet blocks (about their point's mean) and, during
    events, the posterior sd of the loss given z of its event blocks at one depth (noise
    beta^2 var(z) against the spread of the point's event losses)."""
    cls = pool.block_class if pool.block_class is not None else np.full(len(pool), "outside")
    run = pool.run_id.astype(str)
    out: dict[str, list[tuple[float, int]]] = {c: [] for c in CHECK_CLASSES}
    for r in np.unique(run):
        for cmd in np.unique(pool.command[run == r]):
            at = (run == r) & (pool.command == cmd)
            var_y, var_z = _quiet_variances(pool, at & (cls == "outside"))
            if not math.isfinite(var_y):
                continue
            out["outside"].append((math.sqrt(var_y), int(np.sum(at & (cls == "outside")))))
            for depth in np.unique(pool.x[at, 2]):
                ev = at & (pool.x[:, 2] == depth) & (cls == "event")
                if ev.sum() >= 2:
                    spread = max(float(np.var(pool.y[ev], ddof=1)) - var_y, 0.0)
                    meas = beta**2 * var_z
                    post = meas * spread / (meas + spread) if meas + spread > 0 else 0.0
                    out["event"].append((math.sqrt(var_y + post), int(ev.sum())))
    return {c: (np.array([g[0] for g in v], float), np.array([g[1] for g in v], int))
            for c, v in out.items()}


def _quiet_variances(pool: TrainingSet, quiet: np.ndarray) -> tuple[float, float]:
    """Robust (var y, var z) of quiet blocks about their point's median, (1.4826 MAD)^2: a
    block of ventilation the detection missed must not pass for noise (NaN with too few)."""
    if quiet.sum() < MIN_QUIET_ROWS:
        return math.nan, math.nan
    depth = np.round(pool.x[quiet, 2], 3)
    y, z = pool.y[quiet].copy(), pool.xf[quiet, 1].copy()
    for d in np.unique(depth):
        y[depth == d] -= np.median(y[depth == d])
        z[depth == d] -= np.median(z[depth == d])
    return float((MAD_TO_SD * np.median(np.abs(y))) ** 2), float(
        (MAD_TO_SD * np.median(np.abs(z))) ** 2)


def mixture_p95(sd: np.ndarray) -> float:
    """q with mean_i P(|e_i| <= q) = 0.95 for e_i ~ N(0, sd_i^2) (NaN for no rows)."""
    if sd.size == 0:
        return math.nan
    return float(weighted_p95(np.asarray(sd, float)[None, :], np.ones((1, sd.size)))[0])


def weighted_p95(sd: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per row of `sd` (mixtures side by side, each column a component with its `weight`):
    q with sum_j w_j P(|e_j| <= q) / sum_j w_j = 0.95 for e_j ~ N(0, sd_j^2), by bisection."""
    from scipy.special import erf

    scale = np.sqrt(2.0) * np.maximum(sd, 1e-12)
    w = weight / weight.sum(axis=1, keepdims=True)
    lo, hi = np.zeros(sd.shape[0]), 3.0 * sd.max(axis=1) + 1e-9
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        short = np.sum(w * erf(mid[:, None] / scale), axis=1) < CHECK_LEVEL
        lo, hi = np.where(short, mid, lo), np.where(short, hi, mid)
    return hi


def check_warnings(check: dict, floor: dict) -> list[str]:
    """Warnings about the interval check (too few events) and targets out of reach."""
    out = []
    events = check["classes"]["event"]
    if sum(c["n_blocks"] for c in check["classes"].values()) < MIN_CLASS_ROWS:
        out.append("too few blocks to hold any out: the 95 % intervals are the training fit's, "
                   "not checked on held-out data; record longer or more points")
    elif events["n_blocks"] < MIN_CLASS_ROWS:
        out.append(f"only {events['n_blocks']} held-out blocks during ventilation events: the "
                   "event intervals are not checked on their own (quiet blocks set them)")
    elif check["n_events"] < MIN_CHECK_EVENTS:
        out.append(f"only {check['n_events']} ventilation events in the training runs: the scale "
                   "of the event intervals rests on few events; add runs with `--train-with RUN`")
    for c, v in check["classes"].items():
        where = "during events" if c == "event" else "outside events"
        if v["n_blocks"] >= MIN_CLASS_ROWS and v["coverage"] < CHECK_FLOOR:
            out.append(f"{where}, the 95 % intervals cover only {100 * v['coverage']:.1f} % of "
                       "the held-out blocks even after scaling: they are too narrow there "
                       "(cavitation.json 'interval_check')")
        if check["log_var_shift"][c] >= SHIFT_RANGE - 1e-6:
            out.append(f"{where}, the intervals reached the widening limit (sd x "
                       f"{check['sd_factor'][c]:.1f}): they cover by being wide, not by "
                       "predicting; do not rely on them (cavitation.json 'interval_check')")
    for c, v in floor["classes"].items():
        if v["verdict"] == OUT_OF_REACH:
            where = "during events" if c == "event" else "outside events"
            low, high = v.get("floor_range_n", (math.nan, math.nan))
            spread = f" (range {low:.2f}-{high:.2f} N)" if math.isfinite(low) else ""
            out.append(f"{where}, no estimator from speed and current reaches the target here: "
                       f"floor p95 {v['floor_p95_n']:.2f} N{spread} > {v['target_p95_n']:g} N "
                       "(cavitation.json 'floor')")
    return out


def evaluate_on_run(store: Store, run_id: str, predict: Predictor, betm: Betm,
                    params: CavitationParams | None = None) -> Evaluation:
    """Held-out evaluation of `predict` on another run (twin truth if stored, else detection)."""
    p = params or CavitationParams()
    run = load_run(store, run_id)
    blocks = block_means(run, p.train_block_s)
    pred, lo, hi = predict(blocks.speed_rpm, blocks.current_a, blocks.depth_m, blocks.point)
    detected, det_blocks = find_events(run, betm, p)
    return evaluate(store, run_id, blocks, det_blocks, detected, pred, lo, hi, p,
                     f"held-out run {run_id}")


ONE_RUN_WARNING = ("the model is trained on this one run, so its 95 % intervals were checked and "
                   "scaled on held-out blocks of the same run (block-fold), never on another run: "
                   "they hold on a new run only as far as it resembles this one; add runs with "
                   "`calibrate --train-with RUN` to check them run by run (docs/cavitation.md)")


def calibrate_cavitation(store: Store, run_id: str, base_run_id: str | None,
                         params: CavitationParams | None = None,
                         train_with: Sequence[str] = (),
                         run: RunData | None = None,
                         progress: ProgressHook = no_progress) -> CavitationResult:
    """Full quasi-cavitation analysis of `run_id` (reads the store, never writes: the detected
    events are in the result for the caller to store). The model is trained on `run_id` and
    the runs `train_with` (full ids, see `training_runs`): with two runs or more, held-out
    twin runs met the accuracy targets; with one, not always.

    UsageError when the analysis does not apply or no base run is usable (`cavitation_stage`).
    `run`: `run_id` already loaded (calibrate has it), so it is not read twice. The stages and
    the GP fits of each fold are reported to `progress`.
    """
    p = params or CavitationParams()
    stage = cavitation_stage(store, run_id, base_run_id)
    if stage.base_run_id is None:
        raise UsageError(stage.reason)
    base_id = stage.base_run_id
    task = "quasi-cavitation stages"
    progress(task, 0, len(CAVITATION_STAGES))
    betm, deep_blocks, deep_samples = build_betm(load_run(store, base_id), p)
    progress(task, 1, len(CAVITATION_STAGES))
    run = run if run is not None and run.run_id == run_id else load_run(store, run_id)
    events, det_blocks = find_events(run, betm, p)
    records = event_records(run, events)
    table = event_table(run, det_blocks, records)

    all_blocks, scale = training_blocks(run, betm, events, p)
    all_blocks.provenance.update({"block_s": p.train_block_s, "huber_scale_n": scale})
    pool = all_blocks
    if train_with:
        from rigtool.analysis.trainset import concat

        pool = concat([all_blocks, *(_training_set(store, rid, betm, p) for rid in train_with)])
    training = select(pool, p.budget)
    progress(task, 2, len(CAVITATION_STAGES))
    gp = fit_checked(pool, training, p, progress)
    progress(task, 3, len(CAVITATION_STAGES))
    evaluation, series = _two_fold(store, run, all_blocks, det_blocks, events, gp, p, progress)
    progress(task, 4, len(CAVITATION_STAGES))
    warnings = [] if train_with else [ONE_RUN_WARNING]
    if len(training) < 50:
        warnings.append(f"only {len(training)} training blocks: the GP is poorly constrained")
    warnings += check_warnings(gp.check["intervals"], gp.check["floor"])
    bounds, domain = fit_limits(training, p.shortfall_range)
    return CavitationResult(run_id, base_id, p, betm, deep_blocks, deep_samples, records, table,
                            training, len(all_blocks), gp, evaluation, series, warnings,
                            bounds=bounds, domain=domain, interval_check=gp.check["intervals"],
                            floor=gp.check["floor"])


def fit_checked(pool: TrainingSet, training: TrainingSet, params: CavitationParams,
                progress: ProgressHook = no_progress) -> ExactGp:
    """The model fitted on `training` (selected from `pool`), its intervals checked and scaled
    on held-out folds of `pool` and its floor stated (gp.check: "intervals", "floor")."""
    gp = fit_gp(training, params)
    check = check_intervals(pool, gp, params, progress)
    gp.check = {"intervals": check, "floor": stated_floor(pool, gp, check)}
    return gp


def _training_set(store: Store, run_id: str, betm: Betm, p: CavitationParams) -> TrainingSet:
    """All training blocks of another run, events found with the same BETM."""
    run = load_run(store, run_id)
    events, _ = find_events(run, betm, p)
    return training_blocks(run, betm, events, p)[0]


def _two_fold(store: Store, run: RunData, all_blocks: TrainingSet, det_blocks: Blocks,
              events: list[Event], gp: ExactGp, p: CavitationParams,
              progress: ProgressHook = no_progress
              ) -> tuple[Evaluation, dict[str, np.ndarray]]:
    """2-fold evaluation inside the run (folds from `point_folds`), hyperparameters and mean
    term fixed from the main fit."""
    fold = np.asarray(all_blocks.provenance["fold"])
    n = len(all_blocks)
    pred, std, miss = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n)
    folds = np.unique(fold) if np.unique(fold).size > 1 else ()
    for k in counted(folds, "GP fits of the 2-fold evaluation", progress):
        train = select(all_blocks.take(np.flatnonzero(fold != k)), p.budget)
        test = np.flatnonzero(fold == k)
        model = fit_exact(train.xf, train.y, train.w, p.gp, hyper=gp.hyper, noise=gp.noise,
                          mean_term=gp.mean_term)
        m, s = model.predict(all_blocks.xf[test])
        pred[test] = all_blocks.betm_n[test] + m
        std[test] = s
        miss[test] = gp.noise.missed_lower(all_blocks.xf[test]) if gp.noise is not None else 0.0
    blocks = block_means(run, p.train_block_s)
    ok = np.isfinite(blocks.thrust_n) & np.isfinite(blocks.speed_rpm) & np.isfinite(blocks.current_a)
    blocks = blocks.take(np.flatnonzero(ok))
    up = np.sign(all_blocks.xf[:, 0]) >= 0  # the widening is on the loss side
    lo = pred - Z95 * std - np.where(up, miss, 0.0)
    hi = pred + Z95 * std + np.where(up, 0.0, miss)
    combos = np.unique(np.column_stack([all_blocks.x[:, 2], all_blocks.command]), axis=0)
    how = ("by point (alternate depth/command combinations held out)" if len(combos) > 1
           else "into the first and second half of its one point")
    ev = evaluate(store, run.run_id, blocks, det_blocks, events, pred, lo, hi, p,
                   f"2-fold split of run {run.run_id} {how}")
    series = {"t_s": blocks.t_s, "thrust_n": blocks.thrust_n, "betm_n": all_blocks.betm_n,
              "pred_n": pred, "lo95_n": lo, "hi95_n": hi, "depth_m": blocks.depth_m,
              "command": blocks.command, "point": blocks.point}
    return ev, series



def train_model(store: Store, run_ids: list[str], base_run_id: str,
                params: CavitationParams | None = None) -> tuple[Betm, ExactGp, TrainingSet]:
    """BETM from the base run and an exact GP trained on the selected blocks of several runs,
    its intervals checked and scaled on held-out runs (`fit_checked`)."""
    from rigtool.analysis.trainset import concat

    p = params or CavitationParams()
    betm, _, _ = build_betm(load_run(store, base_run_id), p)
    pool = concat([_training_set(store, rid, betm, p) for rid in run_ids])
    training = select(pool, p.budget)
    return betm, fit_checked(pool, training, p), training


def thrust_model(betm: Betm, gp: ExactGp, training: TrainingSet,
                 params: CavitationParams) -> ThrustModel:
    """The model `calibrate` exports (bounds and domain from `training`), ready to evaluate."""
    bounds, domain = fit_limits(training, params.shortfall_range)
    doc = model_document(betm, gp, {}, params.window_blocks, params.train_block_s,
                         params.lead_blocks, bounds, domain)
    return model_from_document(doc, gp.k_inv)
