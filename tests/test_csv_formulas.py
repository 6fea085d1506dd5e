"""No stored text reaches a CSV file as a spreadsheet formula: a thruster id, a step's
direction or status, a command unit starting with = + - @ is written behind a `'`, on one line,
and every file still parses to the same columns."""

from __future__ import annotations

import csv
import sqlite3
from pathlib import Path

from rigtool.artefacts.write import columns_text, csv_cell, csv_text
from rigtool.cli import main

from .conftest import ROOT

FORMULA = "=cmd|' /C calc'!A0"
STARTS = ("=", "+", "@", "\t", "\r")


def _cells(path: Path) -> list[list[str]]:
    lines = [line for line in path.read_text(encoding="utf-8").splitlines()
             if not line.startswith("#")]
    return list(csv.reader(lines, strict=True))


def _no_formula(path: Path) -> None:
    rows = _cells(path)
    width = len(rows[0])
    for row in rows:
        assert len(row) == width, (path.name, row)
        for cell in row:
            assert not cell.startswith(STARTS), (path.name, cell)
            if cell.startswith("-"):
                float(cell)  # only numbers may start with a minus


def test_hostile_texts_reach_every_csv_defused(tmp_path):
    text = (ROOT / "protocols/quick-demo.yaml").read_text()
    text = text.replace("thruster_id: demo", f'thruster_id: "{FORMULA}"')
    text = text.replace("step: 10}", "step: 50}").replace("samples: 1000", "samples: 100")
    protocol = tmp_path / "p.yaml"
    protocol.write_text(text)
    db = tmp_path / "db.sqlite"
    assert main(["sweep", str(protocol), "--sim", "--db", str(db)]) == 0
    with sqlite3.connect(db) as conn:  # as a merged database from elsewhere could hold them
        conn.execute("UPDATE steps SET direction = ? WHERE idx = 1", ("@SUM(1+1)",))
        conn.execute("UPDATE steps SET status = ? WHERE idx = 2", ('"' + FORMULA,))
    assert main(["export", "last", "--db", str(db), "--out", str(tmp_path / "exp")]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp_path / "cal"),
                 "--export", "csv-lut"]) == 0
    files = sorted((tmp_path / "exp").glob("*.csv")) + sorted((tmp_path / "cal").rglob("*.csv"))
    assert len(files) >= 6
    for path in files:
        _no_formula(path)
    points = next((tmp_path / "exp").glob("*points.csv")).read_text()
    assert "'" + FORMULA in points


def test_cells_and_sidecar_notes_hold_no_formula_line_break_or_bidi_mark():
    assert csv_cell(FORMULA) == "'=cmd|' /C calc'!A0"
    assert csv_cell('"up\n,x') == "'up ;x"
    assert csv_text([("a", "N", "x")], [["+1"]]) == "a\n'+1\n"
    text = columns_text(["run a\u202eb", "=unit \u2028=1"], [("a", "N", "x\u2029=2, y")])
    assert "\u202e" not in text and "\\u202e" in text
    rows = list(csv.reader(text.splitlines(), strict=True))  # one line each, the comma quoted
    assert rows == [["column", "unit", "description"], ["", "", "run a\\u202eb"],
                    ["", "", "'=unit  =1"], ["a", "N", "x =2, y"]]
