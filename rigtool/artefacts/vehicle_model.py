"""vehicle_model.json: the identified vehicle, checked strictly and written atomically.

The document (schema version 1, docs/vehicle-formats.md) holds a rigid body and diagonal
hydrodynamic derivatives in Fossen's (2011) SNAME convention: body axes x forward, y starboard,
z down (FRD), origin at the centre of gravity, derivatives with their sign. Every parameter is
{"value": number or null, "ci95": [lo, hi] or null, "reason": text or null}. Signs are not
enforced (an identification may give a positive damping term, and that is worth seeing), but
every number must be finite and within a bound no vehicle reaches, every list its exact length,
every object its exact keys: a crafted document is refused naming the file and the field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from rigtool.artefacts.write import atomic_write, json_text
from rigtool.errors import ConfigError

FILE = "vehicle_model.json"
FORMAT = "rigtool-vehicle-model"
SCHEMA_VERSION = 1
NAME_MAX = 200
REASON_MAX = 2000
COEFFICIENT_MAX = 1e12  # |derivative| (SI); a large ship's added mass is ~1e8 kg
POSITION_MAX_M = 1e4
GROUPS: dict[str, tuple[str, ...]] = {
    "added_mass": ("X_udot", "Y_vdot", "Z_wdot", "K_pdot", "M_qdot", "N_rdot"),
    "linear_damping": ("X_u", "Y_v", "Z_w", "K_p", "M_q", "N_r"),
    "quadratic_damping": ("X_uu", "Y_vv", "Z_ww", "K_pp", "M_qq", "N_rr"),
}
TOP_KEYS = ("format", "schema_version", "name", "frame", "rigid_body", "hydrodynamics")
BODY_KEYS = ("mass_kg", "inertia_kg_m2", "cog_m", "cob_m", "weight_n", "buoyancy_n",
             "water_density_kg_m3", "gravity_m_s2")
# positive quantities of the rigid body and their upper bounds
BODY_POSITIVE = {"mass_kg": 1e9, "weight_n": 1e10, "buoyancy_n": 1e10,
                 "water_density_kg_m3": 2000.0, "gravity_m_s2": 100.0}
PARAM_KEYS = ("value", "ci95", "reason")


class _Check:
    """Collects every problem of one document, each naming the file and the field."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.problems: list[str] = []

    def bad(self, field: str, text: str) -> None:
        """Record one problem."""
        self.problems.append(f"{self.source}: {field}: {text}")

    def keys(self, obj: Any, field: str, want: tuple[str, ...]) -> bool:
        """True when `obj` is an object with exactly the keys `want`."""
        if not isinstance(obj, dict):
            self.bad(field, f"must be an object, not {type(obj).__name__}")
            return False
        extra = [str(k)[:40] for k in obj if k not in want]
        missing = [k for k in want if k not in obj]
        if extra:
            self.bad(field, f"unknown key(s) {', '.join(repr(k) for k in extra[:5])}")
        if missing:
            self.bad(field, f"missing key(s) {', '.join(missing)}")
        return not extra and not missing

    def number(self, v: Any, field: str, limit: float, positive: bool = False) -> float | None:
        """`v` as a finite float with |v| <= limit (and > 0 when `positive`), else None."""
        if isinstance(v, bool) or not isinstance(v, int | float):
            self.bad(field, f"must be a number, not {type(v).__name__}")
            return None
        try:
            x = float(v)
        except OverflowError:
            x = math.inf
        if not math.isfinite(x) or abs(x) > limit:
            self.bad(field, f"must be finite and at most {limit:g} in magnitude")
            return None
        if positive and x <= 0:
            self.bad(field, "must be positive")
            return None
        return x

    def numbers(self, v: Any, field: str, n: int, limit: float) -> list[float] | None:
        """`v` as a list of exactly `n` bounded finite floats, else None."""
        if not isinstance(v, list) or len(v) != n:
            what = f"{len(v)} items" if isinstance(v, list) else type(v).__name__
            self.bad(field, f"must be a list of {n} numbers, not {what}")
            return None
        out = [self.number(x, f"{field}[{i}]", limit) for i, x in enumerate(v)]
        return None if any(x is None for x in out) else out  # type: ignore[return-value]

    def text(self, v: Any, field: str, limit: int, allow_none: bool = False) -> str | None:
        """`v` as a string of at most `limit` characters (or None when allowed)."""
        if v is None and allow_none:
            return None
        if not isinstance(v, str):
            self.bad(field, f"must be text, not {type(v).__name__}")
            return None
        if len(v) > limit:
            self.bad(field, f"is {len(v)} characters long; at most {limit}")
            return None
        return v


def _inertia(c: _Check, v: Any, field: str) -> list[list[float]] | None:
    """A 3x3 symmetric positive-definite inertia matrix in kg m^2."""
    if not isinstance(v, list) or len(v) != 3:
        c.bad(field, "must be a 3x3 list of lists")
        return None
    rows = [c.numbers(row, f"{field}[{i}]", 3, 1e9) for i, row in enumerate(v)]
    if any(r is None for r in rows):
        return None
    m = np.array(rows, dtype=float)
    scale = float(np.max(np.abs(m)))
    if not np.allclose(m, m.T, rtol=0.0, atol=1e-9 * max(scale, 1.0)):
        c.bad(field, "must be symmetric")
        return None
    if scale == 0.0 or float(np.min(np.linalg.eigvalsh(m))) <= 1e-12 * scale:
        c.bad(field, "must be positive definite")
        return None
    return [list(map(float, r)) for r in rows]  # type: ignore[arg-type]


def _rigid_body(c: _Check, v: Any) -> dict[str, Any]:
    """The checked rigid_body object."""
    if not c.keys(v, "rigid_body", BODY_KEYS):
        return {}
    out: dict[str, Any] = {k: c.number(v[k], f"rigid_body.{k}", limit, positive=True)
                           for k, limit in BODY_POSITIVE.items()}
    out["inertia_kg_m2"] = _inertia(c, v["inertia_kg_m2"], "rigid_body.inertia_kg_m2")
    for k in ("cog_m", "cob_m"):
        out[k] = c.numbers(v[k], f"rigid_body.{k}", 3, POSITION_MAX_M)
    return out


def _parameter(c: _Check, v: Any, field: str) -> dict[str, Any]:
    """One {"value", "ci95", "reason"} parameter."""
    if not c.keys(v, field, PARAM_KEYS):
        return {}
    value = None if v["value"] is None else c.number(v["value"], f"{field}.value",
                                                      COEFFICIENT_MAX)
    ci = None
    if v["ci95"] is not None:
        ci = c.numbers(v["ci95"], f"{field}.ci95", 2, COEFFICIENT_MAX)
        if ci is not None and ci[0] > ci[1]:
            c.bad(f"{field}.ci95", "must be [lo, hi] with lo <= hi")
    reason = c.text(v["reason"], f"{field}.reason", REASON_MAX, allow_none=True)
    return {"value": value, "ci95": ci, "reason": reason}


def _hydrodynamics(c: _Check, v: Any) -> dict[str, Any]:
    """The checked hydrodynamics object: three groups of six diagonal derivatives."""
    if not c.keys(v, "hydrodynamics", tuple(GROUPS)):
        return {}
    out: dict[str, Any] = {}
    for group, names in GROUPS.items():
        field = f"hydrodynamics.{group}"
        if c.keys(v[group], field, names):
            out[group] = {n: _parameter(c, v[group][n], f"{field}.{n}") for n in names}
    return out


def validate_model(doc: Any, source: str) -> dict[str, Any]:
    """The checked vehicle model (numbers as floats), or ConfigError naming `source` and
    every bad field."""
    c = _Check(source)
    if not c.keys(doc, "(document)", TOP_KEYS):
        raise ConfigError(c.problems)
    if doc["format"] != FORMAT:
        c.bad("format", f"must be {FORMAT!r}")
    if isinstance(doc["schema_version"], bool) or doc["schema_version"] != SCHEMA_VERSION:
        c.bad("schema_version", f"must be {SCHEMA_VERSION} (this rigtool reads version "
              f"{SCHEMA_VERSION} only)")
    if doc["frame"] != "FRD":
        c.bad("frame", "must be 'FRD' (x forward, y starboard, z down)")
    out = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "frame": "FRD",
           "name": c.text(doc["name"], "name", NAME_MAX),
           "rigid_body": _rigid_body(c, doc["rigid_body"]),
           "hydrodynamics": _hydrodynamics(c, doc["hydrodynamics"])}
    if c.problems:
        raise ConfigError(c.problems)
    return out


def write_model(doc: dict[str, Any], folder: str | Path) -> Path:
    """Check `doc` and write it atomically as `folder`/vehicle_model.json (numbers exact)."""
    path = Path(folder) / FILE
    model = validate_model(doc, str(path))
    return atomic_write(path, json_text(model, digits=None))
