"""The exported QCTM-GP: its JSON document, physical bounds and training domain.

Fitting side of rigtool.models: everything here runs once per calibration, and the document
it writes is all `rigtool.models.model_from_document` needs.
"""

from __future__ import annotations

import numpy as np

from rigtool.analysis.trainset import TrainingSet
from rigtool.models.betm import Betm
from rigtool.models.domain import DEFAULT_MAX_DISTANCE, Bounds, Domain
from rigtool.models.qctm import (
    FEATURES,
    FORMAT,
    FORMAT_VERSION,
    SIGNAL_ARRAYS,
    VARIANCE_FILE,
    GatedMean,
)

RANGE_MARGIN = 0.05  # each training range is widened by this fraction of its span per side
ABOVE_QUANTILE = 0.995  # quantile of f_measured - f_BETM that sets bounds.above_n


def fit_limits(training: TrainingSet, shortfall: tuple[float, float],
               max_distance: float = DEFAULT_MAX_DISTANCE) -> tuple[Bounds, Domain]:
    """Bounds (admissible shortfall, how far above f_BETM thrust was seen) and the domain
    (per-input ranges of the training rows, widened by RANGE_MARGIN of their span)."""
    above = max(0.0, float(np.quantile(training.y, ABOVE_QUANTILE))) if len(training) else 0.0
    cols = {"speed_rpm": training.x[:, 0], "current_a": np.abs(training.x[:, 1]),
            "depth_m": training.x[:, 2], "shortfall_thrust_n": training.xf[:, 1]}
    ranges = {}
    for name, v in cols.items():
        lo, hi = (float(np.min(v)), float(np.max(v))) if v.size else (0.0, 0.0)
        pad = RANGE_MARGIN * (hi - lo)
        ranges[name] = (lo - pad, hi + pad)
    return Bounds(tuple(shortfall), above), Domain(ranges, max_distance)


def model_document(betm: Betm, gp: object, extra: dict, window: int = 1,
                   block_s: float = 0.2, lead: int | None = None,
                   bounds: Bounds | None = None, domain: Domain | None = None) -> dict:
    """The JSON document of a fitted model (`gp` an analysis.gp.ExactGp on gp_features).
    With signal variance 0 the GP's mean and posterior terms are 0: `gp.signal` is false and
    the arrays only they use (SIGNAL_ARRAYS, the variance file) are left out."""
    h = gp.hyper  # type: ignore[attr-defined]
    y_std = float(gp.y_std)  # type: ignore[attr-defined]
    alpha = np.asarray(gp.alpha)  # type: ignore[attr-defined]
    noise = getattr(gp, "noise", None)
    doc = {
        "format": FORMAT, "format_version": FORMAT_VERSION, **extra,
        "inputs": ["speed_rpm", "current_a", "depth_m"],
        "features": {"columns": list(FEATURES), "block_s": block_s, "window_blocks": window,
                     "lead_blocks": window // 2 if lead is None else min(max(lead, 0), window - 1),
                     "c_n": betm.c_n, "i_0": betm.i_0,
                     "shortfall": "1 - |I| / (c_n |n|^3 + i_0), mean over window_blocks blocks, the last "
                                  "lead_blocks of them after the current block, leaving out blocks "
                                  "whose own shortfall is outside bounds.shortfall",
                     "z": "betm.speed_estimate(n) * shortfall"},
        "output": "thrust_n = f_BETM(speed_rpm, current_a) + beta * z / (1 + exp(-(|z| - "
                  "gate_z0) / gate_s)) + gp_mean(x); gate_s = 0: beta * z; then held to "
                  "[0, f_BETM + bounds.above_n] in the direction of the speed",
        "bounds": (bounds or Bounds()).to_dict(),
        "domain": None if domain is None else domain.to_dict(),
        "flags": {"1": "out of domain", "2": "current fault: speed estimate", "4": "clamped"},
        "noise": None if noise is None else noise.to_dict(),
        "betm": {k: (list(v) if isinstance(v, tuple) else v) for k, v in betm.to_dict().items()},
        "gp": {
            "kernel": "matern", "nu": 2.5,
            "length_scales": h.length_scales.tolist(),
            "signal_var": h.signal_var, "signal_var_n2": h.signal_var * y_std**2,
            "noise_var": h.noise_var, "noise_var_n2": h.noise_var * y_std**2,
            "x_mean": gp.x_mean.tolist(), "x_scale": gp.x_scale.tolist(),  # type: ignore[attr-defined]
            "y_mean": float(gp.y_mean), "y_std": y_std,  # type: ignore[attr-defined]
            **getattr(gp, "mean_term", GatedMean()).to_dict(),
            "x_train": gp.x_train.tolist(),  # type: ignore[attr-defined]
            "weights": gp.w.tolist(),  # type: ignore[attr-defined]
            "alpha": alpha.tolist(),
            "a_n": (y_std * h.signal_var * alpha).tolist(),
            "variance_file": VARIANCE_FILE,
            "signal": h.signal_var != 0.0,
        },
    }
    if not doc["gp"]["signal"]:
        doc["gp"] = {k: v for k, v in doc["gp"].items() if k not in SIGNAL_ARRAYS}
    return doc
