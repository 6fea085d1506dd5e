"""Load an exported QCTM-GP thrust model and evaluate it with numpy only (no scikit-learn).

    model = load_model("calibrations/<run-id>")
    thrust_n, lo95, hi95 = model.predict(speed_rpm, current_a, depth_m)

thrust = f_BETM(n, I) + y_mean + sum_j a_j m(r_j), m(r) = (1 + sqrt5 r + 5 r^2 / 3) exp(-sqrt5 r),
r_j = || (x - X_j) / (x_scale * length_scales) ||; see docs/cavitation.md for the format.
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
Z95 = 1.959963984540054
SQRT5 = 5.0**0.5


def matern52(a: np.ndarray, b: np.ndarray, length_scales: np.ndarray) -> np.ndarray:
    """Matern nu=5/2 correlation between rows of a and b (already standardised)."""
    d = (a[:, None, :] - b[None, :, :]) / length_scales
    s = SQRT5 * np.sqrt(np.sum(d * d, axis=-1))
    return (1.0 + s + s * s / 3.0) * np.exp(-s)


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

    def correction(self, speed_rpm: np.ndarray, current_a: np.ndarray,
                   depth_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(GP mean of f_measured - f_BETM, std of a new measurement), N."""
        x = np.column_stack(np.broadcast_arrays(np.atleast_1d(np.asarray(speed_rpm, float)),
                                                np.atleast_1d(np.asarray(current_a, float)),
                                                np.atleast_1d(np.asarray(depth_m, float))))
        xs = (x - self.x_mean) / self.x_scale
        xt = (self.x_train - self.x_mean) / self.x_scale
        out_mean = np.empty(len(xs))
        out_var = np.empty(len(xs))
        for s in range(0, len(xs), 2048):
            k = self.signal_var * matern52(xs[s:s + 2048], xt, self.length_scales)
            out_mean[s:s + 2048] = self.y_mean + self.y_std * (k @ self.alpha)
            var = np.full(len(k), self.signal_var)
            if self.k_inv is not None:
                var = var - np.einsum("ij,jk,ik->i", k, self.k_inv, k)
            out_var[s:s + 2048] = np.maximum(var, 0.0) + self.noise_var
        return out_mean, self.y_std * np.sqrt(out_var)

    def predict(self, speed_rpm: np.ndarray, current_a: np.ndarray,
                depth_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(thrust_n, lo95, hi95) for measured speed, current and depth (arrays or scalars)."""
        n = np.atleast_1d(np.asarray(speed_rpm, float))
        i = np.atleast_1d(np.asarray(current_a, float))
        base = self.betm.fuse(*np.broadcast_arrays(n, i)).thrust_n
        mean, std = self.correction(speed_rpm, current_a, depth_m)
        f = base + mean
        return f, f - Z95 * std, f + Z95 * std


def model_document(betm: Betm, gp: object, extra: dict) -> dict:
    """The JSON document of a fitted model (`gp` an analysis.gp.ExactGp)."""
    h = gp.hyper  # type: ignore[attr-defined]
    y_std = float(gp.y_std)  # type: ignore[attr-defined]
    alpha = np.asarray(gp.alpha)  # type: ignore[attr-defined]
    return {
        "format": FORMAT, "format_version": 1, **extra,
        "inputs": ["speed_rpm", "current_a", "depth_m"],
        "output": "thrust_n = f_BETM(speed_rpm, current_a) + gp_mean(x)",
        "betm": {k: (list(v) if isinstance(v, tuple) else v) for k, v in betm.to_dict().items()},
        "gp": {
            "kernel": "matern", "nu": 2.5,
            "length_scales": h.length_scales.tolist(),
            "signal_var": h.signal_var, "signal_var_n2": h.signal_var * y_std**2,
            "noise_var": h.noise_var, "noise_var_n2": h.noise_var * y_std**2,
            "x_mean": gp.x_mean.tolist(), "x_scale": gp.x_scale.tolist(),  # type: ignore[attr-defined]
            "y_mean": float(gp.y_mean), "y_std": y_std,  # type: ignore[attr-defined]
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
    b = doc["betm"]
    betm = Betm(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in b.items()})
    g = doc["gp"]
    kinv_path = folder / g.get("variance_file", VARIANCE_FILE)
    k_inv = np.load(kinv_path) if kinv_path.exists() else None
    return ThrustModel(
        betm=betm, x_mean=np.array(g["x_mean"]), x_scale=np.array(g["x_scale"]),
        length_scales=np.array(g["length_scales"]), signal_var=float(g["signal_var"]),
        noise_var=float(g["noise_var"]), y_mean=float(g["y_mean"]), y_std=float(g["y_std"]),
        x_train=np.array(g["x_train"], dtype=float), alpha=np.array(g["alpha"]), k_inv=k_inv)
