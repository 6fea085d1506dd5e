"""rigtool import of Tyto/RCbenchmark logs: headers with units, kgf, BOM, bad rows, then calibrate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigtool.analysis.calibrate import calibrate_run
from rigtool.cli import main
from rigtool.importers import Mapping, RowErrors, import_file, with_overrides
from rigtool.importers.units import G0, split_header
from rigtool.store import Store

from .importdata import FWD_MAX_KGF, rcbenchmark_log


@pytest.fixture
def log(tmp_path: Path) -> Path:
    path = tmp_path / "data.csv"
    path.write_text(rcbenchmark_log(bad_line_at=57), encoding="utf-8")
    return path


def test_split_header_units() -> None:
    assert split_header("Thrust (kgf)") == ("Thrust", "kgf")
    assert split_header("ESC signal (µs)") == ("ESC signal", "µs")
    assert split_header("Speed [rpm]") == ("Speed", "rpm")
    assert split_header("pwm") == ("pwm", None)


def test_import_calibrates_into_dead_zone_and_coefficients(log: Path, db_path: Path) -> None:
    store = Store(db_path)
    result = import_file(store, log, with_overrides(Mapping(), settle_s=1.0), thruster_id="T1")
    assert result.importer == "rcbenchmark" and result.fmt == "timeseries"
    assert result.command_unit == "pulse_us"
    assert result.errors == [f"{log}:57: thrust: 'abc' is not a number"]
    assert (result.n_rows, result.n_skipped, result.n_steps) == (1980, 1, 33)
    assert not any("electrical" in w for w in result.warnings)  # optical speed preferred
    run = store.run(result.run_id)
    assert run["status"] == "completed" and run["metadata"]["thruster_id"] == "T1"
    assert run["rig"]["import"]["files"][0]["name"] == "data.csv"
    assert len(run["rig"]["import"]["files"][0]["sha256"]) == 64
    steps = store.steps(result.run_id)
    top = steps[-1]
    assert top["command"] == 1900 and top["thrust_all_mean_n"] == pytest.approx(FWD_MAX_KGF * G0,
                                                                            rel=0.01)
    cal = calibrate_run(store, result.run_id)
    sec = cal.sections[0]
    assert sec.curve.dead_zones == [(1475.0, 1525.0)]
    assert "C_p_fwd" in sec.fits and sec.fits["C_p_fwd"].r2 > 0.99


def test_settling_cut_removes_the_transient(log: Path, db_path: Path) -> None:
    store = Store(db_path)
    raw = import_file(store, log, Mapping())
    cut = import_file(store, log, with_overrides(Mapping(), settle_s=1.0))
    top_raw = store.steps(raw.run_id)[-1]
    top_cut = store.steps(cut.run_id)[-1]
    assert top_cut["n"] < top_raw["n"]
    target = FWD_MAX_KGF * G0
    assert abs(top_cut["thrust_all_mean_n"] - target) < abs(top_raw["thrust_all_mean_n"] - target)


def test_strict_refuses_bad_rows(log: Path, db_path: Path) -> None:
    store = Store(db_path)
    with pytest.raises(RowErrors, match=r"data.csv:57: thrust: 'abc' is not a number"):
        import_file(store, log, Mapping(), strict=True)
    assert store.runs() == []


def test_electrical_speed_needs_pole_pairs(tmp_path: Path, db_path: Path) -> None:
    text = rcbenchmark_log().replace(",Motor Optical Speed (RPM)", ",Other")
    path = tmp_path / "erpm.csv"
    path.write_text(text, encoding="utf-8")
    store = Store(db_path)
    no_pp = import_file(store, path, Mapping())
    assert any("--pole-pairs" in w for w in no_pp.warnings)
    assert np.isnan(store.steps(no_pp.run_id)[-1]["speed_all_mean_rpm"] or np.nan)
    with_pp = import_file(store, path, with_overrides(Mapping(), pole_pairs=7, settle_s=1.0))
    assert store.steps(with_pp.run_id)[-1]["speed_all_mean_rpm"] == pytest.approx(3800, rel=0.02)


def test_cli_import_calibrate_report(log: Path, tmp_path: Path, capsys) -> None:
    db = str(tmp_path / "cli.sqlite")
    assert main(["import", str(log), "--settle-s", "1", "--thruster-id", "stern-1",
                 "--name", "tyto", "--db", db]) == 0
    captured = capsys.readouterr()
    assert "1979 row(s) read, 1 skipped" in captured.out
    assert "data.csv:57: thrust: 'abc' is not a number" in captured.err
    out = tmp_path / "cal"
    assert main(["calibrate", "last", "--out", str(out), "--report", "--db", db]) == 0
    run_dir = next(out.iterdir())
    html = (run_dir / "report.html").read_text()
    assert "tyto" in html and "import:rcbenchmark" in html
    assert main(["import", str(log), "--strict", "--db", db]) == 2
