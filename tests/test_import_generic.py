"""rigtool import of any CSV through a column mapping: per-point tables, comma decimals, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigtool.analysis.calibrate import calibrate_run
from rigtool.cli import main
from rigtool.errors import ConfigError, UsageError
from rigtool.importers import Mapping, import_file, load_mapping, with_overrides
from rigtool.importers.units import G0
from rigtool.store import Store

from .importdata import COMMANDS, FWD_MAX_KGF, point_table, thrust_kgf

MAPPING = """\
rigtool_mapping: 1
columns: {command: pwm, thrust: F_z, thrust_std: F_std, n_samples: count, voltage: 5}
command_unit: pulse_us
decimal: ","
delimiter: ";"
"""


def test_mapping_file_decimal_comma_per_point_table(tmp_path: Path, db_path: Path) -> None:
    data = tmp_path / "points.csv"
    data.write_text(point_table(decimal_comma=True))
    mapping = tmp_path / "map.yaml"
    mapping.write_text(MAPPING)
    store = Store(db_path)
    result = import_file(store, data, load_mapping(mapping))
    assert (result.importer, result.fmt, result.n_skipped) == ("generic", "points", 0)
    steps = store.steps(result.run_id)
    assert len(steps) == COMMANDS.size and steps[0]["n"] == 500
    assert steps[-1]["thrust_all_mean_n"] == pytest.approx(FWD_MAX_KGF * G0, rel=0.01)
    assert steps[-1]["thrust_all_std_n"] == pytest.approx((0.004 + 0.04) * G0, rel=0.01)
    cal = calibrate_run(store, result.run_id)
    assert cal.sections[0].curve.dead_zones == [(1475.0, 1525.0)]


def test_cli_cols_single_sample_points_with_zero_band(tmp_path: Path, capsys) -> None:
    rng = np.random.default_rng(4)
    rows = ["cmd,force (N),junk"]
    for c in np.arange(1100.0, 1901.0, 10.0):
        f = thrust_kgf(np.array([c]))[0] * G0 + rng.normal(0, 0.003)
        rows.append(f"{c:.0f},{f:.4f},x,")
    rows.insert(10, "1190,abc,x")
    data = tmp_path / "data.csv"
    data.write_text("\n".join(rows) + "\n\n")
    db = str(tmp_path / "cli.sqlite")
    assert main(["import", str(data), "--col", "command=cmd", "--col", "thrust=force",
                 "--command-unit", "pulse_us", "--db", db]) == 0
    captured = capsys.readouterr()
    assert "data.csv:11: thrust: 'abc' is not a number" in captured.err
    assert "81 row(s) read, 1 skipped" in captured.out
    store = Store(db, create=False)
    cal = calibrate_run(store, store.resolve_run_id("last"))
    (lo, hi), = cal.sections[0].curve.dead_zones
    assert 1460 <= lo <= 1480 and 1520 <= hi <= 1540
    out = tmp_path / "cal"
    assert main(["report", "last", "--out", str(out), "--db", db]) == 2
    assert "has not been calibrated" in capsys.readouterr().err
    assert main(["calibrate", "last", "--out", str(out), "--db", db]) == 0
    assert main(["report", "last", "--out", str(out), "--db", db]) == 0
    assert "data:image/svg+xml" in next(out.glob("*/report.html")).read_text()


def test_units_override_and_thrust_sign(tmp_path: Path, db_path: Path) -> None:
    data = tmp_path / "lbf.csv"
    data.write_text("t,u,F\n0,1900,-1\n1,1500,0\n2,1100,1\n")
    m = with_overrides(Mapping(), cols=["command=u", "thrust=F", "time=t"],
                       units=["thrust=lbf"], command_unit="pulse_us", thrust_sign=-1)
    store = Store(db_path)
    result = import_file(store, data, m)
    assert result.fmt == "points"
    assert store.steps(result.run_id)[0]["thrust_all_mean_n"] == pytest.approx(4.4482216, rel=1e-6)


def test_comma_values_without_option_are_reported(tmp_path: Path, db_path: Path) -> None:
    data = tmp_path / "c.csv"
    data.write_text("u;F\n1500;0\n1600;1,5\n1700;3\n")
    m = with_overrides(Mapping(), cols=["command=u", "thrust=F"], command_unit="pulse_us")
    result = import_file(Store(db_path), data, m)
    assert result.errors == [f"{data}:3: thrust: '1,5' is not a number (comma decimal? use "
                             "--decimal-comma)"]


def test_mapping_unknown_key_names_file_and_line(tmp_path: Path) -> None:
    mapping = tmp_path / "bad.yaml"
    mapping.write_text("columns:\n  command: pwm\n  thrust: F\n  thrusst_std: s\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:4: columns.thrusst_std: unknown field"):
        load_mapping(mapping)


def test_unrecognised_file_asks_for_columns(tmp_path: Path, db_path: Path) -> None:
    data = tmp_path / "x.csv"
    data.write_text("a,b\n1,2\n")
    with pytest.raises(UsageError, match="--col command=COLUMN"):
        import_file(Store(db_path), data, Mapping())
    assert main(["import", str(data), "--col", "thrust=b", "--col", "command=zz",
                 "--command-unit", "percent", "--db", str(db_path)]) == 2
    assert main(["import", str(data), "--col", "bogus=b", "--db", str(db_path)]) == 2
