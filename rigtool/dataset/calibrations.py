"""A run's latest calibration as rows of the dataset's calibrations table: one per coefficient
and section, with the section's depth, supply voltage, role (deep or shallow) and whether it is
the one the API and the vehicle artefacts use by default."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pyarrow as pa

from rigtool.analysis.results import DEEP_DEPTH_M
from rigtool.sections import default_section
from rigtool.store import Store

_TEXT = pa.string()
_TYPES = {"run_id": _TEXT, "thruster_id": _TEXT, "rig": _TEXT, "created_utc": _TEXT,
          "out_dir": _TEXT, "depth_m": pa.float64(), "voltage_set_v": pa.float64(),
          "role": _TEXT, "main_section": pa.bool_(), "coefficient": _TEXT,
          "value": pa.float64(), "lo": pa.float64(), "hi": pa.float64(), "unit": _TEXT,
          "n": pa.int64()}
SCHEMA = pa.schema(list(_TYPES.items()))
CALIBRATION_KEYS = tuple(_TYPES)[3:]  # a footer row: created_utc ... n (the run's keys aside)


def calibration_rows(store: Store, run_id: str) -> list[list]:
    """The run's latest calibration as rows of CALIBRATION_KEYS, for its partition's footer;
    none when the run was never calibrated."""
    cal = store.latest_calibration(run_id)
    if cal is None:
        return []
    return [[cal["created_utc"], cal["out_dir"], *(_finite(v) for v in row)]
            for row in coefficient_rows(cal["summary"])]


def _finite(value: object) -> object:
    return None if isinstance(value, float) and not math.isfinite(value) else value


LAW_TERMS = {"k": "C_n_law_k", "b": "C_n_law_b", "k_inverse": "C_n_law_k_inverse"}


def coefficient_rows(summary: dict) -> Iterator[tuple]:
    """(depth, voltage, role, main section, coefficient, value, lo, hi, unit, n) of every
    coefficient a stored calibration summary holds."""
    depths = summary.get("depths") or []
    deep = (summary.get("analysis") or {}).get("deep_depth_m")
    deep = DEEP_DEPTH_M if deep is None else deep
    main = _main_section(depths)
    for i, section in enumerate(depths):
        depth = section.get("depth_m")
        head = (depth, section.get("supply_voltage_v"), _role(depth, deep), i == main)
        for name, c in (section.get("coefficients") or {}).items():
            yield (*head, name, *_coefficient(c))
    main_depth = None if main is None else depths[main].get("depth_m")
    for law in summary.get("voltage_laws") or []:
        depth = law.get("depth_m")
        head = (depth, None, _role(depth, deep), main is not None and depth == main_depth)
        for term, name in LAW_TERMS.items():
            if law.get(term) is not None:
                yield (*head, name, *_coefficient(law[term]))


def _main_section(depths: list[dict]) -> int | None:
    """The section the Python API and the vehicle artefacts use by default (the deepest
    depth, the middle supply voltage there); None without sections."""
    if not depths:
        return None
    return default_section([d.get("depth_m") for d in depths],
                           [d.get("supply_voltage_v") for d in depths])


def _role(depth: float | None, deep_m: float) -> str:
    """`shallow` where the propeller may ventilate (as calibrate decides), else `deep`."""
    return "shallow" if depth is not None and depth < deep_m else "deep"


def _coefficient(c: dict) -> tuple:
    """value, lo, hi, unit and n of a stored coefficient."""
    return c.get("value"), c.get("lo"), c.get("hi"), c.get("unit"), c.get("n")
