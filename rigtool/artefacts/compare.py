"""Thruster-comparison artefacts: corrections.json and corrections.csv."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from rigtool.analysis.compare import CompareResult, Correction
from rigtool.artefacts.write import atomic_write, csv_cell, json_text


def corrections_document(result: CompareResult) -> dict:
    """The corrections.json content: what each thruster should be sent, per branch."""
    return {
        "rigtool_corrections": 1,
        "command_unit": result.command_unit,
        "reference": result.reference_run or "mean",
        "reference_label": result.reference_label,
        "model": "send c_i = a * c + b to thruster i when the controller wants the reference "
                 "thrust at command c; use the branch whose [command_lo, command_hi] side of "
                 "the reference's neutral contains c",
        "floor_frac": result.floor_frac,
        "spread_before": result.spread_before,
        "spread_after": result.spread_after,
        "corrections": [asdict(c) for c in result.corrections],
        "warnings": result.warnings,
    }


def write_corrections(result: CompareResult, out_dir: Path) -> list[Path]:
    """Write corrections.json and corrections.csv into `out_dir`; return their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    names = list(Correction.__dataclass_fields__)
    rows = [",".join(names)] + [",".join(csv_cell(v) for v in asdict(c).values())
                                for c in result.corrections]
    return [atomic_write(out_dir / "corrections.json", json_text(corrections_document(result))),
            atomic_write(out_dir / "corrections.csv", "\n".join(rows) + "\n")]
