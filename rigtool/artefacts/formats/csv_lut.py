"""inverse_lut.csv, the inverse lookup table of every section, as calibrate writes it."""

from __future__ import annotations

from rigtool.artefacts.calibration import FILES, lut_text
from rigtool.artefacts.vehicle import ExportInput

FILE = FILES["inverse_lut"]
FOLLOWS = "rigtool's own CSV (docs/artefacts.md)"


def needs(x: ExportInput) -> list[str]:
    """Nothing beyond the calibration."""
    return []


def render(x: ExportInput) -> str:
    """The table: a header row and the rows (no stored text reaches it)."""
    return lut_text(x.cal)
