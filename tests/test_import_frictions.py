"""`rigtool import` frictions found by an audit, each through the CLI on CSV text built here:
an eRPM column that is already mechanical r/min, a speed column of nothing but zeros, a file
with no header line, an analog throttle in volts, and a hand-mapped table's importer label."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigtool.cli import main
from rigtool.store import Store

CP_FWD = 2.0e-6  # N/(r/min)^2; reverse 0.8 x
TOP_RPM = 3000.0
POLE_PAIRS = 7
COMMANDS = np.arange(1100.0, 1901.0, 50.0)
ROWS_PER_COMMAND = 20  # 2 s at 10 Hz: a time series
OPTICAL = "Motor Optical Speed (RPM)"
ELECTRICAL = "Motor Electrical Speed (RPM)"


def _speed(command: np.ndarray, neutral: float = 1500.0, dead: float = 25.0,
           full: float = 400.0) -> np.ndarray:
    """Signed mechanical r/min: zero within `dead` of neutral, linear to TOP_RPM at `full`."""
    x = np.clip((np.abs(command - neutral) - dead) / (full - dead), 0.0, 1.0)
    return np.sign(command - neutral) * TOP_RPM * x


def _thrust(n: np.ndarray) -> np.ndarray:
    return np.where(n >= 0, CP_FWD, 0.8 * CP_FWD) * n * np.abs(n)


def _tyto_log(electrical: float | None = None, optical: str | None = "measured") -> str:
    """A Tyto-style time series; `electrical`: the eRPM column as this multiple of the
    mechanical speed (1: a stand that was given the pole count), None: no such column;
    `optical`: "measured", "zeros", "empty" or None (no column)."""
    rng = np.random.default_rng(4711)
    header = ["Time (s)", "ESC signal (µs)", "Thrust (N)"]
    header += [ELECTRICAL] if electrical is not None else []
    header += [OPTICAL] if optical is not None else []
    lines = [",".join(header)]
    t = 0.0
    for cmd in COMMANDS:
        n = float(_speed(np.array([cmd]))[0])
        f = float(_thrust(np.array([n]))[0])
        for _ in range(ROWS_PER_COMMAND):
            row = [f"{t:.2f}", f"{cmd:.0f}", f"{f + rng.normal(0, 0.002):.5f}"]
            row += [f"{electrical * abs(n):.0f}"] if electrical is not None else []
            row += [{"measured": f"{abs(n):.0f}", "zeros": "0", "empty": ""}[optical]
                    ] if optical else []
            lines.append(",".join(row))
            t += 0.1
    return "\n".join(lines) + "\n"


def _run(tmp_path: Path, text: str, *options: str, name: str = "log.csv") -> tuple[int, Path]:
    """`rigtool import` of `text` written to `name`; (exit status, database)."""
    path, db = tmp_path / name, tmp_path / "runs.sqlite"
    path.write_text(text, encoding="utf-8")
    return main(["import", str(path), "--db", str(db), *options]), db


def _calibration(tmp_path: Path, db: Path) -> dict:
    """calibration.json of the last run, through `rigtool calibrate`."""
    out = tmp_path / "cal"
    assert main(["calibrate", "last", "--db", str(db), "--out", str(out)]) == 0
    run_id = Store(db).resolve_run_id("last")
    return json.loads((out / run_id / "calibration.json").read_text())


def _cp_fwd(tmp_path: Path, db: Path) -> float | None:
    (depth,) = _calibration(tmp_path, db)["depths"]
    return depth["coefficients"].get("C_p_fwd", {}).get("value")


def _stored_warnings(db: Path) -> list[str]:
    store = Store(db)
    return [e["detail"]["message"] for e in store.events(store.resolve_run_id("last"), "warning")]


# 1. eRPM column that is already mechanical r/min ------------------------------------------------

def test_electrical_column_already_mechanical_beside_optical_is_named(tmp_path, capsys):
    """Both columns read the same with --pole-pairs 7: the optical speed is used (C_p right)
    and a warning says the eRPM column is mechanical already."""
    status, db = _run(tmp_path, _tyto_log(electrical=1.0), "--pole-pairs", str(POLE_PAIRS))
    assert status == 0
    err = capsys.readouterr().err
    assert f"warning: speed column {ELECTRICAL!r} reads 1.00 x {OPTICAL!r}" in err
    assert "mechanical r/min already" in err and f"--pole-pairs {POLE_PAIRS} does not apply" in err
    assert any("mechanical r/min already" in w for w in _stored_warnings(db))
    assert _cp_fwd(tmp_path, db) == pytest.approx(CP_FWD, rel=0.02)


def test_electrical_column_that_is_electrical_beside_optical_is_silent(tmp_path, capsys):
    status, db = _run(tmp_path, _tyto_log(electrical=POLE_PAIRS), "--pole-pairs",
                      str(POLE_PAIRS))
    assert status == 0
    assert "speed column" not in capsys.readouterr().err
    assert _cp_fwd(tmp_path, db) == pytest.approx(CP_FWD, rel=0.02)


def test_electrical_column_disagreeing_with_the_pole_pairs_is_named(tmp_path, capsys):
    status, _ = _run(tmp_path, _tyto_log(electrical=POLE_PAIRS), "--pole-pairs", "4")
    assert status == 0
    err = capsys.readouterr().err
    assert f"reads 7.00 x {OPTICAL!r}: neither 1 (mechanical) nor --pole-pairs 4" in err


def test_electrical_column_alone_is_divided_with_a_caveat(tmp_path, capsys):
    """Only the eRPM column, holding mechanical r/min: nothing in the log can tell, so it is
    divided as documented, and the warning says how the speed may be 7 x too low and how to
    check it."""
    status, db = _run(tmp_path, _tyto_log(electrical=1.0, optical=None), "--pole-pairs",
                      str(POLE_PAIRS))
    assert status == 0
    err = capsys.readouterr().err
    assert f"warning: speed column {ELECTRICAL!r} divided by --pole-pairs 7" in err
    assert "7 x too low (C_p 49 x too large)" in err
    assert "optical tachometer" in err and "KV x voltage" in err
    top = Store(db).steps(Store(db).resolve_run_id("last"))[-1]
    assert top["speed_all_mean_rpm"] == pytest.approx(TOP_RPM / POLE_PAIRS, rel=0.01)


# 2. a speed column of nothing but zeros or empty cells ------------------------------------------

@pytest.mark.parametrize("optical", ["zeros", "empty"])
def test_unmeasured_optical_falls_back_to_the_electrical_column(tmp_path, capsys, optical):
    status, db = _run(tmp_path, _tyto_log(electrical=POLE_PAIRS, optical=optical),
                      "--pole-pairs", str(POLE_PAIRS))
    assert status == 0
    err = capsys.readouterr().err
    assert (f"warning: speed column {OPTICAL!r} holds only zeros or empty cells: not measured, "
            f"ignored; speed from {ELECTRICAL!r} divided by --pole-pairs 7") in err
    assert Store(db).run(Store(db).resolve_run_id("last"))["rig"]["import"]["columns"]["speed"][
        "header"] == ELECTRICAL
    assert _cp_fwd(tmp_path, db) == pytest.approx(CP_FWD, rel=0.02)


def test_unmeasured_optical_without_pole_pairs_says_no_usable_speed(tmp_path, capsys):
    status, db = _run(tmp_path, _tyto_log(electrical=POLE_PAIRS, optical="zeros"))
    assert status == 0
    err = capsys.readouterr().err
    assert (f"ignored; {ELECTRICAL!r} is electrical speed: give --pole-pairs to use it; "
            "no usable speed column") in err
    assert "speed" not in Store(db).run(Store(db).resolve_run_id("last"))["rig"]["import"][
        "columns"]
    assert _cp_fwd(tmp_path, db) is None


@pytest.mark.parametrize("optical", ["zeros", "empty"])
def test_only_speed_column_unmeasured_is_ignored_with_a_warning(tmp_path, capsys, optical):
    """As an all-zero torque column: no C_p fitted from a speed of zero, and a warning."""
    status, db = _run(tmp_path, _tyto_log(optical=optical))
    assert status == 0
    err = capsys.readouterr().err
    assert f"speed column {OPTICAL!r} holds only zeros or empty cells" in err
    assert "no usable speed column" in err
    store = Store(db)
    run_id = store.resolve_run_id("last")
    assert "speed" not in store.run(run_id)["rig"]["import"]["columns"]
    assert store.steps(run_id)[-1]["speed_all_mean_rpm"] is None
    assert any("holds only zeros" in w for w in _stored_warnings(db))


# 3. a file with no header line --------------------------------------------------------------

def _headerless(n: int = 12) -> str:
    return "".join(f"{0.5 * i:.1f},{1100 + 50 * i},{0.25 * i:.2f}\n" for i in range(n))


def test_headerless_file_keeps_its_first_row(tmp_path, capsys):
    status, db = _run(tmp_path, _headerless(), "--col", "time=1", "--col", "command=2",
                      "--col", "thrust=3", "--command-unit", "pulse_us")
    assert status == 0
    captured = capsys.readouterr()
    assert "12 row(s) read, 0 skipped -> 12 point(s)" in captured.out
    assert "warning: no header line: line 1 holds only numbers and is read as data" in captured.err
    store = Store(db)
    steps = store.steps(store.resolve_run_id("last"))
    assert [s["command"] for s in steps[:2]] == [1100, 1150]
    columns = store.run(store.resolve_run_id("last"))["rig"]["import"]["columns"]
    assert columns["command"]["header"] == "column 2"


def test_headerless_file_refuses_columns_given_by_name(tmp_path, capsys):
    status, db = _run(tmp_path, _headerless(), "--col", "time=1", "--col", "command=pwm",
                      "--col", "thrust=3", "--command-unit", "pulse_us")
    assert status == 2
    err = capsys.readouterr().err
    assert "log.csv: no header line (line 1 holds only numbers" in err
    assert "give command by column number" in err
    assert not db.exists() or Store(db).runs() == []


# 4. an analog throttle in volts -------------------------------------------------------------

def _volts_log() -> str:
    """`Throttle (V)` 0.5-4.5 V, neutral 2.5 V (dead band +-0.1 V), thrust in N, optical speed."""
    lines = ["Time (s),Throttle (V),Thrust (N),Motor Optical Speed (RPM)"]
    t = 0.0
    for v in np.round(np.arange(0.5, 4.501, 0.1), 2):
        n = float(_speed(np.array([v]), neutral=2.5, dead=0.1, full=2.0)[0])
        for _ in range(ROWS_PER_COMMAND):
            lines.append(f"{t:.2f},{v:.2f},{float(_thrust(np.array([n]))[0]):.5f},{abs(n):.0f}")
            t += 0.1
    return "\n".join(lines) + "\n"


def test_volts_command_without_neutral_is_refused(tmp_path, capsys):
    status, db = _run(tmp_path, _volts_log())
    assert status == 2
    err = capsys.readouterr().err
    assert "the commands run 0.5..4.5 (volts), and the default neutral 0 is outside them" in err
    assert "give --neutral" in err
    assert not db.exists() or Store(db).runs() == []


def test_volts_command_from_the_header_with_neutral(tmp_path, capsys):
    status, db = _run(tmp_path, _volts_log(), "--neutral", "2.5")
    assert status == 0
    assert "(rcbenchmark, timeseries, volts)" in capsys.readouterr().out
    store = Store(db)
    run = store.run(store.resolve_run_id("last"))
    assert run["command_unit"] == "volts" and run["protocol"]["command"]["neutral"] == 2.5
    assert _cp_fwd(tmp_path, db) == pytest.approx(CP_FWD, rel=0.02)


def test_command_unit_option_takes_volts_and_refuses_unknown_units(tmp_path, capsys):
    text = _volts_log().replace("Throttle (V)", "throttle")
    status, db = _run(tmp_path, text, "--command-unit", "volts", "--neutral", "2.5")
    assert status == 0
    assert Store(db).run(Store(db).resolve_run_id("last"))["command_unit"] == "volts"
    capsys.readouterr()
    status, _ = _run(tmp_path, text, "--command-unit", "volt", "--neutral", "2.5")
    assert status == 2
    assert "--command-unit 'volt': unknown command unit" in capsys.readouterr().err


# 5. importer label of a hand-mapped table ---------------------------------------------------

def test_hand_mapped_table_is_labelled_generic(tmp_path, capsys):
    """Headers a Tyto log also uses (`pwm`, `thrust`), command and thrust mapped by hand."""
    text = "time,pwm,thrust\n" + "".join(
        f"{i},{c:.0f},{0.01 * (c - 1500):.3f}\n" for i, c in enumerate(COMMANDS))
    status, db = _run(tmp_path, text, "--col", "time=time", "--col", "command=pwm",
                      "--col", "thrust=thrust", "--command-unit", "pulse_us")
    assert status == 0
    assert "(generic, " in capsys.readouterr().out
    store = Store(db)
    rig = store.run(store.resolve_run_id("last"))["rig"]
    assert rig["name"] == "import:generic" and rig["import"]["importer"] == "generic"
    status, db = _run(tmp_path, text, "--command-unit", "pulse_us", name="recognised.csv")
    assert status == 0
    assert Store(db).run(Store(db).resolve_run_id("last"))["rig"]["import"][
        "importer"] == "rcbenchmark"
