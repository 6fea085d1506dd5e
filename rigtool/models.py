"""Load an exported QCTM-GP thrust model and evaluate it with numpy only (no scikit-learn).

    model = load_model("calibrations/<run-id>")
    thrust_n, lo95, hi95 = model.predict(speed_rpm, current_a, depth_m, segment)

Inputs are consecutive block means (`features.block_s`, 0.2 s) of one record; `segment` (one
label per block, default: all one segment) marks where the record is cut (e.g. a new point).
GP inputs x = (n, z, h) with z = f_n(n) * shortfall, shortfall = 1 - |I| / (C_n |n|^3 + I_0)
averaged over a window of `features.window_blocks` blocks within the segment that reaches
`features.lead_blocks` blocks ahead (window_blocks // 2: centred; 0: causal, for a controller).
thrust = f_BETM(n, I) + y_mean + g(z) + sum_j a_j m(r_j) with the gated mean term
g(z) = beta z / (1 + exp(-(|z| - z0) / s)), m(r) = (1 + sqrt5 r + 5 r^2 / 3) exp(-sqrt5 r) and
r_j = || (x - X_j) / (x_scale * length_scales) ||; the noise variance of a new measurement is
exp(log_mean + log_bias + signal_var sum_j b_j m(r'_j)) (heteroscedastic); see docs/cavitation.md.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigtool.analysis.betm import Betm

MODEL_FILE = "qctm_gp.json"
VARIANCE_FILE = "qctm_gp_kinv.npy"
FORMAT = "rigtool-qctm-gp"
FORMAT_VERSION = 3  # 3: gated mean term and lead_blocks; 2 (plain beta z, centred) still loads
Z95 = 1.959963984540054
SQRT5 = 5.0**0.5
LOG_CHI2_BIAS = 1.2703628454614782  # -E[log chi^2_1]: exp(E[log e^2] + this) = var(e), e Gaussian
FEATURES = ("speed_rpm", "shortfall_thrust_n", "depth_m")


def matern52(a: np.ndarray, b: np.ndarray, length_scales: np.ndarray) -> np.ndarray:
    """Matern nu=5/2 correlation between rows of a and b (already standardised)."""
    d = (a[:, None, :] - b[None, :, :]) / length_scales
    s = SQRT5 * np.sqrt(np.sum(d * d, axis=-1))
    return (1.0 + s + s * s / 3.0) * np.exp(-s)


def segment_runs(segment: np.ndarray | None, size: int) -> list[tuple[int, int]]:
    """(start, stop) of the runs of equal consecutive labels (one run if `segment` is None)."""
    if segment is None or size == 0:
        return [(0, size)]
    seg = np.asarray(segment)
    cuts = np.flatnonzero(seg[1:] != seg[:-1]) + 1
    edges = np.r_[0, cuts, size]
    return list(zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True))


def window_mean(v: np.ndarray, segment: np.ndarray | None, window: int,
                lead: int | None = None) -> np.ndarray:
    """Mean of v over `window` samples ending `lead` samples ahead, truncated at segment ends.

    lead = window // 2 (the default) centres the window; lead = 0 uses past samples only.
    """
    v = np.asarray(v, dtype=float)
    if window <= 1:
        return v.copy()
    half_hi = window // 2 if lead is None else min(max(lead, 0), window - 1)
    half_lo = window - 1 - half_hi
    out = np.empty_like(v)
    for a, b in segment_runs(segment, v.size):
        c = np.r_[0.0, np.cumsum(v[a:b])]
        j = np.arange(b - a)
        lo, hi = np.maximum(j - half_lo, 0), np.minimum(j + half_hi + 1, b - a)
        out[a:b] = (c[hi] - c[lo]) / (hi - lo)
    return out


def gp_features(betm: Betm, speed_rpm: np.ndarray, current_a: np.ndarray, depth_m: np.ndarray,
                segment: np.ndarray | None = None, window: int = 1,
                lead: int | None = None) -> np.ndarray:
    """GP inputs (n, z, h): z = f_n(n) * window mean of 1 - |I| / (C_n |n|^3 + I_0) (N)."""
    n, i, h = np.broadcast_arrays(np.atleast_1d(np.asarray(speed_rpm, float)),
                                  np.atleast_1d(np.asarray(current_a, float)),
                                  np.atleast_1d(np.asarray(depth_m, float)))
    i_hat = betm.c_n * np.abs(n) ** 3 + betm.i_0
    with np.errstate(divide="ignore", invalid="ignore"):
        short = np.where(i_hat > 0, 1.0 - np.abs(i) / i_hat, 0.0)
    short = window_mean(short, segment, window, lead)
    return np.column_stack([n, betm.speed_estimate(n) * short, h])


@dataclass(frozen=True)
class GatedMean:
    """Explicit mean term g(z) = beta z / (1 + exp(-(|z| - z0) / s)) of the GP (s = 0: beta z).

    Outside events z is current noise that a plain linear term would turn into thrust error;
    the gate switches the term off below about z0 (N)."""

    beta: float = 0.0
    z0: float = 0.0
    s: float = 0.0

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        if self.s <= 0.0:
            return self.beta * z
        u = np.clip((np.abs(z) - self.z0) / self.s, -700.0, 700.0)  # exp stays finite
        return self.beta * z / (1.0 + np.exp(-u))

    def to_dict(self) -> dict:
        return {"beta": self.beta, "gate_z0": self.z0, "gate_s": self.s}

    @classmethod
    def from_dict(cls, g: dict) -> GatedMean:
        return cls(float(g.get("beta", 0.0)), float(g.get("gate_z0", 0.0)),
                   float(g.get("gate_s", 0.0)))


@dataclass
class LogNoise:
    """Heteroscedastic noise: var(x) = exp(log_mean + log_bias + k(x)^T alpha) (N^2)."""

    x_mean: np.ndarray
    x_scale: np.ndarray
    length_scales: np.ndarray
    signal_var: float
    log_mean: float
    x_train: np.ndarray  # raw inputs
    alpha: np.ndarray
    log_bias: float = LOG_CHI2_BIAS  # fitted: makes 95 % of the training residuals covered

    def var_n2(self, x: np.ndarray) -> np.ndarray:
        xs = (np.asarray(x, dtype=float) - self.x_mean) / self.x_scale
        xt = (self.x_train - self.x_mean) / self.x_scale
        out = np.empty(len(xs))
        for s in range(0, len(xs), 2048):
            k = self.signal_var * matern52(xs[s:s + 2048], xt, self.length_scales)
            out[s:s + 2048] = k @ self.alpha
        return np.exp(self.log_mean + self.log_bias + out)

    def to_dict(self) -> dict:
        return {"kernel": "matern", "nu": 2.5, "x_mean": self.x_mean.tolist(),
                "x_scale": self.x_scale.tolist(), "length_scales": self.length_scales.tolist(),
                "signal_var": self.signal_var, "log_mean": self.log_mean,
                "log_bias": self.log_bias, "x_train": self.x_train.tolist(),
                "alpha": self.alpha.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> LogNoise:
        return cls(np.array(d["x_mean"]), np.array(d["x_scale"]), np.array(d["length_scales"]),
                   float(d["signal_var"]), float(d["log_mean"]),
                   np.array(d["x_train"], dtype=float), np.array(d["alpha"]),
                   float(d.get("log_bias", LOG_CHI2_BIAS)))


@dataclass
class ThrustModel:
    """BETM + GP correction with 95 % intervals for a new measurement."""

    betm: Betm
    x_mean: np.ndarray
    x_scale: np.ndarray
    length_scales: np.ndarray
    signal_var: float
    noise_var: float
    y_mean: float
    y_std: float
    x_train: np.ndarray
    alpha: np.ndarray
    k_inv: np.ndarray | None
    noise: LogNoise | None = None  # heteroscedastic noise; None: constant noise_var
    window: int = 1  # shortfall averaging window (blocks)
    lead: int | None = None  # blocks the window reaches ahead (None: window // 2, centred)
    block_s: float = 0.2
    mean_term: GatedMean = GatedMean()  # explicit mean g(z)

    def features(self, speed_rpm: np.ndarray, current_a: np.ndarray, depth_m: np.ndarray,
                 segment: np.ndarray | None = None) -> np.ndarray:
        """GP inputs (n, z, h) of consecutive block means (see gp_features)."""
        return gp_features(self.betm, speed_rpm, current_a, depth_m, segment, self.window,
                           self.lead)

    def correction(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(GP mean of f_measured - f_BETM, std of a new measurement) at GP inputs x, N."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        xs = (x - self.x_mean) / self.x_scale
        xt = (self.x_train - self.x_mean) / self.x_scale
        out_mean = np.empty(len(xs))
        out_var = np.empty(len(xs))
        for s in range(0, len(xs), 2048):
            k = self.signal_var * matern52(xs[s:s + 2048], xt, self.length_scales)
            out_mean[s:s + 2048] = (self.y_mean + self.mean_term(x[s:s + 2048, 1])
                                    + self.y_std * (k @ self.alpha))
            var = np.full(len(k), self.signal_var)
            if self.k_inv is not None:
                var = var - np.einsum("ij,jk,ik->i", k, self.k_inv, k)
            out_var[s:s + 2048] = np.maximum(var, 0.0) + self.noise_var
        var_n2 = self.y_std**2 * out_var
        if self.noise is not None:
            var_n2 = var_n2 + self.noise.var_n2(x)
        return out_mean, np.sqrt(var_n2)

    def predict(self, speed_rpm: np.ndarray, current_a: np.ndarray, depth_m: np.ndarray,
                segment: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(thrust_n, lo95, hi95) for consecutive block means of speed, current and depth."""
        x = self.features(speed_rpm, current_a, depth_m, segment)
        base = self.betm.fuse(x[:, 0], np.broadcast_to(
            np.atleast_1d(np.asarray(current_a, float)), x[:, 0].shape)).thrust_n
        mean, std = self.correction(x)
        f = base + mean
        return f, f - Z95 * std, f + Z95 * std


def model_document(betm: Betm, gp: object, extra: dict, window: int = 1,
                   block_s: float = 0.2, lead: int | None = None) -> dict:
    """The JSON document of a fitted model (`gp` an analysis.gp.ExactGp on gp_features)."""
    h = gp.hyper  # type: ignore[attr-defined]
    y_std = float(gp.y_std)  # type: ignore[attr-defined]
    alpha = np.asarray(gp.alpha)  # type: ignore[attr-defined]
    noise = getattr(gp, "noise", None)
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION, **extra,
        "inputs": ["speed_rpm", "current_a", "depth_m"],
        "features": {"columns": list(FEATURES), "block_s": block_s, "window_blocks": window,
                     "lead_blocks": window // 2 if lead is None else min(max(lead, 0), window - 1),
                     "c_n": betm.c_n, "i_0": betm.i_0,
                     "shortfall": "1 - |I| / (c_n |n|^3 + i_0), mean over window_blocks blocks, the last "
                                  "lead_blocks of them after the current block",
                     "z": "betm.speed_estimate(n) * shortfall"},
        "output": "thrust_n = f_BETM(speed_rpm, current_a) + beta * z / (1 + exp(-(|z| - "
                  "gate_z0) / gate_s)) + gp_mean(x); gate_s = 0: beta * z",
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
        },
    }


def load_model(calibration_dir: str | Path) -> ThrustModel:
    """Read qctm_gp.json (and, for the posterior variance, qctm_gp_kinv.npy) from a folder."""
    folder = Path(calibration_dir)
    doc = json.loads((folder / MODEL_FILE).read_text(encoding="utf-8"))
    if doc.get("format") != FORMAT:
        raise ValueError(f"{folder / MODEL_FILE} is not a {FORMAT} document")
    version = int(doc.get("format_version", 1))
    if version < 2:
        raise ValueError(f"{folder / MODEL_FILE} is a version-1 model on raw (n, I, h) inputs: "
                         "rerun rigtool calibrate to refit it")
    if version > FORMAT_VERSION:
        raise ValueError(f"{folder / MODEL_FILE} is format version {version}; this rigtool "
                         f"reads up to {FORMAT_VERSION}: update rigtool")
    b = doc["betm"]
    betm = Betm(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in b.items()})
    g = doc["gp"]
    kinv_path = folder / g.get("variance_file", VARIANCE_FILE)
    k_inv = np.load(kinv_path) if kinv_path.exists() else None
    return ThrustModel(
        betm=betm, x_mean=np.array(g["x_mean"]), x_scale=np.array(g["x_scale"]),
        length_scales=np.array(g["length_scales"]), signal_var=float(g["signal_var"]),
        noise_var=float(g["noise_var"]), y_mean=float(g["y_mean"]), y_std=float(g["y_std"]),
        x_train=np.array(g["x_train"], dtype=float), alpha=np.array(g["alpha"]), k_inv=k_inv,
        noise=None if doc.get("noise") is None else LogNoise.from_dict(doc["noise"]),
        window=int(doc.get("features", {}).get("window_blocks", 1)),
        lead=None if doc.get("features", {}).get("lead_blocks") is None
        else int(doc["features"]["lead_blocks"]),
        mean_term=GatedMean.from_dict(g),
        block_s=float(doc.get("features", {}).get("block_s", 0.2)))
