"""inverse_lut.csv, the inverse lookup table of every section, as calibrate writes it."""

from __future__ import annotations

from dataclasses import replace

from rigtool.artefacts.calibration import FILES, lut_text
from rigtool.artefacts.encode import scalar_text
from rigtool.artefacts.vehicle import ExportInput

FILE = FILES["inverse_lut"]
FOLLOWS = "rigtool's own CSV (docs/artefacts.md)"


def needs(x: ExportInput) -> list[str]:
    """Nothing beyond the calibration."""
    return []


def render(x: ExportInput) -> str:
    """The table, with lone surrogates in the comment texts as U+FFFD."""
    cal = x.cal
    cal = replace(cal, run_id=scalar_text(cal.run_id), command_unit=scalar_text(cal.command_unit),
                  tool_version=scalar_text(cal.tool_version))
    return lut_text(cal, scalar_text(x.created))
