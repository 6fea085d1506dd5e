"""Every CSV rigtool writes opens as a table with a reader's default options (issue 50 items 6
and 8): the calibration folder's tables, their `.columns.csv` sidecars, the csv-lut export and
`rigtool export`'s points, samples and events. Read with `pandas.read_csv(path)` as it is, and
with the csv module strictly: one header row of distinct names, every row as wide. Export
floats carry at most 12 significant digits."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import pytest

from rigtool.cli import main

from .conftest import SMALL_PROTOCOL

VOLTAGE_SWEEP = SMALL_PROTOCOL.replace("values: [-50, 0, 50, 100]",
                                       "values: [-100, -75, -50, -25, 0, 25, 50, 75, 100]").replace(
    "simulator: {profile: can-bldc, seed: 3}",
    "simulator: {profile: can-bldc, seed: 7, overrides: {feedback: [speed_rpm, current_a, "
    "voltage_v]}}").replace("timing:", "voltage: {unit: V, values: [12, 16]}\ntiming:")
DIGITS = re.compile(r"^-?(\d+)(?:\.(\d+))?(?:e[-+]\d+)?$")


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, list[Path]]:
    """A calibrated voltage sweep: its calibration folder, csv-lut export and run export."""
    tmp = tmp_path_factory.mktemp("csvs")
    protocol = tmp / "p.yaml"
    protocol.write_text(VOLTAGE_SWEEP)
    db = tmp / "lab.sqlite"
    assert main(["sweep", str(protocol), "--sim", "--db", str(db)]) == 0
    assert main(["calibrate", "last", "--db", str(db), "--out", str(tmp / "cal"),
                 "--export", "csv-lut"]) == 0
    assert main(["export", "last", "--db", str(db), "--out", str(tmp / "exp")]) == 0
    return tmp, sorted(tmp.rglob("*.csv"))


def _strict(path: Path) -> list[list[str]]:
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh, strict=True))
    header = rows[0]
    assert header and len(set(header)) == len(header), path.name
    assert all(re.fullmatch(r"[A-Za-z][^,]*", name) for name in header), (path.name, header)
    assert all(len(row) == len(header) for row in rows), path.name
    return rows


def test_every_csv_has_one_header_row_and_rectangular_rows(written):
    tmp, files = written
    names = {p.relative_to(tmp).parts[0] + "/" + p.name.split("-")[-1] for p in files}
    assert {"cal/points.csv", "cal/points.columns.csv", "cal/command_curve.csv",
            "cal/inverse_lut.csv", "cal/performance.csv", "cal/voltage.csv",
            "cal/voltage.columns.csv", "exp/points.csv", "exp/samples.csv",
            "exp/events.csv"} <= names
    for path in files:
        assert not path.read_text(encoding="utf-8").startswith("#"), path
        _strict(path)


def test_pandas_opens_every_csv_with_its_defaults(written):
    pd = pytest.importorskip("pandas")
    _, files = written
    for path in files:
        rows = _strict(path)
        frame = pd.read_csv(path)
        assert list(frame.columns) == rows[0], path.name
        assert len(frame) == len(rows) - 1, path.name


def test_a_sidecar_documents_every_column_of_its_table(written):
    _, files = written
    for sidecar in (p for p in files if p.name.endswith(".columns.csv")):
        table = sidecar.with_name(sidecar.name.replace(".columns.csv", ".csv"))
        rows = _strict(sidecar)
        assert rows[0] == ["column", "unit", "description"]
        documented = [r[0] for r in rows[1:] if r[0]]
        assert documented == _strict(table)[0], sidecar.name
        assert any(r[0] == "" and "calibration of run" in r[2] for r in rows[1:])


def test_export_floats_have_at_most_twelve_significant_digits(written):
    tmp, files = written
    longest = 0
    for path in (p for p in files if p.parent.name == "exp"):
        for row in _strict(path)[1:]:
            for cell in row:
                m = DIGITS.match(cell)
                if m and m.group(2):
                    longest = max(longest, len((m.group(1) + m.group(2)).lstrip("0")))
    assert 6 <= longest <= 12
