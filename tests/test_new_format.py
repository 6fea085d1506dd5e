"""A new vehicle format is one module plus its line in the format registry
(artefacts/formats MODULES): the CLI offers it, `calibrate --export` and `export-cal` write it,
its unmet needs refuse the whole export, and nothing else in rigtool is edited."""

from __future__ import annotations

import types

import pytest

from rigtool.artefacts.formats import MODULES
from rigtool.artefacts.vehicle import ExportInput
from rigtool.cli import main

from .conftest import copy_db


def _format(refuse: bool) -> types.ModuleType:
    """A throwaway format module: each inverse-table row as `direction thrust command`."""
    module = types.ModuleType("thrust_lines")
    module.FILE = "thrust_lines.txt"
    module.FOLLOWS = "a test's own text"

    def needs(x: ExportInput) -> list[str]:
        return ["thrust-lines: a vehicle name (test refusal)"] if refuse else []

    def render(x: ExportInput) -> str:
        return "".join(f"{direction} {t:g} {c:g}\n" for direction, thrust, command in x.tables
                       for t, c in zip(thrust, command, strict=True))

    module.needs, module.render = needs, render
    return module


@pytest.fixture
def calibrated(shipped_sweep, tmp_path):
    db = copy_db(shipped_sweep("quick-demo"), tmp_path / "db.sqlite")
    return db, tmp_path / "cal"


def test_a_registered_format_is_offered_and_written(calibrated, monkeypatch, capsys):
    db, out = calibrated
    monkeypatch.setitem(MODULES, "thrust-lines", _format(refuse=False))
    assert main(["calibrate", "last", "--db", str(db), "--out", str(out), "--export", "thrust-lines",
                 "--export", "csv-lut"]) == 0, capsys.readouterr().err
    written = next(out.glob("*/thrust_lines.txt"))
    rows = [line.split() for line in written.read_text().splitlines()]
    assert len(rows) >= 5 and all(len(r) == 3 for r in rows)
    assert main(["export-cal", "last", "--db", str(db), "--out", str(out.parent / "again"),
                 "--format", "thrust-lines"]) == 0
    assert next((out.parent / "again").glob("*/thrust_lines.txt")).read_text() \
        == written.read_text()


def test_an_unregistered_format_is_a_usage_error(calibrated, capsys):
    db, out = calibrated
    with pytest.raises(SystemExit) as exc:
        main(["export-cal", "last", "--db", str(db), "--out", str(out), "--format", "thrust-lines"])
    assert exc.value.code == 2 and "thrust-lines" in capsys.readouterr().err


def test_a_registered_format_that_lacks_its_needs_writes_nothing(calibrated, monkeypatch,
                                                                capsys):
    db, out = calibrated
    assert main(["calibrate", "last", "--db", str(db), "--out", str(out)]) == 0
    before = sorted(p.name for p in out.rglob("*"))
    monkeypatch.setitem(MODULES, "thrust-lines", _format(refuse=True))
    assert main(["export-cal", "last", "--db", str(db), "--out", str(out), "--format", "csv-lut",
                 "--format", "thrust-lines"]) == 2
    assert "test refusal" in capsys.readouterr().err
    assert sorted(p.name for p in out.rglob("*")) == before
