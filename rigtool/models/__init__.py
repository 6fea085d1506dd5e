"""Run-time thrust models for a vehicle controller or simulator, numpy only.

`load_model(folder)` reads an exported QCTM-GP (qctm_gp.json); `Betm` is the fused speed and
current thrust estimate it builds on. Fitting lives in rigtool.analysis.
"""

from rigtool.models.betm import Betm, BetmEstimate, fuse_estimates
from rigtool.models.domain import CLAMPED, CURRENT_FAULT, OUT_OF_DOMAIN, Bounds, Domain
from rigtool.models.qctm import (
    FORMAT,
    FORMAT_VERSION,
    MODEL_FILE,
    VARIANCE_FILE,
    Z95,
    GatedMean,
    LogNoise,
    Prediction,
    ThrustModel,
    gp_features,
    load_model,
    matern52,
    model_from_document,
    shortfall,
    window_mean,
)

__all__ = ["CLAMPED", "CURRENT_FAULT", "FORMAT", "FORMAT_VERSION", "MODEL_FILE", "OUT_OF_DOMAIN",
           "VARIANCE_FILE", "Z95", "Betm", "BetmEstimate", "Bounds", "Domain", "GatedMean",
           "LogNoise", "Prediction", "ThrustModel", "fuse_estimates", "gp_features",
           "load_model", "matern52", "model_from_document", "shortfall", "window_mean"]
