"""Evaluation of the quasi-cavitation predictions against the truth: the twin's stored
ventilation intervals where the run has them, else the detected events.

Errors and 95 % coverage are summarised by block class (during or outside events, event
edges, point starts); detected events are matched against the twin's truth.
"""

from __future__ import annotations

import math

import numpy as np

from rigtool.analysis.blocks import Blocks, classify, windows_of
from rigtool.analysis.events import Event, MatchResult, clip_to_windows, match_events
from rigtool.analysis.results import CavitationParams, ClassErrors, Evaluation
from rigtool.store import Store

TRUTH_KIND = "sim.ventilation"


def truth_intervals(store: Store, run_id: str) -> list[tuple[float, float]]:
    """Twin ground-truth ventilation intervals (evaluation only)."""
    return [(float(e["detail"]["t_start_s"]), float(e["detail"]["t_end_s"]))
            for e in store.events(run_id, TRUTH_KIND)]


def class_errors(err: np.ndarray, inside: np.ndarray, cls: np.ndarray, blocks: Blocks) -> list[ClassErrors]:
    """Error summary per class and for all blocks."""
    out = []
    for name in ("event", "outside", "edge", "step", "all"):
        m = np.ones(err.size, bool) if name == "all" else cls == name
        if not m.any():
            out.append(ClassErrors(name, 0, math.nan, math.nan, math.nan, math.nan, ""))
            continue
        e = np.abs(err[m])
        j = np.flatnonzero(m)[int(np.argmax(e))]
        where = (f"t = {blocks.t_s[j]:.1f} s, {blocks.depth_m[j]:g} m, "
                 f"command {blocks.command[j]:g}, {cls[j]}")
        out.append(ClassErrors(name, int(m.sum()), float(np.quantile(e, 0.95)), float(e.max()),
                               float(np.sqrt(np.mean(e**2))), float(np.mean(inside[m])), where))
    return out


def evaluate_blocks(blocks: Blocks, pred: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    events: list[tuple[float, float]], edge_s: float, source: str,
                    matching: MatchResult | None, truth_source: str) -> Evaluation:
    """Errors of predictions on blocks against measured block thrust, by class."""
    err = pred - blocks.thrust_n
    inside = (blocks.thrust_n >= lo) & (blocks.thrust_n <= hi)
    cls = classify(blocks, events, edge_s)
    return Evaluation(source, class_errors(err, inside, cls, blocks), float(np.mean(inside)),
                      matching, truth_source)


def evaluate(store: Store, run_id: str, blocks: Blocks, det_blocks: Blocks,
             detected: list[Event], pred: np.ndarray, lo: np.ndarray, hi: np.ndarray,
             p: CavitationParams, source: str) -> Evaluation:
    """Errors of `pred` (with its 95 % interval lo..hi) on the blocks of run `run_id`, by
    class of the twin's truth if stored (the detected events matched against it), else of the
    `detected` events."""
    truth = truth_intervals(store, run_id)
    wins = windows_of(det_blocks)
    det = [(e.t_start_s, e.t_end_s) for e in detected]
    if truth:
        clipped = clip_to_windows(truth, wins)
        matching = match_events(det, clipped, p.events.min_duration_s)
        return evaluate_blocks(blocks, pred, lo, hi, truth, p.edge_s, source, matching,
                               f"{TRUTH_KIND} (twin ground truth)")
    return evaluate_blocks(blocks, pred, lo, hi, det, p.edge_s, source, None,
                           "detected events (no ground truth stored)")
